"""Front-layout variants (``cad.layouts``) and their search in ``replace_object``.

The library holds one cabinet (a front of two doors); the observed cabinet is the
same carcass with four drawers. With its drawers pulled out the library model cannot explain the
front: the layout search must find a drawer variant, with its drawers pulled out and a carcass of
the object's depth instead of one stretched over the drawers (1.56x here without the search).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from testsupport.observations import observe_model, yaw_pose

from cad_replacement.cad.layouts import layout_variants, parse_variant_key, variant_entry, variant_key
from cad_replacement.cad.library import CadEntry
from cad_replacement.cad.procedural import build_model
from cad_replacement.replace_config import CadReplacementConfig
from cad_replacement.replace_object import replace_object
from cad_replacement.seeded_library import SeededLibrary
from scene_recon.evaluation.cad_metrics import extents_along

SEED = 38  # cabinet 38: "doors", 0.70 m wide (two doors)
DRAWERS = {"layout": "drawers", "drawer_count": 4}


@pytest.fixture(scope="module")
def library(tmp_path_factory: pytest.TempPathFactory) -> SeededLibrary:
    return SeededLibrary(cache_dir=tmp_path_factory.mktemp("cad"), seeds_per_class=0, classes=["cabinet"],
                         extra_seeds={"cabinet": [SEED]})


def test_variant_keys_round_trip_and_rebuild(library: SeededLibrary) -> None:
    (base,) = library.entries("cabinet")
    variant = variant_entry(base, DRAWERS)
    assert variant.key == variant_key(base.key, DRAWERS) == f"{base.key}@drawer_count=4;layout=drawers"
    assert parse_variant_key(variant.key) == (base.key, DRAWERS)
    assert library.entry(variant.key) == variant
    assert library.entry(base.key) == base
    assert library.entry("procedural/cabinet/cabinet_s0099@layout=drawers") is None  # no such base model
    assert library.entry(f"{base.key}@layout=sliding") is None  # not a layout of the class
    model = library.model(variant)
    assert sorted(j.type for j in model.movable_joints) == ["prismatic"] * 4
    assert model.params["layout"] == "drawers"
    # the carcass is the base model's: the same seed draws the same sizes
    assert np.allclose(model.size, library.model(base).size, atol=0.01)
    assert library.digest(variant) != library.digest(base)


def test_variant_entry_rejects_what_the_class_table_does_not_have(library: SeededLibrary) -> None:
    (base,) = library.entries("cabinet")
    with pytest.raises(ValueError, match="no parameter"):
        variant_entry(base, {"doors_count": 2})
    with pytest.raises(ValueError, match="must be one of"):
        variant_entry(base, {"layout": "sliding"})
    with pytest.raises(ValueError, match="only procedural"):
        variant_entry(CadEntry("urdf/cabinet/x", "cabinet", "urdf", path=Path("x.urdf")), DRAWERS)


def test_layout_variants_leave_out_the_models_own_layout(library: SeededLibrary) -> None:
    (base,) = library.entries("cabinet")
    own = build_model("cabinet", SEED).params
    variants = layout_variants(base)
    assert variants and all(v.key.startswith(base.key + "@") for v in variants)
    assert not any(dict(v.overrides) == {"layout": own["layout"], "hinge_side": own["hinge_side"]} for v in variants)
    assert layout_variants(variant_entry(base, DRAWERS))  # a variant has variants too
    assert layout_variants(CadEntry("procedural/cup/cup_s0000", "cup", "procedural", seed=0)) == []


def _observe_drawer_cabinet(openings: list[float]) -> tuple[object, np.ndarray, object]:
    obj = build_model("cabinet", SEED, overrides=DRAWERS).scaled([1.04, 0.97, 1.0])
    drawers = sorted(j.name for j in obj.movable_joints)
    values = dict(zip(drawers, openings, strict=True))
    pose = yaw_pose(0.4, (1.0, -0.5, 0.0))
    obs, _ = observe_model(obj, pose, values, np.random.default_rng(5))
    return obj, pose, obs


def test_open_drawers_find_the_drawer_front(library: SeededLibrary) -> None:
    obj, pose, obs = _observe_drawer_cabinet([0.22, 0.15, 0.25, 0.18])
    found = replace_object(obs, library, CadReplacementConfig())
    plain = replace_object(obs, library, CadReplacementConfig(layout_search=False))
    assert found.chosen is not None and plain.chosen is not None
    assert "@" in found.chosen.key and "@" not in plain.chosen.key
    assert found.model is not None
    # A drawer front; its count within one of the truth: four drawers pulled out to different
    # depths, seen from one side with 5 mm noise, fit a stack of five about as well (AE 11 vs 12 mm).
    types = [j.type for j in found.model.movable_joints]
    assert set(types) == {"prismatic"} and len(types) in (4, 5), types
    opened = np.array(list(found.joint_values.values()))
    assert np.all((opened > 0.1) & (opened < 0.3)), found.joint_values  # every drawer found pulled out
    # the carcass keeps the object's depth (the library's doors cannot open like drawers: its fit stretched)
    depth = extents_along(pose[:3, :3], found.chosen.pose[:3, :3], found.chosen.scale * found.model.size)[0]
    assert plain.model is not None
    stretched = extents_along(pose[:3, :3], plain.chosen.pose[:3, :3], plain.chosen.scale * plain.model.size)[0]
    assert abs(depth - obj.size[0]) / obj.size[0] <= 0.10, (depth, obj.size)
    assert abs(depth - obj.size[0]) < abs(stretched - obj.size[0])
    assert found.chosen.ae.ae < plain.chosen.ae.ae
    # the variant's key names a model the library rebuilds (replacement.json -> evaluation, export)
    entry = library.entry(found.chosen.key)
    assert entry is not None and library.model(entry).params["layout"] == "drawers"


def test_a_closed_front_keeps_the_library_model(library: SeededLibrary) -> None:
    _obj, _pose, obs = _observe_drawer_cabinet([0.0, 0.0, 0.0, 0.0])
    rep = replace_object(obs, library, CadReplacementConfig())
    assert rep.chosen is not None and "@" not in rep.chosen.key
    assert all(r.match.entry.overrides == () for r in rep.candidates)  # not even searched


def test_layout_settings_are_validated() -> None:
    with pytest.raises(ValueError, match="layout_margin"):
        CadReplacementConfig(layout_margin=-0.1)
    for bad in ({"layout_outlier_m": 0.0}, {"layout_outlier_share": 1.5}, {"layout_fits": -1}):
        with pytest.raises(ValueError, match="layout_outlier_m"):
            CadReplacementConfig(**bad)
