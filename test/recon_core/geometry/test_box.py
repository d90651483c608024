"""Minimal gravity-aligned boxes, exact yaw-box IoU and the convex polygon helpers."""

from __future__ import annotations

import numpy as np
import pytest
from shapely.geometry import Polygon

from recon_core.errors import EntityError
from recon_core.geometry.box import GravityBox, iou_matrix
from recon_core.geometry.box_fit import fit_gravity_box, min_area_rectangle_yaw
from recon_core.geometry.polygon import clip_convex, polygon_area, polygon_distance, rectangle, rectangles_overlap


def _rotated_cuboid_points(size, yaw, center, n=2000, seed=0):
    rng = np.random.default_rng(seed)
    local = (rng.uniform(-0.5, 0.5, (n, 3)) * size)
    corners = np.array([[sx, sy, sz] for sx in (-0.5, 0.5) for sy in (-0.5, 0.5) for sz in (-0.5, 0.5)]) * size
    local = np.r_[local, corners]
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return local @ rot.T + center


@pytest.mark.parametrize("yaw", [0.0, 0.3, -0.7, 1.2, np.pi / 4])
def test_box_of_a_rotated_cuboid_is_exact(yaw):
    size, center = np.array([1.2, 0.5, 0.8]), np.array([1.0, -2.0, 0.4])
    box = fit_gravity_box(_rotated_cuboid_points(size, yaw, center))
    truth = GravityBox(center, size, yaw)
    assert box.iou(truth) == pytest.approx(1.0, abs=1e-9)
    assert -np.pi / 4 - 1e-12 <= box.yaw <= np.pi / 4 + 1e-12


def test_min_area_rectangle_beats_every_sampled_angle():
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(300, 2)) * [2.0, 0.5]
    yaw = min_area_rectangle_yaw(pts)

    def area(a):
        c, s = np.cos(a), np.sin(a)
        u, v = pts @ [c, s], pts @ [-s, c]
        return np.ptp(u) * np.ptp(v)

    assert area(yaw) <= min(area(a) for a in np.linspace(0, np.pi / 2, 2000)) + 1e-9


def test_trimming_ignores_outliers():
    pts = _rotated_cuboid_points(np.array([1.0, 0.6, 0.5]), 0.4, np.zeros(3), n=5000)
    noisy = np.r_[pts, [[3.0, 3.0, 2.0], [-2.5, 1.0, -1.0], [0.0, -3.0, 0.2]]]
    exact = fit_gravity_box(noisy)
    trimmed = fit_gravity_box(noisy, trim_percent=0.5)
    truth = GravityBox(np.zeros(3), [1.0, 0.6, 0.5], 0.4)
    assert exact.iou(truth) < 0.2
    assert trimmed.iou(truth) > 0.9


def test_degenerate_point_sets():
    with pytest.raises(EntityError, match="empty"):
        fit_gravity_box(np.zeros((0, 3)))
    one = fit_gravity_box([[1.0, 2.0, 3.0]])
    np.testing.assert_allclose(one.center, [1, 2, 3])
    np.testing.assert_allclose(one.size, 0)
    same = fit_gravity_box([[1.0, 2.0, 3.0]] * 10)
    np.testing.assert_allclose(same.size, 0)
    line = fit_gravity_box([[0, 0, 0], [1, 1, 0], [2, 2, 0.5]])
    assert line.size[0] == pytest.approx(np.hypot(2, 2)) and line.size[1] == pytest.approx(0, abs=1e-12)
    assert line.yaw == pytest.approx(np.pi / 4)
    flat = fit_gravity_box([[0, 0, 1], [1, 0, 1], [1, 2, 1], [0, 2, 1]])
    np.testing.assert_allclose(flat.size, [1, 2, 0], atol=1e-12)
    for b in (one, same, line, flat):
        assert b.iou(b) in (0.0, 1.0) and np.isfinite(b.iou(b))  # zero volume -> 0, never NaN


def test_iou_matches_shapely_times_z_overlap():
    rng = np.random.default_rng(7)
    for _ in range(200):
        a = GravityBox(rng.uniform(-1, 1, 3), rng.uniform(0.1, 1.5, 3), rng.uniform(-np.pi, np.pi))
        b = GravityBox(rng.uniform(-1, 1, 3), rng.uniform(0.1, 1.5, 3), rng.uniform(-np.pi, np.pi))
        inter2d = Polygon(a.corners_xy()).intersection(Polygon(b.corners_xy())).area
        inter = inter2d * a.z_overlap(b)
        expected = inter / (a.volume + b.volume - inter)
        assert a.iou(b) == pytest.approx(expected, abs=1e-9)
        assert rectangles_overlap(a.corners_xy(), b.corners_xy()) == (inter2d > 0 or
                                                                       Polygon(a.corners_xy()).intersects(
                                                                           Polygon(b.corners_xy())))


def test_iou_matrix_and_quarter_turns():
    a = GravityBox([0, 0, 0.5], [2, 1, 1], 0.0)
    turned = GravityBox([0, 0, 0.5], [1, 2, 1], np.pi / 2)  # the same box described differently
    far = GravityBox([10, 0, 0.5], [1, 1, 1], 0.3)
    m = iou_matrix([a], [turned, far])
    np.testing.assert_allclose(m, [[1.0, 0.0]], atol=1e-12)


def test_clip_and_distance_helpers():
    sq = rectangle([0, 0], [2, 2], 0.0)
    diamond = rectangle([1, 1], [2, 2], np.pi / 4)
    inter = clip_convex(sq, diamond)
    assert polygon_area(inter) == pytest.approx(Polygon(sq).intersection(Polygon(diamond)).area)
    assert len(clip_convex(sq, rectangle([5, 5], [1, 1], 0.0))) == 0
    assert polygon_distance(sq, rectangle([3, 0], [1, 1], 0.0)) == pytest.approx(1.5)
    assert polygon_distance(sq, diamond) == 0.0
    # Degenerate polygons: separated points and a point on a segment's line beyond its end.
    assert not rectangles_overlap([[0, 0]] * 4, [[1, 1]] * 4)
    assert not rectangles_overlap([[0, 0], [1, 0], [1, 0], [0, 0]], [[2, 0]] * 4)
    assert rectangles_overlap([[0, 0], [1, 0], [1, 0], [0, 0]], [[0.5, 0]] * 4)
