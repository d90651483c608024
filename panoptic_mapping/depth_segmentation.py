"""Convexity-based geometric segmentation of a depth image (Furrer et al. 2018; Tateno et al. 2015).

A pixel is an edge when, against some neighbour j (several offsets, 4 directions):
* depth discontinuity: the neighbour is off the tangent plane by more than a depth-relative margin
  |(p_j - p_i) . n_i| > max(ratio * z_i, floor), or
* concavity: the neighbour lies in front of the tangent plane ((p_j - p_i) . n_i > 0, an inside
  corner such as floor meets wall) and the normals differ: n_i . n_j < min_convexity.
Convex edges (a table's rim) do not cut, so one convex object stays one segment. The remaining
pixels form segments by 4-connected components. Everything is whole-image numpy / OpenCV.
"""

from __future__ import annotations

import cv2
import numpy as np

from panoptic_mapping.config import DepthSegmentationConfig
from recon_core.frame import CameraIntrinsics

_EPS = 1e-9


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-pixel dot product of two (H, W, 3) images (faster than einsum for this shape)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def backproject(depth: np.ndarray, intr: CameraIntrinsics) -> np.ndarray:
    """(H, W, 3) float32 camera-frame points (x right, y down, z forward); z = 0 where invalid."""
    h, w = depth.shape
    u = (np.arange(w, dtype=np.float32) - np.float32(intr.cx)) / np.float32(intr.fx)
    v = (np.arange(h, dtype=np.float32) - np.float32(intr.cy)) / np.float32(intr.fy)
    pts = np.empty((h, w, 3), np.float32)
    pts[..., 0] = depth * u[None, :]
    pts[..., 1] = depth * v[:, None]
    pts[..., 2] = depth
    return pts


def smooth_points(points: np.ndarray, valid: np.ndarray, smoothing: int) -> np.ndarray:
    """Mean of the valid points in a (2s+1)^2 window: suppresses sensor noise before the edge tests."""
    if smoothing <= 0:
        return points
    vf = valid.astype(np.float32)
    k = (2 * smoothing + 1, 2 * smoothing + 1)
    weight = cv2.boxFilter(vf, -1, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
    summed = cv2.boxFilter(points * vf[..., None], -1, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
    return np.where(valid[..., None], summed / np.maximum(weight, 1.0)[..., None], 0.0).astype(np.float32)


def estimate_normals(points: np.ndarray, valid: np.ndarray, step: int = 2, smoothing: int = 2) -> np.ndarray:
    """Unit normals facing the camera from central differences of box-smoothed points (0 where unknown)."""
    smooth = smooth_points(points, valid, smoothing)
    dx = np.zeros_like(smooth)
    dy = np.zeros_like(smooth)
    dx[:, step:-step] = smooth[:, 2 * step:] - smooth[:, : -2 * step]
    dy[step:-step, :] = smooth[2 * step:, :] - smooth[: -2 * step, :]
    n = np.cross(dx, dy)
    norm = np.linalg.norm(n, axis=2, keepdims=True)
    ok = valid & (norm[..., 0] > _EPS)
    ok[:, :step] = ok[:, -step:] = False
    ok[:step, :] = ok[-step:, :] = False
    n = np.where(ok[..., None], n / np.maximum(norm, _EPS), 0.0).astype(np.float32)
    # face the camera: n . p < 0
    flip = _dot(n, points) > 0
    n[flip] *= -1
    return n


def _shift(a: np.ndarray, dy: int, dx: int, fill: float | bool) -> np.ndarray:
    """out[y, x] = a[y + dy, x + dx] (fill outside)."""
    out = np.full_like(a, fill)
    h, w = a.shape[:2]
    ys, yd = (slice(dy, h), slice(0, h - dy)) if dy >= 0 else (slice(0, h + dy), slice(-dy, h))
    xs, xd = (slice(dx, w), slice(0, w - dx)) if dx >= 0 else (slice(0, w + dx), slice(-dx, w))
    out[yd, xd] = a[ys, xs]
    return out


def edge_map(points: np.ndarray, normals: np.ndarray, valid: np.ndarray, cfg: DepthSegmentationConfig,
             scale: float = 1.0) -> np.ndarray:
    """Boolean (H, W): True on depth-discontinuity and concave edges and on invalid pixels."""
    has_n = np.any(normals != 0, axis=2)
    edge = ~(valid & has_n)
    z = points[..., 2]
    margin = np.maximum(cfg.max_discontinuity_ratio * z, cfg.min_discontinuity_m)
    for off in cfg.neighbour_offsets:
        off = max(1, round(off * scale))
        for dy, dx in ((0, off), (off, 0), (0, -off), (-off, 0)):
            pj = _shift(points, dy, dx, 0.0)
            nj = _shift(normals, dy, dx, 0.0)
            vj = _shift(valid, dy, dx, False)
            d = _dot(pj - points, normals)
            disc = np.abs(d) > margin
            concave = (d > 0) & (_dot(normals, nj) < cfg.min_convexity)
            edge |= vj & (disc | concave)
    return edge


def segment_depth(
    depth: np.ndarray, intr: CameraIntrinsics, cfg: DepthSegmentationConfig, pixel_area_scale: float = 1.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Geometric segments of a depth image.

    Returns (labels (H, W) int32 with 0 = no segment and segments 1..K, camera points, normals).
    `pixel_area_scale` converts the full-resolution min segment size to this image (1/4 at half size).
    """
    valid = depth > 0
    points = backproject(depth, intr)
    normals = estimate_normals(points, valid, cfg.normal_step, cfg.normal_smoothing)
    smooth = smooth_points(points, valid, cfg.edge_smoothing)
    edges = edge_map(smooth, normals, valid, cfg, scale=np.sqrt(pixel_area_scale))
    n, labels, stats, _ = cv2.connectedComponentsWithStats((~edges).astype(np.uint8), connectivity=4)
    min_px = max(1, round(cfg.min_segment_pixels * pixel_area_scale))
    keep = stats[:, cv2.CC_STAT_AREA] >= min_px
    keep[0] = False
    # relabel kept components 1..K (0 = edge, invalid or too small)
    lut = np.zeros(n, np.int32)
    lut[keep] = np.arange(1, int(keep.sum()) + 1, dtype=np.int32)
    return lut[labels], points, normals
