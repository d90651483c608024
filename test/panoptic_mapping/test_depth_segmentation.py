"""The planar, vectorised depth segmentation (issue 26) gives bit-identical results to the plain
(H, W, 3) formulation it replaced: that formulation is kept here, frozen, as the reference."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from testsupport.tiny_room import EYES, INTR, render_frame, room_renderer

from panoptic_mapping import depth_segmentation as ds
from panoptic_mapping.config import DepthSegmentationConfig

# ---------------------------------------------------------------------------- reference (before issue 26)


def _ref_dot(a, b):
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _ref_backproject(depth, intr):
    h, w = depth.shape
    u = (np.arange(w, dtype=np.float32) - np.float32(intr.cx)) / np.float32(intr.fx)
    v = (np.arange(h, dtype=np.float32) - np.float32(intr.cy)) / np.float32(intr.fy)
    pts = np.empty((h, w, 3), np.float32)
    pts[..., 0] = depth * u[None, :]
    pts[..., 1] = depth * v[:, None]
    pts[..., 2] = depth
    return pts


def _ref_smooth(points, valid, smoothing):
    if smoothing <= 0:
        return points
    vf = valid.astype(np.float32)
    k = (2 * smoothing + 1, 2 * smoothing + 1)
    weight = cv2.boxFilter(vf, -1, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
    summed = cv2.boxFilter(points * vf[..., None], -1, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
    return np.where(valid[..., None], summed / np.maximum(weight, 1.0)[..., None], 0.0).astype(np.float32)


def _ref_normals(points, valid, step=2, smoothing=2):
    smooth = _ref_smooth(points, valid, smoothing)
    dx = np.zeros_like(smooth)
    dy = np.zeros_like(smooth)
    dx[:, step:-step] = smooth[:, 2 * step:] - smooth[:, : -2 * step]
    dy[step:-step, :] = smooth[2 * step:, :] - smooth[: -2 * step, :]
    n = np.cross(dx, dy)
    norm = np.linalg.norm(n, axis=2, keepdims=True)
    ok = valid & (norm[..., 0] > 1e-9)
    ok[:, :step] = ok[:, -step:] = False
    ok[:step, :] = ok[-step:, :] = False
    n = np.where(ok[..., None], n / np.maximum(norm, 1e-9), 0.0).astype(np.float32)
    flip = _ref_dot(n, points) > 0
    n[flip] *= -1
    return n


def _ref_shift(a, dy, dx, fill):
    out = np.full_like(a, fill)
    h, w = a.shape[:2]
    ys, yd = (slice(dy, h), slice(0, h - dy)) if dy >= 0 else (slice(0, h + dy), slice(-dy, h))
    xs, xd = (slice(dx, w), slice(0, w - dx)) if dx >= 0 else (slice(0, w + dx), slice(-dx, w))
    out[yd, xd] = a[ys, xs]
    return out


def _ref_edges(points, normals, valid, cfg, scale=1.0):
    edge = ~(valid & np.any(normals != 0, axis=2))
    margin = np.maximum(cfg.max_discontinuity_ratio * points[..., 2], cfg.min_discontinuity_m)
    for off in cfg.neighbour_offsets:
        off = max(1, round(off * scale))
        for dy, dx in ((0, off), (off, 0), (0, -off), (-off, 0)):
            pj, nj = _ref_shift(points, dy, dx, 0.0), _ref_shift(normals, dy, dx, 0.0)
            vj = _ref_shift(valid, dy, dx, False)
            d = _ref_dot(pj - points, normals)
            edge |= vj & ((np.abs(d) > margin) | ((d > 0) & (_ref_dot(normals, nj) < cfg.min_convexity)))
    return edge


def _ref_segment(depth, intr, cfg, area=1.0):
    valid = depth > 0
    points = _ref_backproject(depth, intr)
    normals = _ref_normals(points, valid, cfg.normal_step, cfg.normal_smoothing)
    edges = _ref_edges(_ref_smooth(points, valid, cfg.edge_smoothing), normals, valid, cfg, scale=np.sqrt(area))
    n, labels, stats, _ = cv2.connectedComponentsWithStats((~edges).astype(np.uint8), connectivity=4)
    keep = stats[:, cv2.CC_STAT_AREA] >= max(1, round(cfg.min_segment_pixels * area))
    keep[0] = False
    lut = np.zeros(n, np.int32)
    lut[keep] = np.arange(1, int(keep.sum()) + 1, dtype=np.int32)
    return lut[labels], points, normals


# ---------------------------------------------------------------------------- tests


@pytest.fixture(scope="module")
def depths():
    renderer = room_renderer()
    rng = np.random.default_rng(7)
    out = []
    for i, eye in enumerate(EYES[:3]):
        d = render_frame(renderer, eye)[0].depth.astype(np.float32)
        noisy = d + (rng.normal(0, 0.004, d.shape) * d * d).astype(np.float32) * (d > 0)
        noisy[rng.random(d.shape) < 0.03] = 0.0  # dropouts
        if i == 2:
            noisy[5:9, 20:30] = np.nan  # NaN readings stay NaN through in_range: never a segment
        out += [d, noisy]
    return out


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("cfg", [
    DepthSegmentationConfig(),
    DepthSegmentationConfig(neighbour_offsets=[1, 3], normal_smoothing=1, edge_smoothing=0, normal_step=1),
    DepthSegmentationConfig(min_convexity=0.9, max_discontinuity_ratio=0.03, min_segment_pixels=20),
])
@pytest.mark.parametrize("area", [1.0, 0.25])
@pytest.mark.parametrize("threads", [1, 2])
def test_segments_points_and_normals_are_bit_identical_to_the_reference(depths, cfg, area, threads, monkeypatch):
    monkeypatch.setattr(ds, "THREADS", threads)  # 2: normals by row halves and edge tests on two threads
    segmented = 0
    for d in depths:
        ref = _ref_segment(d, INTR, cfg, area)
        got = ds.segment_depth(d, INTR, cfg, pixel_area_scale=area)
        assert _same(ref[0], got[0])
        assert np.array_equal(ref[1], got[1], equal_nan=True)
        assert _same(ref[2], got[2])
        segmented += int(ref[0].max() > 0)
    assert segmented >= 2  # not a comparison of empty images


def test_public_helpers_match_the_reference(depths):
    for d in depths:
        valid = d > 0
        p = _ref_backproject(d, INTR)
        assert np.array_equal(p, ds.backproject(d, INTR), equal_nan=True)
        assert _same(_ref_normals(p, valid), ds.estimate_normals(p, valid))
        assert np.array_equal(_ref_smooth(p, valid, 1), ds.smooth_points(p, valid, 1), equal_nan=True)
        n = _ref_normals(p, valid)
        s = _ref_smooth(p, valid, 1)
        cfg = DepthSegmentationConfig()
        assert _same(_ref_edges(s, n, valid, cfg), ds.edge_map(s, n, valid, cfg))
