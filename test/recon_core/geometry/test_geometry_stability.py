"""Numerical stability of the core geometry kernels under degenerate and extreme inputs (hypothesis).

Boxes, IoU, the gravity-aligned box fit, RANSAC planes, rigid transforms and box inertia, fed
collinear/coplanar/single points, tiny (1e-4 m) and huge (1e3 m) objects, scenes far from the
origin (up to 1e6 m) and float32 input. Every property says: the result is finite (never NaN/inf)
and geometrically right within a tolerance that follows float64 precision at that magnitude, or the
kernel raises a clear error. Examples are bounded and derandomized (deterministic in CI).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from recon_core.errors import EntityError
from recon_core.geometry.box import GravityBox, iou_matrix
from recon_core.geometry.box_fit import fit_gravity_box, min_area_rectangle_yaw
from recon_core.geometry.plane import Plane
from recon_core.geometry.plane_fit import extract_planes
from recon_core.geometry.transforms import invert_rigid, is_rigid, rotation_about, transform_points, unit
from recon_core.kinematic_tree import box_inertia

STABILITY = settings(max_examples=25, deadline=None, derandomize=True,
                     suppress_health_check=[HealthCheck.too_slow])

yaws = st.floats(-np.pi, np.pi, allow_nan=False)
#: Object sizes from a 0.1 mm part to a 1 km building (metres).
sizes = st.floats(1e-4, 1e3)
#: Where a scene sits: at the origin up to 1000 km away (UTM-like coordinates).
offsets = st.tuples(*[st.floats(-1e6, 1e6)] * 3)


def _box_points(center, size, yaw, n=200, seed=0):
    rng = np.random.default_rng(seed)
    local = (rng.random((n, 3)) - 0.5) * size
    local[:8] = 0.5 * size * np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    c, s = np.cos(yaw), np.sin(yaw)
    r = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return local @ r.T + center


def _abs_tol(*magnitudes: float) -> float:
    """What float64 can resolve at these magnitudes (a few hundred ulps), at least 1e-9 m."""
    return max(1e-9, 512 * np.finfo(np.float64).eps * max(abs(float(m)) for m in magnitudes))


# ---------------------------------------------------------------------------- box fit
@STABILITY
@given(size=st.tuples(sizes, sizes, sizes), yaw=yaws, offset=offsets)
def test_box_fit_recovers_any_box_any_scale_anywhere(size, yaw, offset):
    size, offset = np.array(size), np.array(offset)
    pts = _box_points(offset, size, yaw)
    box = fit_gravity_box(pts)
    assert np.all(np.isfinite(box.center)) and np.all(np.isfinite(box.size)) and np.isfinite(box.yaw)
    tol = _abs_tol(*offset, *size) + 1e-6 * size.max()
    np.testing.assert_allclose(box.center, offset, atol=tol * 4)
    # the minimal box never has a larger footprint than the true one (up to what float64 resolves)
    assert box.size[0] * box.size[1] <= size[0] * size[1] * (1 + 1e-6) + tol * size.max() * 4
    assert box.size[2] == pytest.approx(size[2], abs=tol * 4)
    assert -np.pi / 4 - 1e-12 <= box.yaw <= np.pi / 4 + 1e-12


@STABILITY
@given(n=st.integers(2, 60), direction=yaws, offset=offsets, length=sizes,
       dz=st.floats(0.0, 10.0))
def test_box_fit_of_collinear_points_is_a_flat_finite_box_along_the_line(n, direction, offset, length, dz):
    t = np.linspace(-0.5, 0.5, n)[:, None]
    d = np.array([np.cos(direction), np.sin(direction), 0.0])
    pts = np.asarray(offset) + t * length * d + np.c_[np.zeros(n), np.zeros(n), np.linspace(0, dz, n)]
    box = fit_gravity_box(pts)
    assert np.all(np.isfinite(box.size)) and np.isfinite(box.yaw)
    tol = _abs_tol(*offset, length)
    assert min(box.size[0], box.size[1]) <= tol * 8 + 1e-9 * length  # zero width
    assert max(box.size[0], box.size[1]) == pytest.approx(length, abs=tol * 8 + 1e-9 * length)
    assert GravityBox(box.center, box.size, box.yaw).iou(box) in (0.0, 1.0) or box.volume > 0


@STABILITY
@given(offset=offsets, n=st.integers(1, 30))
def test_box_fit_of_one_repeated_point_is_a_zero_box_at_it(offset, n):
    pts = np.repeat(np.asarray(offset, float)[None], n, axis=0)
    box = fit_gravity_box(pts)
    np.testing.assert_allclose(box.center, offset)
    np.testing.assert_allclose(box.size, 0.0, atol=_abs_tol(*offset))
    assert box.iou(box) == 0.0  # no volume: IoU 0, never NaN


@STABILITY
@given(size=st.tuples(st.floats(0.01, 5), st.floats(0.01, 5), st.floats(0.01, 5)), yaw=yaws,
       offset=st.tuples(*[st.floats(-1e4, 1e4)] * 3))
def test_box_fit_float32_input_agrees_with_float64(size, yaw, offset):
    pts = _box_points(np.array(offset), np.array(size), yaw)
    b64 = fit_gravity_box(pts)
    b32 = fit_gravity_box(pts.astype(np.float32))
    # float32 rounds coordinates by half an ulp at the offset's magnitude: the boxes agree to that
    tol = 4 * np.finfo(np.float32).eps * max(1.0, np.abs(offset).max())
    np.testing.assert_allclose(b32.center, b64.center, atol=tol)
    np.testing.assert_allclose(np.sort(b32.size[:2]), np.sort(b64.size[:2]), atol=2 * tol + 1e-3 * max(size))


def test_box_fit_rejects_empty_and_non_finite_points():
    with pytest.raises(EntityError):
        fit_gravity_box(np.zeros((0, 3)))
    with pytest.raises(EntityError):
        fit_gravity_box([[0, 0, 0], [np.nan, 1, 1], [1, 1, 1]])
    with pytest.raises(EntityError):
        fit_gravity_box([[0, 0, 0], [np.inf, 1, 1], [1, 1, 1]])


@STABILITY
@given(xy=st.lists(st.tuples(st.floats(-1e6, 1e6), st.floats(-1e6, 1e6)), min_size=0, max_size=12))
def test_min_area_rectangle_yaw_is_finite_for_any_point_set(xy):
    yaw = min_area_rectangle_yaw(np.array(xy, float).reshape(-1, 2))
    assert np.isfinite(yaw) and abs(yaw) <= np.pi / 4 + 1e-12


# ---------------------------------------------------------------------------- IoU
@STABILITY
@given(size=st.tuples(sizes, sizes, sizes), yaw=yaws, offset=offsets, shift=st.floats(0.0, 2.0))
def test_iou_is_in_unit_interval_symmetric_and_one_with_itself(size, yaw, offset, shift):
    a = GravityBox(offset, size, yaw)
    b = GravityBox(np.asarray(offset) + shift * np.asarray(size), size, yaw + 0.3)
    for x, y in ((a, b), (b, a), (a, a)):
        v = x.iou(y)
        assert np.isfinite(v) and 0.0 <= v <= 1.0 + 1e-9
    assert a.iou(b) == pytest.approx(b.iou(a), abs=1e-9)
    assert a.iou(a) == pytest.approx(1.0, abs=1e-6)
    m = iou_matrix([a, b], [a, b])
    assert np.all(np.isfinite(m)) and np.all((m >= 0) & (m <= 1 + 1e-9))


@STABILITY
@given(size=st.tuples(sizes, sizes, sizes), yaw=yaws, zero_axis=st.integers(0, 2), offset=offsets)
def test_iou_of_flat_boxes_is_zero_never_nan(size, yaw, zero_axis, offset):
    s = np.array(size)
    s[zero_axis] = 0.0
    a = GravityBox(offset, s, yaw)
    assert a.iou(a) == 0.0
    assert a.iou(GravityBox(offset, size, yaw)) == 0.0


def test_box_rejects_non_finite_and_negative_sizes():
    for center, size, yaw in (([np.nan, 0, 0], [1, 1, 1], 0.0), ([0, 0, 0], [1, np.inf, 1], 0.0),
                              ([0, 0, 0], [1, 1, 1], np.nan), ([0, 0, 0], [1, -1, 1], 0.0)):
        with pytest.raises(ValueError):
            GravityBox(center, size, yaw)


# ---------------------------------------------------------------------------- planes and RANSAC
@STABILITY
@given(tilt_deg=st.floats(0.0, 90.0), azimuth=yaws, offset=st.tuples(*[st.floats(-1e4, 1e4)] * 3),
       extent=st.floats(0.05, 50.0))
def test_ransac_finds_a_plane_at_any_tilt_up_to_vertical_and_far_away(tilt_deg, azimuth, offset, extent):
    rng = np.random.default_rng(0)
    t = np.radians(tilt_deg)
    n = np.array([np.sin(t) * np.cos(azimuth), np.sin(t) * np.sin(azimuth), np.cos(t)])
    u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    ab = (rng.random((400, 2)) - 0.5) * extent
    pts = np.asarray(offset) + ab[:, :1] * u + ab[:, 1:] * v
    planes = extract_planes(pts, distance_threshold=max(1e-3, 1e-3 * extent), iterations=50)
    assert planes, "a clean plane must be found"
    p = planes[0]
    assert np.all(np.isfinite(p.normal)) and np.isfinite(p.d)
    assert abs(abs(float(p.normal @ n)) - 1.0) < 1e-6
    # every input point lies on it (float64 resolves the offset to ~1e-12 relative)
    assert np.abs(p.signed_distance(pts)).max() < 1e-6 * max(1.0, np.abs(offset).max())
    assert p.area == pytest.approx(1.0)


@STABILITY
@given(n=st.integers(0, 50), offset=offsets, direction=st.tuples(*[st.floats(-1, 1)] * 3))
def test_ransac_on_collinear_or_coincident_points_returns_no_plane_not_nan(n, offset, direction):
    d = np.asarray(direction, float)
    pts = np.asarray(offset) + np.linspace(0, 1, n)[:, None] * d
    planes = extract_planes(pts, iterations=30)
    for p in planes:  # a line lies on many planes: any found must be finite and contain the line
        assert np.all(np.isfinite(p.normal)) and np.isfinite(p.d)
    assert planes == [] or np.linalg.norm(d) < 1e-9 or all(
        np.abs(p.signed_distance(pts)).max() < 0.03 + 1e-9 for p in planes)


def test_ransac_with_zero_normals_does_not_divide_by_zero():
    rng = np.random.default_rng(1)
    pts = np.c_[rng.random((300, 2)), np.zeros(300)]
    normals = np.zeros_like(pts)
    normals[:150, 2] = 1.0  # half the normals unknown (zero vectors)
    with np.errstate(all="raise"):
        planes = extract_planes(pts, normals=normals, iterations=30, min_inlier_fraction=0.3)
    assert planes and np.allclose(planes[0].normal, [0, 0, 1])


def test_plane_rejects_zero_and_non_finite_normals():
    for normal in ([0, 0, 0], [np.nan, 0, 1], [0, np.inf, 0], [1e-300, 0, 0]):
        with pytest.raises(ValueError):
            Plane(normal=normal, d=0.0)


@STABILITY
@given(scale=st.floats(1e-9, 1e9), direction=st.tuples(*[st.floats(-1, 1)] * 3), d=st.floats(-1e6, 1e6))
def test_plane_normalises_any_scale_of_normal(scale, direction, d):
    v = np.asarray(direction, float)
    if np.linalg.norm(v) < 1e-3:
        return
    p = Plane(normal=v * scale, d=d * scale)
    assert np.linalg.norm(p.normal) == pytest.approx(1.0, abs=1e-12)
    assert p.d == pytest.approx(d / np.linalg.norm(v), rel=1e-9, abs=1e-9)


# ---------------------------------------------------------------------------- transforms
unit_axes = st.tuples(*[st.floats(-1, 1)] * 3).filter(lambda a: np.linalg.norm(a) > 1e-3)


@STABILITY
@given(axis=unit_axes, angle=st.floats(-10 * np.pi, 10 * np.pi), offset=offsets,
       axis_scale=st.floats(1e-9, 1e9))
def test_rotation_about_is_rigid_and_inverts_exactly(axis, angle, offset, axis_scale):
    t = rotation_about(np.asarray(axis) * axis_scale, angle)
    t[:3, 3] = offset
    assert is_rigid(t)
    inv = invert_rigid(t)
    np.testing.assert_allclose(inv @ t, np.eye(4), atol=_abs_tol(*offset) * 4)
    pts = np.asarray(offset) + np.eye(3)
    back = transform_points(inv, transform_points(t, pts))
    np.testing.assert_allclose(back, pts, atol=_abs_tol(*offset) * 8)


@pytest.mark.parametrize("bad", [[0, 0, 0], [1e-13, 0, 0], [np.nan, 1, 0], [np.inf, 0, 0]])
def test_unit_and_rotation_about_refuse_zero_or_non_finite_axes(bad):
    with pytest.raises(ValueError):
        unit(bad)
    with pytest.raises(ValueError):
        rotation_about(bad, 0.3)


# ---------------------------------------------------------------------------- inertia
@STABILITY
@given(mass=st.floats(1e-6, 1e4), extents=st.tuples(st.floats(0, 100), st.floats(0, 100), st.floats(0, 100)))
def test_box_inertia_is_finite_positive_definite_and_obeys_the_triangle_inequality(mass, extents):
    inertia = box_inertia(mass, extents)
    d = np.diag(inertia)
    assert np.all(np.isfinite(inertia)) and np.all(d > 0)  # zero extents are clamped: simulators need > 0
    tol = 1e-12 * d.sum()
    assert d[0] + d[1] >= d[2] - tol and d[1] + d[2] >= d[0] - tol and d[0] + d[2] >= d[1] - tol
