"""Image codecs and the TF buffer on hand-made inputs."""

from __future__ import annotations

import numpy as np
import pytest

from panoptic_mapping.dataio import CameraIntrinsics, DatasetError, RGBDFrame
from panoptic_mapping.dataio.image_codec import decode_color, decode_depth, encode_color, encode_depth
from panoptic_mapping.dataio.transforms import (
    TransformBuffer,
    TransformLookupError,
    invert_transform,
    make_transform,
    matrix_to_quat,
    quat_to_matrix,
    slerp,
)


@pytest.mark.parametrize("encoding", ["rgb8", "bgr8", "rgba8", "bgra8"])
def test_color_round_trip(encoding):
    rgb = np.random.default_rng(0).integers(0, 256, (5, 7, 3), dtype=np.uint8)
    enc, h, w, step, data = encode_color(rgb, encoding)
    np.testing.assert_array_equal(decode_color(enc, h, w, step, data.tobytes()), rgb)


def test_depth_round_trip_and_errors():
    d = np.array([[0.0, 1.2345, 65.534], [0.001, 2.0, np.nan]], np.float32)
    enc, h, w, step, data = encode_depth(d, "16UC1")
    out = decode_depth(enc, h, w, step, data.tobytes())
    np.testing.assert_allclose(out, [[0, 1.234, 65.534], [0.001, 2.0, 0]], atol=1e-6)  # 1 mm steps, NaN -> 0
    # past 65.534 m there is no 16-bit code left: 65535 is the "no reading" marker, so it encodes as invalid
    far = encode_depth(np.array([[65.535, 70.0]], np.float32), "16UC1")
    np.testing.assert_array_equal(np.frombuffer(far[4].tobytes(), "<u2"), [0, 0])
    with pytest.raises(DatasetError, match="unsupported depth encoding '8UC1'"):
        decode_depth("8UC1", 2, 3, 3, b"\0" * 6)
    with pytest.raises(DatasetError, match="truncated"):
        decode_depth("32FC1", 2, 3, 12, b"\0" * 20)
    with pytest.raises(DatasetError, match="row step"):
        decode_color("rgb8", 2, 3, 4, b"\0" * 100)


def test_quaternion_matrix_round_trip_and_guards():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(200, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 3] < 0] *= -1
    r = quat_to_matrix(q)
    np.testing.assert_allclose(np.einsum("nij,nkj->nik", r, r), np.broadcast_to(np.eye(3), r.shape), atol=1e-12)
    np.testing.assert_allclose(matrix_to_quat(r), q, atol=1e-12)
    # rotations by ~180 degrees (trace near -1) are the unstable case of the naive formula
    flip = quat_to_matrix(np.array([1.0, 1e-9, 0.0, 0.0]))
    np.testing.assert_allclose(quat_to_matrix(matrix_to_quat(flip)), flip, atol=1e-12)
    with pytest.raises(ValueError):
        quat_to_matrix(np.zeros(4))
    t = make_transform([1, 2, 3], q[0])
    np.testing.assert_allclose(invert_transform(t) @ t, np.eye(4), atol=1e-12)
    # slerp midpoint of 0 and 90 degrees about z is 45 degrees
    mid = slerp(np.array([0, 0, 0, 1.0]), np.array([0, 0, np.sin(np.pi / 4), np.cos(np.pi / 4)]), 0.5)
    np.testing.assert_allclose(mid, [0, 0, np.sin(np.pi / 8), np.cos(np.pi / 8)], atol=1e-12)


def test_tf_buffer_chains_interpolation_and_errors():
    buf = TransformBuffer(max_extrapolation_ns=10, max_gap_ns=1000)
    buf.add("map", "odom", 0, [0, 0, 0], [0, 0, 0, 1], static=True)
    buf.add("odom", "base", 100, [0, 0, 0], [0, 0, 0, 1])
    buf.add("odom", "base", 200, [2, 0, 0], [0, 0, 0, 1])
    buf.add("base", "cam", 0, [0, 1, 0], [0, 0, 0, 1], static=True)
    buf.add("map", "other", 0, [5, 0, 0], [0, 0, 0, 1], static=True)
    np.testing.assert_allclose(buf.lookup("map", "cam", 150)[:3, 3], [1, 1, 0])
    # between two branches of the tree: other -> cam
    np.testing.assert_allclose(buf.lookup("other", "cam", 150)[:3, 3], [-4, 1, 0])
    np.testing.assert_allclose(buf.lookup("cam", "map", 150) @ buf.lookup("map", "cam", 150), np.eye(4), atol=1e-12)
    with pytest.raises(TransformLookupError, match="not available"):
        buf.lookup("map", "cam", 500)
    with pytest.raises(TransformLookupError, match="no TF chain"):
        buf.lookup("map", "nowhere", 150)
    assert not buf.add("x", "base", 0, [0, 0, 0], [0, 0, 0, 1])  # re-parenting is refused and counted
    assert not buf.add("map", "nan", 0, [np.nan, 0, 0], [0, 0, 0, 1])
    assert buf.conflicts == 2
    buf.add("odom", "base", 5000, [0, 0, 0], [0, 0, 0, 1])
    with pytest.raises(TransformLookupError, match="gap"):
        buf.lookup("map", "base", 1000)


def test_frame_validation():
    intr = CameraIntrinsics(100, 100, 2, 2, 4, 4)
    with pytest.raises(DatasetError, match="differ in size"):
        RGBDFrame(np.zeros((4, 5, 3), np.uint8), np.zeros((4, 4), np.float32), intr, None, 0)
    with pytest.raises(DatasetError, match="camera info says"):
        RGBDFrame(np.zeros((3, 4, 3), np.uint8), np.zeros((3, 4), np.float32), intr, None, 0)
    with pytest.raises(DatasetError, match="finite 4x4"):
        RGBDFrame(np.zeros((4, 4, 3), np.uint8), np.zeros((4, 4), np.float32), intr, np.full((4, 4), np.nan), 0)
    with pytest.raises(DatasetError, match="focal"):
        CameraIntrinsics(0, 100, 2, 2, 4, 4)


@pytest.mark.parametrize("encoding", ["16UC1", "mono16"])
@pytest.mark.parametrize("bigendian", [0, 1])
def test_16bit_depth_0_and_65535_are_invalid(encoding, bigendian):
    """Sensors write 65535 for "no reading" (saturation): it must not become a wall at 65.5 m."""
    raw = np.array([[0, 65535, 1000], [65534, 1, 4000]], ">u2" if bigendian else "<u2")
    out = decode_depth(encoding, 2, 3, 6, raw.tobytes(), bigendian)
    np.testing.assert_allclose(out, [[0, 0, 1.0], [65.534, 0.001, 4.0]], rtol=1e-6)
