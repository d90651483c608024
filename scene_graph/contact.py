"""Contact area of Eq. (2): which supporting plane is under which part of a child's footprint.

A(v_p, v_c) is the area of the rectangle containing the parent's geometry near the plane within
the child's box, over the child's bottom area. Measured on a grid of cells over the child's box
footprint: a cell is *covered* by a plane when one of the plane's region triangles (or points)
contains it. Planes claim cells from the highest down (all at or below the child's bottom): a
plane's rectangle is the bounding box (in the child's box axes) of the covered cells no higher
plane has claimed, and it then claims every cell inside that rectangle. So the surface the child
can actually touch wins - a book stacked on a book, a cup on a shelf level, not the larger
surface further down it never touches - and holes in a mapped surface (the unseen patch right
under an object) neither shrink its contact nor hand the hole to the surface below.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from recon_core.geometry.box import GravityBox
from recon_core.geometry.polygon import EPS


@dataclass(frozen=True)
class FootprintGrid:
    """Cell centres over a box footprint: ``local`` (G, 2) in box axes, ``world`` (G, 2) in map x-y."""

    box: GravityBox
    nu: int
    nv: int
    local: NDArray[np.float64]
    world: NDArray[np.float64]

    @property
    def cell(self) -> tuple[float, float]:
        return float(self.box.size[0] / self.nu), float(self.box.size[1] / self.nv)


def footprint_grid(box: GravityBox, cell_size: float, max_cells: int) -> FootprintGrid:
    """A grid of at most ``max_cells`` x ``max_cells`` cells of about ``cell_size`` over the footprint."""
    n = [int(np.clip(np.ceil(s / max(cell_size, EPS)), 1, max(max_cells, 1))) for s in box.size[:2]]
    hu, hv = 0.5 * box.size[0], 0.5 * box.size[1]
    u = -hu + (np.arange(n[0]) + 0.5) * box.size[0] / n[0]
    v = -hv + (np.arange(n[1]) + 0.5) * box.size[1] / n[1]
    uu, vv = np.meshgrid(u, v, indexing="ij")
    local = np.c_[uu.ravel(), vv.ravel()]
    c, s = np.cos(box.yaw), np.sin(box.yaw)
    world = np.c_[c * local[:, 0] - s * local[:, 1], s * local[:, 0] + c * local[:, 1]] + box.center[:2]
    return FootprintGrid(box, n[0], n[1], local, world)


def triangles_cover(points: NDArray[np.float64], triangles: NDArray[np.float64],
                    bounds: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None) -> NDArray[np.bool_]:
    """Which (G, 2) points lie in at least one of the (F, 3, 2) triangles (edges inclusive).

    ``bounds``: precomputed per-triangle (lo, hi), so large regions are not rescanned per query.
    """
    if len(triangles) == 0 or len(points) == 0:
        return np.zeros(len(points), dtype=bool)
    lo, hi = points.min(0), points.max(0)
    tlo, thi = bounds if bounds is not None else (triangles.min(axis=1), triangles.max(axis=1))
    near = np.all((tlo <= hi) & (thi >= lo), axis=1)  # triangles whose bounds meet the grid's
    tri = triangles[near]
    if len(tri) == 0:
        return np.zeros(len(points), dtype=bool)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    px, py = points[:, None, 0], points[:, None, 1]

    def edge(p: NDArray, q: NDArray) -> NDArray:
        return (q[None, :, 0] - p[None, :, 0]) * (py - p[None, :, 1]) - (q[None, :, 1] - p[None, :, 1]) * (
            px - p[None, :, 0])

    e0, e1, e2 = edge(a, b), edge(b, c), edge(c, a)
    tol = 1e-12
    inside = ((e0 >= -tol) & (e1 >= -tol) & (e2 >= -tol)) | ((e0 <= tol) & (e1 <= tol) & (e2 <= tol))
    # Zero-area triangles would accept every collinear point: drop them.
    area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    inside &= np.abs(area2)[None, :] > EPS
    return np.asarray(inside.any(axis=1), dtype=bool)


def points_cover(grid: FootprintGrid, points_xy: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Cells of the grid holding at least one of the (N, 2) map points (point-cloud regions)."""
    covered = np.zeros(grid.nu * grid.nv, dtype=bool)
    if len(points_xy) == 0:
        return covered
    local = grid.box.to_local_xy(points_xy)
    half = 0.5 * grid.box.size[:2]
    cu, cv = grid.cell
    iu = np.floor((local[:, 0] + half[0]) / max(cu, EPS)).astype(np.int64)
    iv = np.floor((local[:, 1] + half[1]) / max(cv, EPS)).astype(np.int64)
    ok = (iu >= 0) & (iu < grid.nu) & (iv >= 0) & (iv < grid.nv)
    covered[iu[ok] * grid.nv + iv[ok]] = True
    return covered


def owned_rectangle_ratio(grid: FootprintGrid, owned: NDArray[np.bool_]) -> float:
    """Eq. (2): area of the rectangle around the owned cells (box axes) / the footprint area, in [0, 1].

    A zero-area footprint (a point or a segment) uses the owned share of its cells instead.
    """
    if not np.any(owned):
        return 0.0
    area = grid.box.footprint_area
    if area <= EPS:
        return float(owned.mean())
    cu, cv = grid.cell
    pts = grid.local[owned]
    width = float(np.ptp(pts[:, 0]) + cu)
    depth = float(np.ptp(pts[:, 1]) + cv)
    return float(np.clip(width * depth / area, 0.0, 1.0))


def claimed_ratios(grid: FootprintGrid, covers: NDArray[np.bool_], heights: NDArray[np.float64]) -> NDArray[np.float64]:
    """Eq. (2) ratio of each of K planes ((K, G) covered cells, (K,) heights), higher planes first."""
    ratios = np.zeros(len(heights))
    claimed = np.zeros(covers.shape[1], dtype=bool)
    for k in np.argsort(-np.asarray(heights), kind="stable"):
        owned = covers[k] & ~claimed
        if not owned.any():
            continue
        ratios[k] = owned_rectangle_ratio(grid, owned)
        lo, hi = grid.local[owned].min(axis=0), grid.local[owned].max(axis=0)
        inside = np.all((grid.local >= lo - 1e-9) & (grid.local <= hi + 1e-9), axis=1)
        claimed |= inside
    return ratios
