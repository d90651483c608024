"""RANSAC planes with outward normals (shared by the contact graph and the CAD library) and box fitting."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from recon_core.geometry.box_fit import fit_gravity_box
from recon_core.geometry.plane import Plane
from recon_core.geometry.plane_fit import extract_planes

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


@pytest.mark.parametrize("seed", range(5))
def test_preemptive_scoring_finds_the_planes_of_full_scoring(seed: int) -> None:
    """Ranking hypotheses on a subset must not change which planes are found (only the cost)."""
    rng = np.random.default_rng(seed)
    pts, fi = trimesh.sample.sample_surface(_box(), 3000, seed=seed)
    nrm = _box().face_normals[fi]
    pts = pts + rng.normal(0.0, 0.004, pts.shape)
    full = extract_planes(pts, normals=nrm, distance_threshold=0.012, seed=seed, score_subset=0)
    fast = extract_planes(pts, normals=nrm, distance_threshold=0.012, seed=seed)
    assert len(fast) == len(full) == 6
    for p in fast:
        assert any(p.normal @ q.normal > 0.999 and abs(p.d - q.d) < 0.003 for q in full)
    assert sum(p.area for p in fast) == pytest.approx(sum(p.area for p in full), rel=0.03)


def test_fit_gravity_box_finds_yaw_of_a_mesh() -> None:
    box = _box()
    box.apply_transform(trimesh.transformations.rotation_matrix(0.3, (0, 0, 1)))
    ob = fit_gravity_box(box.vertices)
    assert ob.yaw == pytest.approx(0.3, abs=1e-6)
    assert ob.size == pytest.approx(EXTENTS, abs=1e-6)
    rotated_back = (box.vertices - ob.center) @ ob.rotation()
    assert np.ptp(rotated_back, axis=0) == pytest.approx(EXTENTS, abs=1e-6)
    flat = fit_gravity_box(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.5]]))  # degenerate hull
    assert flat.size[2] == pytest.approx(0.5)
