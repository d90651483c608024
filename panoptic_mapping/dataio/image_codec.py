"""Decoding and encoding of ROS `sensor_msgs/Image` payloads, shared by the bag loaders and the nodes.

Works on the raw fields (encoding, height, width, step, is_bigendian, data) so it serves rosbags
messages and rclpy messages alike without importing either.
"""

from __future__ import annotations

import numpy as np

from recon_core.frame import DatasetError

#: Color encodings accepted and their (channels, order) after decoding to RGB.
COLOR_ENCODINGS = ("rgb8", "bgr8", "rgba8", "bgra8", "mono8")
#: Depth encodings accepted: 16UC1 / mono16 in millimetres (0 and 65535 invalid), 32FC1 in metres.
DEPTH_ENCODINGS = ("16UC1", "mono16", "32FC1")

_CHANNELS = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1}


def _as_bytes_view(data: object) -> np.ndarray:
    """Zero-copy uint8 view of a message's `data` (numpy array, bytes, bytearray or array.array)."""
    if isinstance(data, np.ndarray):
        return data.view(np.uint8).reshape(-1)
    return np.frombuffer(memoryview(data).cast("B"), dtype=np.uint8)  # type: ignore[arg-type]  # any buffer


def _rows(data: object, height: int, width: int, step: int, row_bytes: int, what: str) -> np.ndarray:
    buf = _as_bytes_view(data)
    if height <= 0 or width <= 0:
        raise DatasetError(f"{what}: empty image ({width}x{height})")
    if step < row_bytes:
        raise DatasetError(f"{what}: row step {step} is smaller than {row_bytes} bytes per row")
    if buf.size < step * (height - 1) + row_bytes:
        raise DatasetError(
            f"{what}: {buf.size} bytes of data for a {width}x{height} image with step {step} "
            f"(needs {step * height}); the message is truncated or its size fields are wrong"
        )
    rows = np.lib.stride_tricks.as_strided(buf, shape=(height, row_bytes), strides=(step, 1))
    return rows


def decode_color(
    encoding: str, height: int, width: int, step: int, data: object, is_bigendian: int = 0
) -> np.ndarray:
    """Return (H, W, 3) uint8 RGB. Raises DatasetError for unknown encodings or bad sizes."""
    if encoding not in _CHANNELS:
        raise DatasetError(
            f"unsupported color encoding {encoding!r}; supported: {', '.join(COLOR_ENCODINGS)}"
        )
    ch = _CHANNELS[encoding]
    rows = _rows(data, height, width, step, width * ch, f"color image ({encoding})")
    img = rows.reshape(height, width, ch)
    if encoding == "rgb8":
        return np.ascontiguousarray(img)
    if encoding == "bgr8":
        return np.ascontiguousarray(img[:, :, ::-1])
    if encoding == "rgba8":
        return np.ascontiguousarray(img[:, :, :3])
    if encoding == "bgra8":
        return np.ascontiguousarray(img[:, :, 2::-1])
    return np.repeat(img, 3, axis=2)  # mono8


def decode_depth(
    encoding: str, height: int, width: int, step: int, data: object, is_bigendian: int = 0
) -> np.ndarray:
    """Return (H, W) float32 metres. 16-bit: 0 and 65535 -> 0 (invalid); 32FC1: NaN / inf / negative
    readings keep their value (see `sanitize_depth`)."""
    dtype: np.dtype
    if encoding in ("16UC1", "mono16"):
        dtype = np.dtype(">u2" if is_bigendian else "<u2")
    elif encoding == "32FC1":
        dtype = np.dtype(">f4" if is_bigendian else "<f4")
    else:
        raise DatasetError(
            f"unsupported depth encoding {encoding!r}; supported: {', '.join(DEPTH_ENCODINGS)} "
            "(16UC1 in millimetres, 32FC1 in metres)"
        )
    rows = _rows(data, height, width, step, width * dtype.itemsize, f"depth image ({encoding})")
    raw = np.ascontiguousarray(rows).view(dtype).reshape(height, width)
    if dtype.kind == "u":
        # 0 and 65535 (the sensors' "no reading" / saturation marker, not 65.5 m) are invalid
        return np.where(raw == 0xFFFF, np.float32(0), raw.astype(np.float32) * np.float32(0.001))
    return raw.astype(np.float32)


def encode_color(rgb: np.ndarray, encoding: str = "rgb8") -> tuple[str, int, int, int, np.ndarray]:
    """(encoding, height, width, step, data) for an (H, W, 3) uint8 RGB image."""
    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected (H, W, 3) uint8 RGB, got {rgb.shape} {rgb.dtype}")
    h, w = rgb.shape[:2]
    if encoding == "rgb8":
        img = rgb
    elif encoding == "bgr8":
        img = rgb[:, :, ::-1]
    elif encoding in ("rgba8", "bgra8"):
        alpha = np.full((h, w, 1), 255, np.uint8)
        img = np.concatenate([rgb if encoding == "rgba8" else rgb[:, :, ::-1], alpha], axis=2)
    elif encoding == "mono8":
        img = np.round(rgb.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32))
        img = np.clip(img, 0, 255).astype(np.uint8)
    else:
        raise ValueError(f"unsupported color encoding {encoding!r}")
    img = np.ascontiguousarray(img)
    return encoding, h, w, img.strides[0], img.reshape(-1).view(np.uint8)


def encode_depth(depth_m: np.ndarray, encoding: str = "16UC1") -> tuple[str, int, int, int, np.ndarray]:
    """(encoding, height, width, step, data) for float metres; 16UC1 rounds to mm, 0 = invalid (so are
    readings past 65.534 m: 65535 means "no reading" to the decoder)."""
    depth_m = np.asarray(depth_m, dtype=np.float32)
    h, w = depth_m.shape
    if encoding == "16UC1":
        mm = np.round(depth_m * np.float32(1000.0))
        valid = np.isfinite(mm) & (mm > 0) & (mm < 0xFFFF)
        img = np.where(valid, mm, 0.0).astype("<u2")
    elif encoding == "32FC1":
        img = depth_m.astype("<f4")
    else:
        raise ValueError(f"unsupported depth encoding {encoding!r}")
    img = np.ascontiguousarray(img)
    return encoding, h, w, img.strides[0], img.reshape(-1).view(np.uint8)
