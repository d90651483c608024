"""Message <-> numpy conversion shared by every node (no cv_bridge needed).

Image payload decoding is the core's (`panoptic_mapping.dataio.image_codec`), so bags and live
topics go through the same, tested code path.
"""

from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Quaternion, Transform, TransformStamped, Vector3
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header

from panoptic_mapping.dataio.image_codec import decode_color, decode_depth, encode_color, encode_depth
from panoptic_mapping.dataio.transforms import make_transform, matrix_to_quat
from recon_core.frame import CameraIntrinsics, DatasetError, sanitize_depth


def stamp_to_ns(stamp: Time) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def ns_to_stamp(ns: int) -> Time:
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def make_header(stamp_ns: int, frame_id: str) -> Header:
    return Header(stamp=ns_to_stamp(stamp_ns), frame_id=frame_id)


def _fill_image(msg: Image, encoded: tuple) -> Image:
    encoding, h, w, step, data = encoded
    msg.encoding, msg.height, msg.width, msg.step, msg.is_bigendian = encoding, h, w, step, 0
    msg.data = np.ascontiguousarray(data, dtype=np.uint8).tobytes()
    return msg


def image_to_rgb(msg: Image) -> np.ndarray:
    """sensor_msgs/Image (rgb8, bgr8, rgba8, bgra8, mono8) -> (H, W, 3) uint8 RGB."""
    return decode_color(msg.encoding, msg.height, msg.width, msg.step, msg.data, msg.is_bigendian)


def image_to_depth(msg: Image) -> tuple[np.ndarray, int]:
    """sensor_msgs/Image (16UC1 mm, 32FC1 m) -> float32 metres (0 = invalid) and the invalid count."""
    return sanitize_depth(decode_depth(msg.encoding, msg.height, msg.width, msg.step, msg.data, msg.is_bigendian))


def rgb_to_image(rgb: np.ndarray, stamp_ns: int = 0, frame_id: str = "", encoding: str = "rgb8") -> Image:
    return _fill_image(Image(header=make_header(stamp_ns, frame_id)), encode_color(rgb, encoding))


def depth_to_image(depth_m: np.ndarray, stamp_ns: int = 0, frame_id: str = "", encoding: str = "16UC1") -> Image:
    return _fill_image(Image(header=make_header(stamp_ns, frame_id)), encode_depth(depth_m, encoding))


def labels_to_image(labels: np.ndarray, stamp_ns: int = 0, frame_id: str = "") -> Image:
    """(H, W) integer label image -> 32SC1 Image."""
    lab = np.ascontiguousarray(labels, dtype="<i4")
    h, w = lab.shape
    return _fill_image(Image(header=make_header(stamp_ns, frame_id)),
                       ("32SC1", h, w, lab.strides[0], lab.reshape(-1).view(np.uint8)))


def image_to_labels(msg: Image) -> np.ndarray:
    """32SC1 Image -> (H, W) int32."""
    if msg.encoding != "32SC1":
        raise DatasetError(f"label image must be 32SC1, got {msg.encoding!r}")
    buf = np.frombuffer(memoryview(msg.data).cast("B"), dtype=np.uint8)
    if buf.size < msg.step * msg.height or msg.step < 4 * msg.width:
        raise DatasetError("label image data is shorter than its size fields say")
    dt = np.dtype(">i4" if msg.is_bigendian else "<i4")
    rows = buf[: msg.step * msg.height].reshape(msg.height, msg.step)[:, : 4 * msg.width]
    return np.ascontiguousarray(rows).view(dt).reshape(msg.height, msg.width).astype(np.int32)


def camera_info_to_intrinsics(msg: CameraInfo) -> CameraIntrinsics:
    return CameraIntrinsics.from_matrix(np.asarray(msg.k, dtype=np.float64), msg.width, msg.height)


def intrinsics_to_camera_info(intr: CameraIntrinsics, stamp_ns: int = 0, frame_id: str = "") -> CameraInfo:
    msg = CameraInfo(header=make_header(stamp_ns, frame_id), width=intr.width, height=intr.height)
    msg.distortion_model = "plumb_bob"
    msg.d = [0.0] * 5
    msg.k = intr.matrix.reshape(-1).tolist()
    msg.r = np.eye(3).reshape(-1).tolist()
    msg.p = [intr.fx, 0.0, intr.cx, 0.0, 0.0, intr.fy, intr.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    return msg


def transform_to_matrix(tf: Transform) -> np.ndarray:
    t, q = tf.translation, tf.rotation
    return make_transform([t.x, t.y, t.z], [q.x, q.y, q.z, q.w])


def matrix_to_transform(matrix: np.ndarray) -> Transform:
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise ValueError("transform must be a finite 4x4 matrix")
    q = matrix_to_quat(m[:3, :3])
    return Transform(
        translation=Vector3(x=float(m[0, 3]), y=float(m[1, 3]), z=float(m[2, 3])),
        rotation=Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
    )


def make_transform_stamped(matrix: np.ndarray, parent: str, child: str, stamp_ns: int) -> TransformStamped:
    return TransformStamped(header=make_header(stamp_ns, parent), child_frame_id=child,
                            transform=matrix_to_transform(matrix))
