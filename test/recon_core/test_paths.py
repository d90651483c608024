"""recon_core.paths: every kind of path a request or message may name, confined to the data root."""

from __future__ import annotations

import os

import pytest

from recon_core.errors import PathConfinementError, StorageError
from recon_core.paths import confined_path, confined_uri


@pytest.fixture
def root(tmp_path):
    r = tmp_path / "root"
    (r / "maps").mkdir(parents=True)
    (tmp_path / "outside").mkdir()
    return r


def test_relative_and_absolute_paths_inside_the_root_are_accepted(root):
    assert confined_path(root, "maps/a") == (root / "maps" / "a").resolve()
    assert confined_path(root, str(root / "maps" / "b")) == (root / "maps" / "b").resolve()
    assert confined_path(root, ".") == root.resolve()
    assert confined_path(str(root), "new/deeper/folder") == root.resolve() / "new/deeper/folder"  # need not exist


@pytest.mark.parametrize("bad, reason", [
    ("", "empty"),
    ("   ", "empty"),
    ("../x", r"'\.\.'"),
    ("maps/../../x", r"'\.\.'"),
    ("maps/../a", r"'\.\.'"),  # even one that would stay inside
    ("/etc/x", "outside the data root"),
    ("/etc/passwd", "outside the data root"),
    ("maps/a\x00b", "NUL"),
    ("\x00", "NUL"),
])
def test_bad_paths_are_refused(root, bad, reason):
    with pytest.raises(PathConfinementError, match=reason):
        confined_path(root, bad)


def test_an_absolute_path_to_a_sibling_with_the_root_as_prefix_is_refused(root):
    sibling = root.parent / (root.name + "2")  # /tmp/.../root2 starts with /tmp/.../root
    with pytest.raises(PathConfinementError, match="outside"):
        confined_path(root, str(sibling / "x"))


def test_symlinks_out_of_the_root_are_refused(root, tmp_path):
    os.symlink(tmp_path / "outside", root / "escape")
    os.symlink("/etc/passwd", root / "maps" / "passwd")
    with pytest.raises(PathConfinementError, match="symbolic link"):
        confined_path(root, "escape/x")
    with pytest.raises(PathConfinementError, match="outside"):
        confined_path(root, "maps/passwd")
    os.symlink(root / "maps", root / "inside")  # a link that stays inside is fine
    assert confined_path(root, "inside/a") == (root / "maps" / "a").resolve()


def test_the_error_is_a_storage_error_and_a_value_error(root):
    with pytest.raises(StorageError):
        confined_path(root, "../x")
    with pytest.raises(ValueError):
        confined_path(root, "../x")


def test_uris_are_local_files_under_the_root_only(root):
    (root / "maps" / "m.ply").write_text("ply")
    assert confined_uri(root, f"file://{root}/maps/m.ply") == (root / "maps" / "m.ply").resolve()
    assert confined_uri(root, "maps/m.ply") == (root / "maps" / "m.ply").resolve()
    for bad in ("file:///etc/passwd", "http://example.com/m.ply", "package://x/m.ply", "file://otherhost/x",
                f"file://{root}/../x", "", "file://" + str(root) + "/a%00b"):
        with pytest.raises(PathConfinementError):
            confined_uri(root, bad)
    with pytest.raises(PathConfinementError, match="no data root"):
        confined_uri(None, f"file://{root}/maps/m.ply")
