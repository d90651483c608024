"""Asset folders: which URDFs, where mesh references point (never outside the root), mesh loading."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from cad_replacement.cad.asset_files import (
    MeshResolver,
    default_asset_root,
    default_model_id,
    find_urdf,
    find_urdfs,
    load_mesh_file,
)
from recon_core.errors import CadImportError


def _touch(path: Path, text: str = "solid x\nendsolid x\n") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_find_urdfs_in_the_known_layouts(tmp_path: Path) -> None:
    partnet = tmp_path / "40417"
    _touch(partnet / "mobility.urdf")
    _touch(partnet / "mobility_vhacd.urdf")  # the same model with decomposed collisions
    assert find_urdfs(partnet) == [partnet / "mobility.urdf"]
    assert default_model_id(partnet / "mobility.urdf", partnet) == "40417"
    replica = tmp_path / "replica"
    for name in ("fridge", "kitchen_counter", "cabinet"):
        _touch(replica / f"{name}.urdf")
    assert [p.stem for p in find_urdfs(replica)] == ["cabinet", "fridge", "kitchen_counter"]
    assert default_model_id(replica / "fridge.urdf", replica) == "fridge"
    with pytest.raises(CadImportError, match="several models"):
        find_urdf(replica)
    package = tmp_path / "sektion_cabinet_model"
    urdf = _touch(package / "urdf" / "sektion_cabinet.urdf")
    assert find_urdfs(package) == [urdf] and default_asset_root(urdf) == package
    assert default_model_id(urdf, package) == "sektion_cabinet_model"
    with pytest.raises(CadImportError, match=r"no \*\.urdf"):
        find_urdfs(tmp_path)  # holds folders only
    with pytest.raises(CadImportError, match="not a directory"):
        find_urdfs(tmp_path / "missing")


def test_mesh_references_resolve_inside_the_root(tmp_path: Path) -> None:
    root = tmp_path / "my_asset"
    urdf = _touch(root / "urdf" / "m.urdf")
    mesh = _touch(root / "meshes" / "body.stl")
    _touch(root / "meshes" / "handle.stl")
    vendored = _touch(root / "third_party" / "other_pkg" / "meshes" / "handle.stl")
    r = MeshResolver(root, urdf)
    assert r.resolve("../meshes/body.stl") == mesh.resolve()  # relative to the URDF
    assert r.resolve("package://my_asset/meshes/body.stl") == mesh.resolve()  # the root's own name
    assert r.resolve("package://renamed_pkg/meshes/body.stl") == mesh.resolve()  # any name: path suffix
    assert r.resolve("package://other_pkg/meshes/handle.stl") == vendored.resolve()  # <pkg>/<rest> first
    assert r.resolve(f"file://{mesh}") == mesh.resolve()
    assert r.resolve(str(mesh)) == mesh.resolve()
    assert r.resolve(" package://x/meshes/body%2Estl ") == mesh.resolve()  # URL-escaped, padded


@pytest.mark.parametrize(
    ("ref", "message"),
    [
        ("../../outside.stl", "outside the model folder"),
        ("{outside}", "outside the model folder"),
        ("file://{outside}", "outside the model folder"),
        ("package://pkg/../../outside.stl", "outside the model folder"),
        ("package://pkg/../outside.stl", "outside the model folder"),
        ("../meshes/escape.stl", "outside the model folder"),  # a symlink pointing out
        ("package://pkg/meshes/dup.stl", "ambiguous"),
        ("package://pkg/meshes/none.stl", "not found"),
        ("package://pkg", "package://<package>/<path>"),
        ("https://example.org/body.stl", "unsupported URI scheme"),
        ("../meshes/notes.txt", "unsupported format"),
        ("", "without a filename"),
    ],
)
def test_bad_mesh_references_raise(tmp_path: Path, ref: str, message: str) -> None:
    root = tmp_path / "asset"
    urdf = _touch(root / "urdf" / "m.urdf")
    outside = _touch(tmp_path / "outside.stl")
    (root / "meshes").mkdir()
    (root / "meshes" / "escape.stl").symlink_to(outside)
    _touch(root / "meshes" / "dup.stl")
    _touch(root / "copy" / "meshes" / "dup.stl")
    _touch(root / "meshes" / "notes.txt")
    with pytest.raises(CadImportError, match=message) as info:
        MeshResolver(root, urdf).resolve(ref.format(outside=outside))
    assert str(urdf) in str(info.value)


def test_glb_scene_parts_are_placed_by_their_nodes(tmp_path: Path) -> None:
    scene = trimesh.Scene()
    rot = trimesh.transformations.rotation_matrix(np.pi / 2, (0.0, 0.0, 1.0))
    scene.add_geometry(trimesh.creation.box(extents=(1.0, 0.2, 0.2)), node_name="a", transform=rot)
    scene.add_geometry(trimesh.creation.box(extents=(0.2, 0.2, 0.2)), node_name="b",
                       transform=trimesh.transformations.translation_matrix((2.0, 0.0, 0.0)))
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0]) @ trimesh.transformations.translation_matrix((3.0, 0.0, 0.0))
    scene.add_geometry(trimesh.creation.box(extents=(0.2, 0.2, 0.2)), node_name="c", transform=mirror)
    (tmp_path / "s.glb").write_bytes(scene.export(file_type="glb"))
    mesh = load_mesh_file(tmp_path / "s.glb", tmp_path / "m.urdf")
    # Not re-oriented (glTF y-up is decided per model, see import_meta), every node applied.
    assert mesh.bounds == pytest.approx(np.array([[-3.1, -0.5, -0.1], [2.1, 0.5, 0.1]]), abs=1e-6)
    assert len(mesh.faces) == 36 and mesh.volume == pytest.approx(0.04 + 0.008 + 0.008, rel=1e-6)  # mirror fixed


def test_collada_unit_is_applied_and_missing_pycollada_is_named(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    pytest.importorskip("collada")  # the optional dependency itself; the error path is tested below
    path = tmp_path / "box.dae"
    trimesh.creation.box(extents=(10.0, 20.0, 30.0)).export(path)
    text = path.read_text()
    assert "<up_axis>Y_UP</up_axis>" in text  # trimesh stamps Y_UP on z-up data: the tag is ignored
    path.write_text(text.replace("<up_axis>", '<unit meter="0.01" name="centimeter"/><up_axis>', 1))
    mesh = load_mesh_file(path, tmp_path / "m.urdf")
    assert mesh.extents == pytest.approx([0.1, 0.2, 0.3])
    monkeypatch.setitem(sys.modules, "collada", None)  # as if pycollada were not installed
    with pytest.raises(CadImportError, match="needs the optional package 'pycollada'"):
        load_mesh_file(path, tmp_path / "m.urdf")
