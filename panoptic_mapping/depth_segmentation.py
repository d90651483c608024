"""Convexity-based geometric segmentation of a depth image (Furrer et al. 2018; Tateno et al. 2015).

A pixel is an edge when, against some neighbour j (several offsets, 4 directions):
* depth discontinuity: the neighbour is off the tangent plane by more than a depth-relative margin
  |(p_j - p_i) . n_i| > max(ratio * z_i, floor), or
* concavity: the neighbour lies in front of the tangent plane ((p_j - p_i) . n_i > 0, an inside
  corner such as floor meets wall) and the normals differ: n_i . n_j < min_convexity.
Convex edges (a table's rim) do not cut, so one convex object stays one segment. The remaining
pixels form segments by 4-connected components.

Speed (issue 26): everything runs on planar float32 images (one contiguous (H, W) array per
coordinate), so every step is a contiguous SIMD pass (numpy) or a native OpenCV kernel (box
filters, connected components); no (H, W, 3) strided arithmetic and no shifted copies. The two
directions of one neighbour offset share the point difference and the normal agreement. The
arithmetic (and its float32 rounding) is the same, operation by operation, as the straightforward
(H, W, 3) formulation it replaced, so the segments are bit-identical (test_depth_segmentation.py).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

from panoptic_mapping.config import DepthSegmentationConfig
from recon_core.frame import CameraIntrinsics

_EPS = 1e-9
Planes = tuple[np.ndarray, np.ndarray, np.ndarray]


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-pixel dot product of two (H, W, 3) images."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _dot3(a: Planes, b: Planes, out: np.ndarray | None = None, tmp: np.ndarray | None = None) -> np.ndarray:
    """a . b of planar images: a0*b0 + a1*b1 + a2*b2 (this order, float32), into `out` if given."""
    out = np.multiply(a[0], b[0], out=out)
    tmp = np.multiply(a[1], b[1], out=tmp)
    out += tmp
    np.multiply(a[2], b[2], out=tmp)
    out += tmp
    return out


def backproject_planes(depth: np.ndarray, intr: CameraIntrinsics) -> Planes:
    """Camera-frame point coordinates (x, y, z) as three contiguous (H, W) float32 images."""
    h, w = depth.shape
    u = (np.arange(w, dtype=np.float32) - np.float32(intr.cx)) / np.float32(intr.fx)
    v = (np.arange(h, dtype=np.float32) - np.float32(intr.cy)) / np.float32(intr.fy)
    x = np.multiply(depth, u[None, :], dtype=np.float32) if depth.dtype == np.float32 else \
        (depth * u[None, :]).astype(np.float32)
    y = np.multiply(depth, v[:, None], dtype=np.float32) if depth.dtype == np.float32 else \
        (depth * v[:, None]).astype(np.float32)
    z = np.array(depth, np.float32)
    return x, y, z


def backproject(depth: np.ndarray, intr: CameraIntrinsics) -> np.ndarray:
    """(H, W, 3) float32 camera-frame points (x right, y down, z forward); z = 0 where invalid."""
    return cv2.merge(list(backproject_planes(depth, intr)))


def _smooth_planes(points: Planes, vf: np.ndarray, valid: np.ndarray, smoothing: int,
                   masked: Planes | None = None) -> Planes:
    """Mean of the valid points in a (2s+1)^2 window (planar); `masked`: the points times `vf`."""
    if smoothing <= 0:
        return points
    k = (2 * smoothing + 1, 2 * smoothing + 1)
    weight = cv2.boxFilter(vf, -1, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
    np.maximum(weight, 1.0, out=weight)
    invalid = ~valid
    if masked is None:
        masked = (points[0] * vf, points[1] * vf, points[2] * vf)
    out: list[np.ndarray] = []
    for p in masked:
        s: np.ndarray = cv2.boxFilter(p, -1, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
        np.divide(s, weight, out=s)
        np.copyto(s, 0.0, where=invalid)
        out.append(s)
    return out[0], out[1], out[2]


def smooth_points(points: np.ndarray, valid: np.ndarray, smoothing: int) -> np.ndarray:
    """Mean of the valid points in a (2s+1)^2 window: suppresses sensor noise before the edge tests."""
    if smoothing <= 0:
        return points
    planes = tuple(np.ascontiguousarray(points[..., c], np.float32) for c in range(3))
    return cv2.merge(list(_smooth_planes(planes, valid.astype(np.float32), valid, smoothing)))  # type: ignore[arg-type]


def _normal_band(points: Planes, smooth: Planes, valid: np.ndarray, step: int, r0: int, r1: int,
                 n_out: Planes, ok_out: np.ndarray) -> None:
    """`_normal_planes` for the image rows [r0, r1), into those rows of `n_out` and `ok_out`."""
    h, w = valid.shape
    s, rows = step, r1 - r0
    a, b = max(r0, s), min(r1, h - s)  # rows with a vertical difference
    dx: list[np.ndarray] = []
    dy: list[np.ndarray] = []
    for sc in smooth:
        gx = np.zeros((rows, w), np.float32)
        np.subtract(sc[r0:r1, 2 * s:], sc[r0:r1, : -2 * s], out=gx[:, s:-s])
        dx.append(gx)
        gy = np.zeros((rows, w), np.float32)
        if b > a:
            np.subtract(sc[a + s:b + s], sc[a - s:b - s], out=gy[a - r0:b - r0])
        dy.append(gy)
    tmp = np.empty((rows, w), np.float32)
    n = [c[r0:r1] for c in n_out]
    for k, (i, j) in enumerate(((1, 2), (2, 0), (0, 1))):  # n = dx x dy, as numpy's cross computes it
        np.multiply(dx[i], dy[j], out=n[k])
        np.multiply(dx[j], dy[i], out=tmp)
        n[k] -= tmp
    sq = np.multiply(n[0], n[0])
    np.multiply(n[1], n[1], out=tmp)
    sq += tmp
    np.multiply(n[2], n[2], out=tmp)
    sq += tmp
    norm = np.sqrt(sq, out=sq)
    ok = ok_out[r0:r1]
    np.greater(norm, _EPS, out=ok)
    ok &= valid[r0:r1]
    ok[:, :s] = ok[:, -s:] = False
    ok[: max(0, min(rows, s - r0)), :] = False
    ok[max(0, h - s - r0):, :] = False
    np.maximum(norm, _EPS, out=norm)
    bad = ~ok
    for nc in n:
        np.divide(nc, norm, out=nc)
        np.copyto(nc, 0.0, where=bad)
    # face the camera: n . p < 0
    flip = _dot3((n[0], n[1], n[2]), (points[0][r0:r1], points[1][r0:r1], points[2][r0:r1]), out=norm,
                 tmp=tmp) > 0
    for nc in n:
        np.negative(nc, out=nc, where=flip)


def _normal_planes(points: Planes, smooth: Planes, valid: np.ndarray, step: int) -> tuple[Planes, np.ndarray]:
    """Unit normals facing the camera (planar; 0 where unknown) from central differences of the
    smoothed points, and the mask of pixels that have one. With `THREADS` > 1 the lower half of the
    rows runs on a second thread (the same arithmetic per pixel: the same result)."""
    h, w = valid.shape
    n_out = (np.empty((h, w), np.float32), np.empty((h, w), np.float32), np.empty((h, w), np.float32))
    ok = np.empty((h, w), bool)
    if THREADS < 2 or h < 64:
        _normal_band(points, smooth, valid, step, 0, h, n_out, ok)
    else:
        mid = h // 2
        other = _pool().submit(_normal_band, points, smooth, valid, step, mid, h, n_out, ok)
        _normal_band(points, smooth, valid, step, 0, mid, n_out, ok)
        other.result()
    return n_out, ok


def estimate_normals(points: np.ndarray, valid: np.ndarray, step: int = 2, smoothing: int = 2) -> np.ndarray:
    """Unit normals facing the camera from central differences of box-smoothed points (0 where unknown)."""
    planes = tuple(np.ascontiguousarray(points[..., c], np.float32) for c in range(3))
    smooth = _smooth_planes(planes, valid.astype(np.float32), valid, smoothing)  # type: ignore[arg-type]
    n, _ok = _normal_planes(planes, smooth, valid, step)  # type: ignore[arg-type]
    return cv2.merge(list(n))


def _edge_cuts(points: Planes, normals: Planes, valid: np.ndarray, margin: np.ndarray, neg_margin: np.ndarray,
               conv: np.float32, combos: list[tuple[int, int]], edge: np.ndarray) -> np.ndarray:
    """OR into `edge` the cuts against the neighbours at the (offset, axis) `combos`, both directions."""
    h, w = valid.shape
    for off, axis in combos:  # the neighbour below / to the right (+off) and above / to the left (-off)
        lo = (slice(0, h - off), slice(None)) if axis == 0 else (slice(None), slice(0, w - off))
        hi = (slice(off, h), slice(None)) if axis == 0 else (slice(None), slice(off, w))
        diff = (np.subtract(points[0][hi], points[0][lo]), np.subtract(points[1][hi], points[1][lo]),
                np.subtract(points[2][hi], points[2][lo]))  # p(x + off) - p(x)
        tmp = np.empty(diff[0].shape, np.float32)
        nlo = (normals[0][lo], normals[1][lo], normals[2][lo])
        nhi = (normals[0][hi], normals[1][hi], normals[2][hi])
        # normals disagree: n(x) . n(x + off) < min_convexity (the same for both directions)
        concave_pair = _dot3(nlo, nhi, tmp=tmp) < conv
        # + direction: pixel x, neighbour x + off: d = (p(x+off) - p(x)) . n(x)
        d = _dot3(diff, nlo, tmp=tmp)
        cut = (d > margin[lo]) | (d < neg_margin[lo]) | ((d > 0) & concave_pair)
        cut &= valid[hi]
        edge[lo] |= cut
        # - direction: pixel x + off, neighbour x: d = (p(x) - p(x+off)) . n(x+off) = -e
        e = _dot3(diff, nhi, out=d, tmp=tmp)
        cut = (e < neg_margin[hi]) | (e > margin[hi]) | ((e < 0) & concave_pair)
        cut &= valid[lo]
        edge[hi] |= cut
    return edge


def _edge_planes(points: Planes, normals: Planes, valid: np.ndarray, has_normal: np.ndarray,
                 cfg: DepthSegmentationConfig, scale: float = 1.0) -> np.ndarray:
    """Boolean (H, W) edge map from planar smoothed points and normals (see `edge_map`).

    With `THREADS` > 1 half of the (offset, axis) neighbour sets run on a second thread (numpy releases
    the interpreter lock in its loops), each into its own mask; the union is the same either way."""
    edge = ~(valid & has_normal)
    z = points[2]
    margin = np.maximum(np.float32(cfg.max_discontinuity_ratio) * z, np.float32(cfg.min_discontinuity_m))
    neg_margin = -margin
    conv = np.float32(cfg.min_convexity)
    h, w = valid.shape
    combos = []
    for off in cfg.neighbour_offsets:
        off = max(1, round(off * scale))
        combos += [(off, axis) for axis in (0, 1) if off < (h if axis == 0 else w)]
    if THREADS < 2 or len(combos) < 2:
        return _edge_cuts(points, normals, valid, margin, neg_margin, conv, combos, edge)
    other = _pool().submit(_edge_cuts, points, normals, valid, margin, neg_margin, conv, combos[1::2],
                           np.zeros_like(edge))
    _edge_cuts(points, normals, valid, margin, neg_margin, conv, combos[::2], edge)
    edge |= other.result()
    return edge


#: Threads of the edge tests (1: all on the calling thread). Two use both cores of a 2-core computer
#: while the rest of the mapper waits on the segmentation; results are the same for any number.
THREADS = min(2, os.cpu_count() or 1)
_POOL: ThreadPoolExecutor | None = None


def _pool() -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=1, thread_name_prefix="depth-seg")
    return _POOL


def edge_map(points: np.ndarray, normals: np.ndarray, valid: np.ndarray, cfg: DepthSegmentationConfig,
             scale: float = 1.0) -> np.ndarray:
    """Boolean (H, W): True on depth-discontinuity and concave edges and on invalid pixels."""
    p = tuple(np.ascontiguousarray(points[..., c], np.float32) for c in range(3))
    n = tuple(np.ascontiguousarray(normals[..., c], np.float32) for c in range(3))
    has_n = np.any(normals != 0, axis=2)
    return _edge_planes(p, n, valid, has_n, cfg, scale)  # type: ignore[arg-type]


def segment_depth(
    depth: np.ndarray, intr: CameraIntrinsics, cfg: DepthSegmentationConfig, pixel_area_scale: float = 1.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Geometric segments of a depth image.

    Returns (labels (H, W) int32 with 0 = no segment and segments 1..K, camera points, normals).
    `pixel_area_scale` converts the full-resolution min segment size to this image (1/4 at half size).
    """
    labels, points, normals = segment_depth_planes(depth, intr, cfg, pixel_area_scale)
    return labels, cv2.merge(list(points)), cv2.merge(list(normals))


def segment_depth_planes(
    depth: np.ndarray, intr: CameraIntrinsics, cfg: DepthSegmentationConfig, pixel_area_scale: float = 1.0,
) -> tuple[np.ndarray, Planes, Planes]:
    """`segment_depth` with the camera points and normals as planar (x, y, z) float32 images."""
    valid = depth > 0
    points = backproject_planes(depth, intr)
    vf = valid.astype(np.float32)
    masked = tuple(p * vf for p in points)
    smooth_n = _smooth_planes(points, vf, valid, cfg.normal_smoothing, masked)  # type: ignore[arg-type]
    normals, has_n = _normal_planes(points, smooth_n, valid, cfg.normal_step)
    smooth_e = _smooth_planes(points, vf, valid, cfg.edge_smoothing, masked)  # type: ignore[arg-type]
    edges = _edge_planes(smooth_e, normals, valid, has_n, cfg, scale=float(np.sqrt(pixel_area_scale)))
    n, labels, stats, _ = cv2.connectedComponentsWithStats((~edges).view(np.uint8), connectivity=4)
    min_px = max(1, round(cfg.min_segment_pixels * pixel_area_scale))
    keep = stats[:, cv2.CC_STAT_AREA] >= min_px
    keep[0] = False
    # relabel kept components 1..K (0 = edge, invalid or too small)
    lut = np.zeros(n, np.int32)
    lut[keep] = np.arange(1, int(keep.sum()) + 1, dtype=np.int32)
    return lut[labels], points, normals
