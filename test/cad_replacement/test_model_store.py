"""The model store: a model a worker chose (collision shapes included) is read back by the next process
number for number; a damaged file is rebuilt, never trusted."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cad_replacement.cad import library as library_module
from cad_replacement.cad.library import CadLibrary
from cad_replacement.cad.model import CadModel
from cad_replacement.cad.model_store import model_arrays
from cad_replacement.collision import inertial_from_shapes, transform_shapes


def _assert_same_model(a: CadModel, b: CadModel) -> None:
    assert (a.class_name, a.model_id, a.source) == (b.class_name, b.model_id, b.source)
    assert a.params == b.params and [type(v) for v in a.params.values()] == [type(v) for v in b.params.values()]
    assert json.dumps(a.features.to_dict(), sort_keys=True) == json.dumps(b.features.to_dict(), sort_keys=True)
    assert [lk.name for lk in a.links] == [lk.name for lk in b.links]
    for la, lb in zip(a.links, b.links, strict=True):
        assert la.color == lb.color and la.inertial is None and lb.inertial is None
        np.testing.assert_array_equal(la.mesh.vertices, lb.mesh.vertices)
        np.testing.assert_array_equal(la.mesh.faces, lb.mesh.faces)
        sa, sb = la.collisions, lb.collisions
        assert sa is not None and sb is not None and len(sa) == len(sb)
        for x, y in zip(sa, sb, strict=True):
            assert (x.kind, x.radius, x.length) == (y.kind, y.radius, y.length)
            np.testing.assert_array_equal(x.origin, y.origin)
            np.testing.assert_array_equal(x.size, y.size)
            assert (x.mesh is None) == (y.mesh is None)
            if x.mesh is not None and y.mesh is not None:
                np.testing.assert_array_equal(x.mesh.vertices, y.mesh.vertices)
                np.testing.assert_array_equal(x.mesh.faces, y.mesh.faces)
                np.testing.assert_array_equal(x.mesh.face_normals, y.mesh.face_normals)
        # what the physical check and the export derive from them
        affine = np.diag([1.1, 0.9, 1.2, 1.0])
        ia = inertial_from_shapes(transform_shapes(sa, affine), 500.0)
        ib = inertial_from_shapes(transform_shapes(sb, affine), 500.0)
        assert (ia is None) == (ib is None)
        if ia is not None and ib is not None:
            assert ia.mass == ib.mass
            np.testing.assert_array_equal(ia.inertia, ib.inertia)
    assert len(a.joints) == len(b.joints)
    for ja, jb in zip(a.joints, b.joints, strict=True):
        assert (ja.name, ja.type, ja.parent, ja.child, ja.lower, ja.upper, ja.effort, ja.velocity) == \
            (jb.name, jb.type, jb.parent, jb.child, jb.lower, jb.upper, jb.effort, jb.velocity)
        np.testing.assert_array_equal(ja.origin, jb.origin)
        np.testing.assert_array_equal(ja.axis, jb.axis)


@pytest.mark.parametrize("cls", ["cabinet", "cup", "fridge", "chair", "shelf", "table"])
def test_a_kept_model_is_read_back_by_the_next_process_as_built(tmp_path: Path, cls: str, monkeypatch) -> None:
    lib = CadLibrary(cache_dir=tmp_path / "cad_features", seeds_per_class=2, classes=[cls])
    store = lib.model_store
    assert store is not None and store.folder == tmp_path / "cad_models"
    for entry in lib.entries(cls):
        lib.keep_model(entry)
        assert store.has(entry)
    calls: list[object] = []
    real = library_module.build_model
    monkeypatch.setattr(library_module, "build_model", lambda *a, **k: calls.append(a) or real(*a, **k))
    fresh = CadLibrary(cache_dir=tmp_path / "cad_features", seeds_per_class=2, classes=[cls])
    for entry in lib.entries(cls):
        again = fresh.model(entry)
        assert all(lk._collision_fn is None for lk in again.links)  # the collisions came with it
        _assert_same_model(lib.model(entry), again)
    assert calls == []  # read back, never built


def test_a_damaged_or_older_model_file_is_rebuilt(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    lib = CadLibrary(cache_dir=tmp_path / "cad_features", seeds_per_class=1, classes=["cup"])
    entry = lib.entries("cup")[0]
    lib.keep_model(entry)
    store = lib.model_store
    assert store is not None
    path = store.path(entry)
    path.write_bytes(path.read_bytes()[:200])
    fresh = CadLibrary(cache_dir=tmp_path / "cad_features", seeds_per_class=1, classes=["cup"])
    with caplog.at_level("WARNING"):
        model = fresh.model(entry)
    assert "unreadable" in caplog.text
    _assert_same_model(lib.model(entry), model)
    # a file of another layout version is ignored too
    raw = model_arrays(lib.model(entry))
    header = json.loads(str(raw["header"]))
    header["version"] = -1
    raw["header"] = np.array(json.dumps(header))
    with path.open("wb") as fh:
        np.savez(fh, **raw)
    caplog.clear()
    with caplog.at_level("WARNING"):
        model = CadLibrary(cache_dir=tmp_path / "cad_features", seeds_per_class=1, classes=["cup"]).model(entry)
    assert "not a version" in caplog.text
    _assert_same_model(lib.model(entry), model)


def test_an_unwritable_model_store_costs_speed_not_the_run(tmp_path: Path) -> None:
    cache = tmp_path / "cad_features"
    (tmp_path / "cad_models").write_text("a file where the folder should be")
    lib = CadLibrary(cache_dir=cache, seeds_per_class=1, classes=["cup"])
    entry = lib.entries("cup")[0]
    lib.keep_model(entry)  # logged, not raised
    assert lib.model(entry).links
