"""The disk-backed geometry cache: restored geometry equals built geometry, the model is built only
when asked for, and a damaged file is rebuilt instead of trusted."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cad_replacement.alignment import ModelGeometry
from cad_replacement.cad.library import CadEntry, CadLibrary
from cad_replacement.cad.model import CadModel
from cad_replacement.geometry_cache import GeometryCache, library_store


def _library(tmp_path: Path) -> CadLibrary:
    return CadLibrary(cache_dir=tmp_path / "cad_features", classes=("cabinet", "cup"))


def _entry(lib: CadLibrary, cls: str) -> CadEntry:
    return next(e for e in lib.entries(cls) if e.kind == "procedural")


class _CountingLoader:
    def __init__(self, lib: CadLibrary) -> None:
        self.lib = lib
        self.calls = 0

    def __call__(self, entry: CadEntry) -> CadModel:
        self.calls += 1
        return self.lib.model(entry)


def _assert_same(a: ModelGeometry, b: ModelGeometry) -> None:
    for name in ("center", "size", "samples", "normals", "self_visible", "sample_links", "link_samples",
                 "link_normals"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.link_names == b.link_names
    assert a.sample_area == pytest.approx(b.sample_area)
    assert a.joint_values == b.joint_values
    assert a.articulated_model == b.articulated_model
    assert (a.envelope is None) == (b.envelope is None)
    if a.static_samples is not None:
        np.testing.assert_array_equal(a.static_samples, b.static_samples)


@pytest.mark.parametrize("cls", ["cabinet", "cup"])
def test_restored_geometry_equals_built_and_defers_the_model(tmp_path: Path, cls: str) -> None:
    lib = _library(tmp_path)
    entry = _entry(lib, cls)
    store = library_store(lib)
    assert store is not None and store.folder == tmp_path / "cad_geometry"

    first = GeometryCache(_CountingLoader(lib), samples=300, store=store)
    built = first.get(entry)
    assert (first.built, first.restored) == (1, 0)
    assert store.path(entry, 300).is_file()

    loader = _CountingLoader(lib)
    second = GeometryCache(loader, samples=300, store=store)
    restored = second.get(entry)
    assert (second.built, second.restored) == (0, 1)
    assert loader.calls == 0  # screening needs no model: nothing was built
    _assert_same(built, restored)
    # same distances from the rebuilt raycasting scene
    q = built.samples[:50] + 0.01 * built.normals[:50]
    import open3d.core as o3c

    d_built = built.scene.compute_distance(o3c.Tensor(q.astype(np.float32))).numpy()
    d_rest = restored.scene.compute_distance(o3c.Tensor(q.astype(np.float32))).numpy()
    np.testing.assert_allclose(d_built, d_rest, atol=1e-6)
    # the model is built on first use, once
    assert restored.model.model_id == built.model.model_id
    assert restored.model is restored.model
    assert loader.calls == 1
    # another sample count is another file
    assert not store.path(entry, 200).exists()


def test_damaged_file_is_rebuilt(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    lib = _library(tmp_path)
    entry = _entry(lib, "cup")
    store = library_store(lib)
    assert store is not None
    GeometryCache(lib.model, samples=200, store=store).get(entry)
    path = store.path(entry, 200)
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])  # a write cut short
    cache = GeometryCache(lib.model, samples=200, store=store)
    geom = cache.get(entry)
    assert (cache.built, cache.restored) == (1, 0)
    assert "unreadable" in caplog.text
    assert np.all(np.isfinite(geom.samples))
    # and rewritten whole: the next cache restores it
    again = GeometryCache(lib.model, samples=200, store=store)
    again.get(entry)
    assert again.restored == 1


def test_unwritable_store_costs_speed_not_the_run(tmp_path: Path) -> None:
    lib = _library(tmp_path)
    entry = _entry(lib, "cup")
    store = library_store(lib)
    assert store is not None
    store.folder.parent.mkdir(parents=True, exist_ok=True)
    store.folder.write_text("not a folder")  # mkdir fails
    cache = GeometryCache(lib.model, samples=200, store=store)
    assert len(cache.get(entry).samples) > 0
    assert cache.built == 1
