"""Gravity-aligned minimal box of a point set (paper Sec. 2.2, after Malandain and Boissonnat 2002).

With gravity known, the minimal box is a 2D problem: the minimum-area rectangle around the
projected points has one side collinear with an edge of their convex hull (Freeman and Shapira
1975), so trying every hull edge direction (rotating calipers, vectorised over edges) is exact.
The z extent is the points' range. Optionally a small percentile is trimmed on each side first,
against the stray voxels of mapped meshes.

Degenerate input never yields NaN: one distinct point gives a zero-size box at it, collinear
points a zero-width box along their line, no points an ``EntityError``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import ConvexHull, QhullError

from recon_core.errors import EntityError
from recon_core.geometry.box import GravityBox
from recon_core.geometry.polygon import EPS

#: Fewer points than this are never trimmed (percentiles of a handful of points are meaningless).
MIN_POINTS_TO_TRIM = 20
#: Extents below this (m) count as degenerate for the hull (points on a line or at one spot).
DEGENERATE_EXTENT = 1e-9


def _canonical_yaw(yaw: float) -> float:
    """Yaw in [-pi/4, pi/4]: a quarter turn only swaps the box's x and y sizes."""
    return float(yaw - np.round(yaw / (0.5 * np.pi)) * 0.5 * np.pi)


def min_area_rectangle_yaw(xy: ArrayLike) -> float:
    """Yaw of the minimum-area rectangle around (N, 2) points, in [-pi/4, pi/4].

    Collinear points give their line's direction, a single point 0.
    """
    p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if len(p) < 2:
        return 0.0
    centered = p - p.mean(axis=0)
    spread = np.ptp(centered, axis=0)
    if np.all(spread < DEGENERATE_EXTENT):
        return 0.0
    try:
        hull = centered[ConvexHull(centered).vertices]
    except (QhullError, ValueError):
        hull = None
    if hull is None or len(hull) < 3:
        # Collinear: the principal direction (guarded SVD of a rank-1 cloud).
        _, _, vt = np.linalg.svd(centered, full_matrices=False)
        return _canonical_yaw(float(np.arctan2(vt[0, 1], vt[0, 0])))
    edges = np.roll(hull, -1, axis=0) - hull
    keep = np.linalg.norm(edges, axis=1) > EPS
    angles = np.arctan2(edges[keep, 1], edges[keep, 0])
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    u = hull[None, :, 0] * c + hull[None, :, 1] * s  # (E, H): hull in every edge frame
    v = -hull[None, :, 0] * s + hull[None, :, 1] * c
    areas = np.ptp(u, axis=1) * np.ptp(v, axis=1)
    return _canonical_yaw(float(angles[int(np.argmin(areas))]))


def _box_at_yaw(points: NDArray[np.float64], yaw: float, trim_percent: float) -> GravityBox:
    c, s = np.cos(yaw), np.sin(yaw)
    u = points[:, 0] * c + points[:, 1] * s
    v = -points[:, 0] * s + points[:, 1] * c
    z = points[:, 2]
    if trim_percent > 0.0 and len(points) >= MIN_POINTS_TO_TRIM:
        q = (trim_percent, 100.0 - trim_percent)
        (u0, u1), (v0, v1), (z0, z1) = (np.percentile(a, q) for a in (u, v, z))
    else:
        (u0, u1), (v0, v1), (z0, z1) = ((a.min(), a.max()) for a in (u, v, z))
    uc, vc = 0.5 * (u0 + u1), 0.5 * (v0 + v1)
    center = np.array([uc * c - vc * s, uc * s + vc * c, 0.5 * (z0 + z1)])
    return GravityBox(center, np.array([u1 - u0, v1 - v0, z1 - z0]), yaw)


def fit_gravity_box(points: ArrayLike, trim_percent: float = 0.0) -> GravityBox:
    """Minimal gravity-aligned box of (N, 3) map-frame points.

    ``trim_percent`` > 0: fit once, drop points outside the [p, 100 - p] percentiles along the
    box axes and z, and fit the rectangle again on what is left (outliers no longer steer the yaw).
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0:
        raise EntityError("cannot fit a box to an empty point set")
    if not np.all(np.isfinite(p)):
        raise EntityError("cannot fit a box to non-finite points")
    yaw = min_area_rectangle_yaw(p[:, :2])
    if trim_percent <= 0.0 or len(p) < MIN_POINTS_TO_TRIM:
        return _box_at_yaw(p, yaw, 0.0)
    first = _box_at_yaw(p, yaw, trim_percent)
    local = first.to_local_xy(p[:, :2])
    half = 0.5 * first.size
    inside = (np.all(np.abs(local) <= half[:2] + EPS, axis=1)
              & (p[:, 2] >= first.z_min - EPS) & (p[:, 2] <= first.z_max + EPS))
    kept = p[inside] if inside.sum() >= 3 else p
    return _box_at_yaw(kept, min_area_rectangle_yaw(kept[:, :2]), 0.0)
