"""Numerical stability of stage-2 kernels (hypothesis): quaternions and TF interpolation, gravity
estimation, TSDF integration and label voting, on degenerate and extreme inputs.

Bounded and derandomized (deterministic in CI). The TSDF far-from-origin property documents the
limit of 2 cm voxels in Open3D's float32 voxel grid (README "Benchmarks and presets").
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from panoptic_mapping.config import TSDFConfig
from panoptic_mapping.dataio.transforms import make_transform, matrix_to_quat, quat_to_matrix, slerp
from panoptic_mapping.gravity import GravityConfig, GravityEstimator, angle_deg, rotation_to_z
from panoptic_mapping.tsdf_map import LabeledTSDF
from recon_core.frame import CameraIntrinsics

STABILITY = settings(max_examples=25, deadline=None, derandomize=True,
                     suppress_health_check=[HealthCheck.too_slow])
quats = st.tuples(*[st.floats(-1.0, 1.0)] * 4).filter(lambda q: np.linalg.norm(q) > 1e-3)
vectors = st.tuples(*[st.floats(-1.0, 1.0)] * 3).filter(lambda v: np.linalg.norm(v) > 1e-3)


def _orthonormal(r: np.ndarray, tol: float) -> bool:
    return bool(np.allclose(r @ r.T, np.eye(3), atol=tol) and abs(np.linalg.det(r) - 1.0) < tol)


# ---------------------------------------------------------------------------- quaternions
@STABILITY
@given(q=quats, scale=st.floats(1e-6, 1e6), f32=st.booleans())
def test_quaternion_round_trip_any_scale_and_precision(q, scale, f32):
    q = np.asarray(q) * scale
    r = quat_to_matrix(q.astype(np.float32) if f32 else q)
    assert _orthonormal(r, 1e-6 if f32 else 1e-12)
    back = matrix_to_quat(r)
    assert np.linalg.norm(back) == pytest.approx(1.0, abs=1e-12) and back[3] >= 0
    np.testing.assert_allclose(quat_to_matrix(back), r, atol=1e-12)


@STABILITY
@given(axis=vectors, eps=st.floats(0.0, 1e-6))
def test_matrix_to_quat_near_half_turns(axis, eps):
    # rotations by ~180 deg: the trace is ~-1, where naive formulas divide by ~0
    r = Rotation.from_rotvec(np.asarray(axis) / np.linalg.norm(axis) * (np.pi - eps)).as_matrix()
    q = matrix_to_quat(r)
    assert np.all(np.isfinite(q))
    np.testing.assert_allclose(quat_to_matrix(q), r, atol=1e-9)


@pytest.mark.parametrize("bad", [[0, 0, 0, 0], [1e-13, 0, 0, 0], [np.nan, 0, 0, 1], [0, 0, np.inf, 1]])
def test_quat_to_matrix_refuses_zero_and_non_finite(bad):
    with pytest.raises(ValueError):
        quat_to_matrix(np.array(bad, float))
    with pytest.raises(ValueError):
        make_transform(np.zeros(3), np.array(bad, float))


@STABILITY
@given(q0=quats, q1=quats, u=st.floats(0.0, 1.0), nearly=st.floats(0.0, 1e-9))
def test_slerp_stays_unit_between_any_pair_even_identical_or_antipodal(q0, q1, u, nearly):
    q0 = np.asarray(q0) / np.linalg.norm(q0)
    for other in (np.asarray(q1), q0 + nearly, -q0):  # arbitrary, (nearly) identical, antipodal
        q = slerp(q0, other, u)
        assert np.all(np.isfinite(q)) and np.linalg.norm(q) == pytest.approx(1.0, abs=1e-9)


# ---------------------------------------------------------------------------- gravity
@STABILITY
@given(up=vectors, scale=st.floats(1e-9, 1e9))
def test_rotation_to_z_takes_any_up_to_z_even_antiparallel(up, scale):
    u = np.asarray(up) * scale
    for v in (u, np.array([0.0, 0.0, -1.0]) + 1e-9 * u, np.array([0.0, 0.0, -scale])):
        r = rotation_to_z(v)
        assert _orthonormal(r, 1e-9)
        np.testing.assert_allclose(r @ (v / np.linalg.norm(v)), [0.0, 0.0, 1.0], atol=1e-9)


@pytest.mark.parametrize("bad", [[0, 0, 0], [np.nan, 0, 1], [0, np.inf, 0]])
def test_rotation_to_z_refuses_a_zero_or_non_finite_up(bad):
    with pytest.raises(ValueError):
        rotation_to_z(np.array(bad, float))


@STABILITY
@given(a=vectors, b=vectors)
def test_angle_deg_is_finite_in_range_for_any_vectors(a, b):
    for x, y in ((a, b), (a, a), (a, -np.asarray(a)), ((0, 0, 0), b)):
        v = angle_deg(np.asarray(x, float), np.asarray(y, float))
        assert np.isfinite(v) and 0.0 <= v <= 180.0


INTR = CameraIntrinsics(200.0, 200.0, 79.5, 59.5, 160, 120)


def _floor_depth(pose: np.ndarray, floor_z: float = 0.0, dtype=np.float32) -> np.ndarray:
    """Depth image (z along the optical axis) of the plane z = floor_z seen from camera-to-world `pose`."""
    v, u = np.mgrid[0:INTR.height, 0:INTR.width].astype(np.float64)
    rays = np.stack([(u - INTR.cx) / INTR.fx, (v - INTR.cy) / INTR.fy, np.ones_like(u)], axis=-1)
    world_dz = rays @ pose[:3, :3].T
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (floor_z - pose[2, 3]) / world_dz[..., 2]
    return np.where((t > 0) & np.isfinite(t), t, 0.0).astype(dtype)


def _camera(pitch_deg: float, yaw: float, roll_deg: float, position) -> np.ndarray:
    """Camera-to-world pose of an optical frame (x right, y down, z forward) looking `pitch_deg` down."""
    base = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]).T  # optical -> world (level, +x ahead)
    r = Rotation.from_euler("ZYX", [yaw, np.radians(pitch_deg), 0.0]).as_matrix() @ base
    r = r @ Rotation.from_rotvec([0.0, 0.0, np.radians(roll_deg)]).as_matrix()
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = r, position
    return t


@STABILITY
@given(pitch=st.floats(20.0, 70.0), roll=st.floats(-10.0, 10.0), yaw=st.floats(-np.pi, np.pi),
       height=st.floats(0.5, 2.5), offset=st.tuples(*[st.floats(-1e5, 1e5)] * 2),
       world_tilt=st.tuples(st.floats(-40.0, 40.0), st.floats(-40.0, 40.0)))
def test_gravity_from_a_floor_any_tilt_far_from_origin_in_float32_depth(pitch, roll, yaw, height, offset, world_tilt):
    tilt = Rotation.from_euler("xy", world_tilt, degrees=True).as_matrix()  # input world -> true (z-up) world
    est = GravityEstimator(GravityConfig(window_frames=3, stride=1))
    for k in range(3):
        pose = _camera(pitch, yaw + 0.4 * k, roll, [offset[0], offset[1], height])
        depth = _floor_depth(pose)
        in_input = np.eye(4)
        in_input[:3, :3] = tilt.T
        est.add_frame(depth, INTR, in_input @ pose)
    e = est.estimate()
    assert e.ok and np.all(np.isfinite(e.up))
    assert angle_deg(e.up, tilt.T @ np.array([0.0, 0.0, 1.0])) < 0.5


@STABILITY
@given(depth_m=st.floats(0.2, 4.0), scale=st.sampled_from([0.0, 1e-30, 1e-12]))
def test_gravity_without_planes_or_with_vanishing_area_gives_no_estimate_not_nan(depth_m, scale):
    est = GravityEstimator(GravityConfig())
    est.add_frame(np.zeros((INTR.height, INTR.width), np.float32), INTR, np.eye(4))  # nothing valid
    e = est.estimate()
    assert not e.ok and np.all(np.isfinite(e.up)) and e.reason
    # a fronto-parallel wall only (one direction): no estimate with a reason; never NaN
    est = GravityEstimator(GravityConfig())
    est.add_frame(np.full((INTR.height, INTR.width), depth_m, np.float32), INTR, _camera(0.0, 0.0, 0.0, [0, 0, 1]))
    if scale:  # near-zero weights (a depth so small the per-sample areas underflow)
        est._weights = [w * scale for w in est._weights]
    e = est.estimate()
    assert np.all(np.isfinite(e.up)) and np.isfinite(e.support)
    assert not e.ok or angle_deg(e.up, [0, 0, 1]) < 1.0


# ---------------------------------------------------------------------------- TSDF
def _tsdf(voxel=0.02) -> LabeledTSDF:
    return LabeledTSDF(TSDFConfig(voxel_size_m=voxel, initial_block_count=2000, min_depth_m=0.1, max_depth_m=4.0))


def _surface_error(offset: np.ndarray, voxel: float = 0.02) -> tuple[float, int]:
    """Largest distance of the meshed surface from the true floor (z = offset_z) after integrating a
    floor seen from 1.2 m above, three views, the whole scene translated by `offset`."""
    tsdf = _tsdf(voxel)
    for k in range(3):
        pose = _camera(50.0, 0.3 * k, 0.0, offset + np.array([0.0, 0.0, 1.2]))
        depth = _floor_depth(pose, floor_z=offset[2])
        tsdf.integrate_depth(depth, INTR.matrix, pose)
    v, _f, _ = tsdf.extract_mesh()
    if len(v) == 0:
        return np.inf, 0
    return float(np.abs(v[:, 2] - offset[2]).max()), len(v)


#: Measured (this module's scene, 2 cm voxels, one alignment to the grid): the surface error is 5.0 mm
#: at the origin (marching cubes on a floor seen obliquely), 5.0-5.4 mm up to 10 km away, 4.6-5.9 mm
#: with 9 % extra vertices at 30 km, 5.8-11.7 mm at 100 km, 10-16 mm at 300 km, 43-63 mm at 1000 km
#: (float32 voxel coordinates).
FAR_LIMIT_M = 1.0e4


@settings(max_examples=8, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(offset=st.tuples(*[st.floats(-FAR_LIMIT_M, FAR_LIMIT_M)] * 3))
def test_tsdf_2cm_voxels_hold_up_to_10km_from_the_origin(offset):
    # the mapper re-centres maps whose first pose is > 1 km away (README: far-away poses); the grid
    # itself holds 10x that: the same surface as at the origin within 1 mm, no spurious vertices
    # compared with the same scene at the same position relative to the voxel grid, near the origin
    # (the marching-cubes error depends on where the floor cuts the voxels: 4.8-7 mm)
    far = np.asarray(offset)
    err0, n0 = _surface_error(far - np.round(far / 0.16) * 0.16)  # 0.16 m: one block of 8 voxels
    err, n = _surface_error(far)
    assert np.isfinite(err) and err0 < 0.02 / 2
    assert err < err0 + 0.001, f"surface {1000 * err:.2f} mm off at {offset} (origin: {1000 * err0:.2f} mm)"
    assert abs(n - n0) <= 0.05 * n0


def test_tsdf_beyond_the_float32_limit_degrades_but_never_emits_nan():
    # 2^20 m (~1000 km): float32 spacing 6 cm > the 2 cm voxel; the grid must not produce NaN/inf
    tsdf = _tsdf()
    offset = np.array([2.0**20, 0.0, 0.0])
    pose = _camera(50.0, 0.0, 0.0, offset + np.array([0.0, 0.0, 1.2]))
    tsdf.integrate_depth(_floor_depth(pose, floor_z=0.0), INTR.matrix, pose)
    v, _f, labels = tsdf.extract_mesh()
    assert np.all(np.isfinite(v)) and len(labels) == len(v)


@STABILITY
@given(weight_scale=st.floats(0.0, 1e-30), depth_m=st.floats(0.0, 1e-3))
def test_tsdf_nothing_in_range_or_zero_weights_integrates_nothing(weight_scale, depth_m):
    tsdf = _tsdf()
    depth = np.full((INTR.height, INTR.width), depth_m, np.float32)  # below min_depth_m: nothing to integrate
    depth[::7, ::5] = np.nan
    assert tsdf.integrate_depth(depth, INTR.matrix, np.eye(4)) == 0
    v, _f, _ = tsdf.extract_mesh()
    assert len(v) == 0
    # integrate once, then scale the weights towards zero: below the mesh threshold nothing is meshed, no NaN
    pose = _camera(50.0, 0.0, 0.0, [0.0, 0.0, 1.2])
    tsdf.integrate_depth(_floor_depth(pose), INTR.matrix, pose)
    w = tsdf.vbg.attribute("weight").numpy()
    w *= weight_scale
    v, _f, _ = tsdf.extract_mesh()
    assert np.all(np.isfinite(v)) and len(v) == 0


@STABILITY
@given(offset=st.tuples(*[st.floats(-1e3, 1e3)] * 3), labels=st.lists(st.integers(0, 5), min_size=1, max_size=60))
def test_label_votes_land_in_the_voxel_of_the_point_far_from_origin(offset, labels):
    tsdf = _tsdf()
    base = np.round(np.asarray(offset) / 0.02) * 0.02  # voxel centres
    pts = base + 0.02 * np.arange(len(labels))[:, None] * np.array([1.0, 0.0, 0.0])
    lab = np.asarray(labels, np.int32)
    for _ in range(2):
        tsdf.integrate_labels(pts, lab)
    got = tsdf.labels_at(pts)
    np.testing.assert_array_equal(got, lab)  # each point its own voxel: its own label, 0 stays unknown
