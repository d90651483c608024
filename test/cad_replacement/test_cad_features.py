"""CAD model features: support surfaces, feature bundles and their JSON round trip."""

from __future__ import annotations

import pytest

from cad_replacement.cad import ModelFeatures, build_model, find_support_surfaces, model_mesh_features
from cad_replacement.cad.feature_types import SupportSurface


def test_support_surfaces_of_a_shelf_match_the_analytic_ones() -> None:
    model = build_model("shelf", 4)
    found = find_support_surfaces(model.mesh())
    analytic = model.features.support_surfaces
    for s in analytic:
        match = [f for f in found if abs(f.height - s.height) < 1e-6]
        assert match, s.height
        assert match[0].area == pytest.approx(s.area, rel=0.05)
        if s.clearance is None:
            assert match[0].clearance is None
        else:
            assert match[0].clearance == pytest.approx(s.clearance, abs=1e-3)


def test_enclosed_fridge_shelves_are_detected() -> None:
    model = build_model("fridge", 0)
    feats = model_mesh_features(model)
    inner = [s for s in feats.support_surfaces if s.height < 0.9 * model.size[2]]
    assert inner and all(s.enclosed for s in inner)
    top = max(feats.support_surfaces, key=lambda s: s.height)
    assert top.height == pytest.approx(model.size[2]) and not top.enclosed and top.clearance is None


def test_features_json_round_trip_and_scaling() -> None:
    f = build_model("cabinet", 1).features
    g = ModelFeatures.from_dict(f.to_dict())
    assert g.plane_array() == pytest.approx(f.plane_array())
    assert [s.to_dict() for s in g.support_surfaces] == [s.to_dict() for s in f.support_surfaces]
    s = f.scaled([2.0, 1.0, 0.5])
    assert s.box_size == pytest.approx(f.box_size * [2.0, 1.0, 0.5])
    top = SupportSurface(height=1.0, polygon=[[0, 0], [0, 1], [1, 1], [1, 0]])  # clockwise input
    assert top.area == pytest.approx(1.0) and top.contains([[0.5, 0.5], [2.0, 0.5]]).tolist() == [True, False]
