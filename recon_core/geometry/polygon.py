"""Small exact 2D geometry on convex polygons (float64): area, clipping, rectangles.

The box IoU of the metrics and the proximal test need the exact intersection of two rotated
rectangles; Sutherland-Hodgman clipping of one convex polygon by another is exact for convex
input and a few microseconds for rectangles, so no general polygon library is needed here.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Lengths/areas below this are treated as zero (guards divisions).
EPS = 1e-12


def polygon_area(poly: ArrayLike) -> float:
    """Absolute area of a simple polygon (shoelace); 0 for fewer than 3 vertices."""
    p = np.asarray(poly, dtype=np.float64).reshape(-1, 2)
    if len(p) < 3:
        return 0.0
    x, y = p[:, 0], p[:, 1]
    return 0.5 * abs(float(x @ np.roll(y, -1) - y @ np.roll(x, -1)))


def ccw(poly: ArrayLike) -> NDArray[np.float64]:
    """The polygon with counter-clockwise vertex order."""
    p = np.asarray(poly, dtype=np.float64).reshape(-1, 2)
    if len(p) >= 3:
        x, y = p[:, 0], p[:, 1]
        if float(x @ np.roll(y, -1) - y @ np.roll(x, -1)) < 0.0:
            return p[::-1].copy()
    return p


def clip_convex(subject: ArrayLike, clip: ArrayLike) -> NDArray[np.float64]:
    """Intersection of polygon ``subject`` with the convex polygon ``clip`` (Sutherland-Hodgman).

    Both are (N, 2) vertex lists; ``clip`` must be convex (orientation is normalised here).
    Returns the (K, 2) intersection polygon, empty (0, 2) when they do not overlap.
    """
    out = np.asarray(subject, dtype=np.float64).reshape(-1, 2)
    c = ccw(clip)
    if len(c) < 3 or len(out) < 3:
        return np.zeros((0, 2))
    for i in range(len(c)):
        if len(out) == 0:
            break
        a, b = c[i], c[(i + 1) % len(c)]
        edge = b - a
        # Signed side of every vertex (>= 0: inside, left of the CCW edge).
        side = edge[0] * (out[:, 1] - a[1]) - edge[1] * (out[:, 0] - a[0])
        nxt = np.roll(out, -1, axis=0)
        side_n = np.roll(side, -1)
        pts: list[NDArray[np.float64]] = []
        for k in range(len(out)):
            if side[k] >= 0.0:
                pts.append(out[k])
            if (side[k] >= 0.0) != (side_n[k] >= 0.0):
                denom = side[k] - side_n[k]
                t = side[k] / denom if abs(denom) > EPS else 0.0
                pts.append(out[k] + t * (nxt[k] - out[k]))
        out = np.array(pts).reshape(-1, 2)
    return out


def convex_intersection_area(a: ArrayLike, b: ArrayLike) -> float:
    """Area of the intersection of two convex polygons."""
    return polygon_area(clip_convex(a, b))


def rectangle(center: ArrayLike, size: ArrayLike, yaw: float) -> NDArray[np.float64]:
    """(4, 2) counter-clockwise corners of a rectangle of ``size`` rotated by ``yaw`` about ``center``."""
    c, s = np.cos(yaw), np.sin(yaw)
    hx, hy = 0.5 * np.asarray(size, dtype=np.float64)[:2]
    local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
    return local @ np.array([[c, s], [-s, c]]) + np.asarray(center, dtype=np.float64)[:2]


def rectangles_overlap(a: ArrayLike, b: ArrayLike) -> bool:
    """Separating-axis test of two convex polygons (touching counts as overlapping)."""
    pa = np.asarray(a, dtype=np.float64).reshape(-1, 2)
    pb = np.asarray(b, dtype=np.float64).reshape(-1, 2)
    if len(pa) == 0 or len(pb) == 0:
        return False
    # Edge normals decide for proper convex polygons; edge directions and the coordinate axes make
    # the test complete for degenerate ones too (segments, points).
    edges = np.concatenate([np.roll(p, -1, axis=0) - p for p in (pa, pb)])
    axes = np.concatenate([np.c_[-edges[:, 1], edges[:, 0]], edges, np.eye(2)])
    axes = axes[np.linalg.norm(axes, axis=1) > EPS]
    proj_a = pa @ axes.T
    proj_b = pb @ axes.T
    return not (np.any(proj_a.max(0) < proj_b.min(0)) or np.any(proj_b.max(0) < proj_a.min(0)))


def point_segment_distances(p: NDArray[np.float64], a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray:
    """(P, S) distances from points (P, 2) to segments a-b (S, 2) (zero-length segments allowed)."""
    ab = b - a
    len2 = np.einsum("ij,ij->i", ab, ab)
    t = np.einsum("pij,ij->pi", p[:, None, :] - a[None], ab) / np.maximum(len2, EPS)[None]
    t = np.clip(t, 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(p[:, None, :] - closest, axis=2)


def polygon_distance(a: ArrayLike, b: ArrayLike) -> float:
    """Smallest distance between two convex polygons (0 when they overlap or touch)."""
    pa = np.asarray(a, dtype=np.float64).reshape(-1, 2)
    pb = np.asarray(b, dtype=np.float64).reshape(-1, 2)
    if len(pa) == 0 or len(pb) == 0:
        return float("inf")
    if rectangles_overlap(pa, pb):
        return 0.0
    d1 = point_segment_distances(pa, pb, np.roll(pb, -1, axis=0)).min()
    d2 = point_segment_distances(pb, pa, np.roll(pa, -1, axis=0)).min()
    return float(min(d1, d2))


def points_in_polygon(points: ArrayLike, polygon: ArrayLike) -> NDArray[np.bool_]:
    """Even-odd rule point-in-polygon test, vectorised over points and edges."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    poly = np.asarray(polygon, dtype=np.float64).reshape(-1, 2)
    a = poly[None, :, :]
    b = np.roll(poly, -1, axis=0)[None, :, :]
    px = pts[:, None, 0]
    py = pts[:, None, 1]
    straddles = (a[..., 1] > py) != (b[..., 1] > py)
    dy = b[..., 1] - a[..., 1]
    safe_dy = np.where(np.abs(dy) < EPS, 1.0, dy)
    x_cross = a[..., 0] + (py - a[..., 1]) * (b[..., 0] - a[..., 0]) / safe_dy
    crossings = straddles & (px < x_cross)
    return (np.count_nonzero(crossings, axis=1) % 2) == 1

