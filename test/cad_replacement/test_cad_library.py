"""CadLibrary: enumeration of procedural + imported models and the JSON feature cache."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cad_replacement.cad import CadLibrary, build_model
from cad_replacement.cad import library as library_module
from cad_replacement.cad.library import LAYOUT_SEED_FACTOR
from recon_core.classes import load_class_table
from recon_core.errors import CadImportError


def _count_computations(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    calls: list[str] = []
    original = library_module.CadLibrary._compute

    def counting(self, entry, digest):  # type: ignore[no-untyped-def]
        calls.append(entry.key)
        return original(self, entry, digest)

    monkeypatch.setattr(library_module.CadLibrary, "_compute", counting)
    return calls


def test_features_are_computed_once_and_cached_on_disk(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, write_external_model
) -> None:
    calls = _count_computations(monkeypatch)
    root = tmp_path / "models"
    write_external_model(root / "cabinet" / "ext1")
    cache = tmp_path / "cache"
    lib = CadLibrary(root=root, cache_dir=cache, seeds_per_class=3, classes=["cabinet", "table"])
    keys = [e.key for e in lib.entries()]
    # a class of varied layout (articulated) enumerates LAYOUT_SEED_FACTOR times the seeds (front layouts)
    n_cab = 3 * LAYOUT_SEED_FACTOR
    n = n_cab + 3 + 1
    assert lib.seeds_for("cabinet") == n_cab and lib.seeds_for("table") == 3
    assert len(keys) == n and "urdf/cabinet/ext1" in keys
    assert len(lib.entries("cabinet")) == n_cab + 1
    first = {e.key: lib.features(e) for e in lib.entries()}
    assert len(calls) == n and lib.stats.computed == n
    files = sorted(cache.glob("*.json"))
    assert len(files) == n
    mtimes = {p: p.stat().st_mtime_ns for p in files}
    lib.features(lib.entries()[0])
    assert lib.stats.memory_hits == 1

    again = CadLibrary(root=root, cache_dir=cache, seeds_per_class=3, classes=["cabinet", "table"])
    second = {e.key: again.features(e) for e in again.entries()}
    assert len(calls) == n  # nothing recomputed
    assert again.stats.disk_hits == n and again.stats.computed == 0
    assert {p: p.stat().st_mtime_ns for p in files} == mtimes
    for key, f in first.items():
        assert second[key].plane_array() == pytest.approx(f.plane_array())
        assert second[key].box_size == pytest.approx(f.box_size)
    # Cached procedural features equal freshly built analytic ones.
    entry = again.entries("table")[1]
    assert again.features(entry).box_size == pytest.approx(build_model("table", 1).size)


def test_changed_or_corrupt_cache_entries_are_recomputed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, write_external_model
) -> None:
    calls = _count_computations(monkeypatch)
    root = tmp_path / "models"
    urdf = write_external_model(root / "cabinet" / "ext1")
    cache = tmp_path / "cache"
    lib = CadLibrary(root=root, cache_dir=cache, seeds_per_class=1, classes=["cup"])
    for e in lib.entries():
        lib.features(e)
    assert len(calls) == 2
    cup = lib.entries("cup")[0]
    lib.cache_path(cup).write_text("{not json")
    lib2 = CadLibrary(root=root, cache_dir=cache, seeds_per_class=1, classes=["cup"])
    lib2.features(lib2.entries("cup")[0])
    assert len(calls) == 3  # corrupt file ignored and rewritten
    assert json.loads(lib2.cache_path(cup).read_text())["format"] == "scene_recon.cad_features"
    # Editing the model's files changes its digest: old cache entry is not reused.
    ext = lib2.entries("cabinet")[0]
    old_digest = lib2.digest(ext)
    urdf.write_text(urdf.read_text().replace('upper="1.5"', 'upper="1.4"'))
    lib3 = CadLibrary(root=root, cache_dir=cache, seeds_per_class=1, classes=["cup"])
    ext3 = lib3.entries("cabinet")[0]
    assert lib3.digest(ext3) != old_digest
    lib3.features(ext3)
    assert len(calls) == 4


def test_library_models_and_broken_imports(tmp_path: Path, write_external_model) -> None:
    root = tmp_path / "models"
    write_external_model(root / "cabinet" / "good")
    bad = write_external_model(root / "cabinet" / "bad")
    bad.write_text("<robot")
    write_external_model(root / "spaceship" / "x")  # unknown class, dropped with a class table
    lib = CadLibrary(
        root=root, cache_dir=tmp_path / "c", seeds_per_class=2, classes=["fridge"], class_table=load_class_table()
    )
    assert lib.class_names == ["cabinet", "fridge"]
    assert any("spaceship" in msg for _, msg in lib.errors)
    good = next(e for e in lib.entries("cabinet") if e.key.endswith("good"))
    m = lib.model(good)
    assert m.class_name == "cabinet" and len(m.movable_joints) == 2
    assert m.features.box_size == pytest.approx(m.size)
    broken = next(e for e in lib.entries("cabinet") if e.key.endswith("bad"))
    with pytest.raises(CadImportError):
        lib.features(broken)
    candidates = lib.candidates("cabinet")
    assert [e.key for e, _ in candidates] == ["urdf/cabinet/good"]
    fridge = lib.model(lib.entries("fridge")[1])
    assert fridge.model_id == "fridge_s0001"
    with pytest.raises(ValueError, match="no procedural builders"):
        CadLibrary(cache_dir=tmp_path / "c", classes=["spaceship"])


def test_library_lists_one_model_per_urdf_in_real_layouts(
    tmp_path: Path, write_replica_folder, write_sektion_package
) -> None:
    root = tmp_path / "models"
    write_replica_folder(root / "cabinet" / "replica")
    write_sektion_package(root / "cabinet" / "sektion_cabinet_model")
    lib = CadLibrary(root=root, cache_dir=tmp_path / "cache", seeds_per_class=0, classes=[])
    keys = sorted(e.key for e in lib.entries())
    assert keys == ["urdf/cabinet/kitchen_counter", "urdf/cabinet/sektion_cabinet_model", "urdf/fridge/fridge"]
    assert not lib.errors
    entries = {e.key: e for e in lib.entries()}
    # Two URDFs of one folder share its files but never a cache entry.
    fridge, counter = entries["urdf/fridge/fridge"], entries["urdf/cabinet/kitchen_counter"]
    assert fridge.asset_root == counter.asset_root and lib.digest(fridge) != lib.digest(counter)
    assert lib.features(fridge).box_size == pytest.approx([0.69, 0.7, 1.8], abs=1e-6)
    assert lib.features(counter).box_size == pytest.approx([0.62, 1.2, 0.9], abs=1e-6)
    sektion = lib.model(entries["urdf/cabinet/sektion_cabinet_model"])
    assert sektion.model_id == "sektion_cabinet_model" and len(sektion.movable_joints) == 3
    assert sektion.link("sektion").collisions is not None and sektion.link("sektion").inertial is not None
    assert len(sektion.features.support_surfaces) == 4
    # A URDF that breaks is skipped on its own; its neighbours stay usable.
    (root / "cabinet" / "replica" / "fridge.urdf").write_text("<robot")
    again = CadLibrary(root=root, cache_dir=tmp_path / "cache2", seeds_per_class=0, classes=[])
    assert [e.key for e, _ in again.candidates("cabinet")] == [
        "urdf/cabinet/kitchen_counter", "urdf/cabinet/sektion_cabinet_model"]
    assert again.candidates("fridge") == [] and any("fridge.urdf" in path for path, _ in again.errors)
