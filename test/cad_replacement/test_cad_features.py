"""CAD model features: support surfaces, feature bundles and their JSON round trip."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

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


def _box(lo: tuple[float, float, float], hi: tuple[float, float, float]) -> trimesh.Trimesh:
    return trimesh.creation.box(bounds=[lo, hi])


def test_support_surfaces_of_imported_meshes_are_real_horizontal_surfaces() -> None:
    """A board in 16 disconnected tiles (1 mm joints, +-1.5 mm height jitter) is one surface; a
    2 cm rail, a U-shaped rim of 2 cm strips and a 10 degree ramp are none."""
    rng = np.random.default_rng(3)
    parts = []
    for i in range(4):
        for j in range(4):
            top = 0.7 + rng.uniform(-0.0015, 0.0015)
            tile = _box((0.2 * i + 0.0005, 0.125 * j + 0.0005, top - 0.02), (0.2 * i + 0.1995, 0.125 * j + 0.1245, top))
            v, f = trimesh.remesh.subdivide_to_size(tile.vertices, tile.faces, max_edge=0.03)
            parts.append(trimesh.Trimesh(v, f))
    parts.append(_box((0.0, 0.6, 0.28), (0.8, 0.62, 0.3)))  # rail: 0.016 m^2, but 2 cm wide
    parts += [_box((0.0, -1.0, 0.48), (0.8, -0.98, 0.5)), _box((0.0, -1.5, 0.48), (0.02, -1.0, 0.5)),
              _box((0.78, -1.5, 0.48), (0.8, -1.0, 0.5))]  # rim: hull 0.4 m^2, faces 0.036 m^2
    ramp = _box((-0.25, -0.25, -0.01), (0.25, 0.25, 0.01))
    ramp.apply_transform(trimesh.transformations.rotation_matrix(np.radians(10.0), (0.0, 1.0, 0.0)))
    ramp.apply_translation((2.0, 0.0, 0.5))
    parts.append(ramp)
    mesh = trimesh.util.concatenate(parts)
    found = find_support_surfaces(mesh)
    assert len(found) == 1
    assert found[0].height == pytest.approx(0.7, abs=0.002)
    assert found[0].area == pytest.approx(0.8 * 0.5, rel=0.01)
    # Each filter on its own: disabled, its pieces come back.
    assert len(find_support_surfaces(mesh, merge_gap=0.0)) == 16
    assert sorted(s.height for s in find_support_surfaces(mesh, min_width=0.0)) == pytest.approx([0.3, 0.7], abs=0.002)
    assert sorted(s.height for s in find_support_surfaces(mesh, min_fill=0.0)) == pytest.approx([0.5, 0.7], abs=0.002)
    sloped = [s for s in find_support_surfaces(mesh, max_relief=1.0) if s.height != found[0].height]
    assert sloped and all(np.mean(s.polygon[:, 0]) > 1.7 for s in sloped)  # on the ramp
