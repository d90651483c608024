"""Generic mesh features: RANSAC planes, gravity-aligned box, support surfaces."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cad_replacement.cad import (
    ModelFeatures,
    build_model,
    extract_planes,
    find_support_surfaces,
    gravity_aligned_box,
    model_mesh_features,
)
from cad_replacement.cad.feature_types import Plane, SupportSurface

EXTENTS = np.array([1.0, 0.8, 0.6])
OFFSET = np.array([0.2, -0.1, 0.3])


def _box() -> trimesh.Trimesh:
    box = trimesh.creation.box(extents=EXTENTS)
    box.apply_translation(OFFSET)
    return box


def _expected_faces() -> list[tuple[np.ndarray, float]]:
    faces = []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            n = np.zeros(3)
            n[axis] = sign
            coord = OFFSET[axis] + sign * 0.5 * EXTENTS[axis]
            faces.append((n, -sign * coord))
    return faces


def _match(planes: list[Plane], normal: np.ndarray, d: float, tol: float = 0.01) -> bool:
    return any(p.normal @ normal > 0.999 and abs(p.d - d) < tol for p in planes)


def test_ransac_recovers_box_faces_with_outward_normals() -> None:
    planes = extract_planes(_box(), seed=1)
    assert len(planes) == 6
    for n, d in _expected_faces():
        assert _match(planes, n, d), (n, d)
    centre = OFFSET
    assert all(p.signed_distance(centre)[0] < 0.0 for p in planes)
    assert sum(p.area for p in planes) == pytest.approx(_box().area, rel=0.05)


def test_ransac_on_points_without_normals_orients_away_from_centroid() -> None:
    rng = np.random.default_rng(0)
    pts, _ = trimesh.sample.sample_surface(_box(), 3000, seed=2)
    pts = pts + rng.normal(0.0, 0.003, pts.shape)  # sensor-like noise
    planes = extract_planes(pts, seed=3)
    assert len(planes) >= 5
    for p in planes:
        assert any(p.normal @ n > 0.99 and abs(p.d - d) < 0.02 for n, d in _expected_faces())


def test_ransac_stops_below_min_fraction_and_is_deterministic() -> None:
    a = extract_planes(_box(), seed=7, min_inlier_fraction=0.2)
    assert 1 <= len(a) < 6  # the smaller faces hold < 20 % of the area
    b = extract_planes(_box(), seed=7, min_inlier_fraction=0.2)
    assert [p.as_vector().tolist() for p in a] == [p.as_vector().tolist() for p in b]
    assert extract_planes(np.zeros((2, 3))) == []


def test_gravity_aligned_box_finds_yaw() -> None:
    box = _box()
    box.apply_transform(trimesh.transformations.rotation_matrix(0.3, (0, 0, 1)))
    ob = gravity_aligned_box(box.vertices)
    assert ob.yaw == pytest.approx(0.3, abs=1e-6)
    assert ob.size == pytest.approx(EXTENTS, abs=1e-6)
    rotated_back = (box.vertices - ob.center) @ ob.rotation()
    assert np.ptp(rotated_back, axis=0) == pytest.approx(EXTENTS, abs=1e-6)
    flat = gravity_aligned_box(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.5]]))  # degenerate hull
    assert flat.size[2] == pytest.approx(0.5)


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
