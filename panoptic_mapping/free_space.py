"""Free-space evidence from the label frames: surface no frame measured, or that frames looked
through, is not what an object was seen to be (issue 22, item 4: an unseen back is unknown, not solid).

A thing seen from one side keeps the TSDF's truncation band behind its seen face as solid: every
frame that sees the face writes negative distances up to ``truncation_voxels`` behind it, and the
zero crossing that closes the object lies where those meet the positive distances of the frames
that looked past it (docs/STAGE4_CAD.md: a 16 mm book's unseen back mapped a median 38 mm beyond
its true face, cups and bottles 18-21 mm on their far side). Open3D's band is symmetric, and the
average it keeps has forgotten who saw what. The depth images have not: no frame measured that
closing surface where it is (it lies behind the seen face, hidden), while a real surface is measured
where it is by the frames that see it. Surface some frames looked through (a reading beyond it on
the same ray) is not solid either; on the protocol's maps that case is rare (137 of 27 447 thing
vertices on gen-4242), since the shadow is hidden rather than seen through, so `min_seen` does the work.

This module keeps a small copy of each label frame's depth (every ``downsample``-th pixel, and the
nearest reading of its neighbourhood, so a silhouette's edge never reads as looked through) with its
pose, and at extraction counts, per vertex of a thing entity, the frames that measured it where it is
and the frames that looked through it. Vertices measured by fewer than ``min_seen`` frames, or looked
through by at least ``min_through`` frames and by more frames than measured them, stay the entity's
surface (panoptic quality counts them) but as its fringe (`Entity.core_vertices`): the box of stage 3
and the CAD fit of stage 4 read the core. Cost: about 1 ms per label frame to store its view, one
projection of the things' vertices per stored view at extraction (20 ms for 30 000 vertices and 38
views); the views are thinned to at most ``max_views`` spread over the whole recording.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import cv2
import numpy as np

from panoptic_mapping.config import FreeSpaceConfig
from recon_core.geometry.observed_space import ObservedSpace

#: Stored depth is integer millimetres (0: no reading), as sensors deliver it: a quarter of float32's bytes.
_MM = 1000.0


@dataclass
class SeenThrough:
    """Per-vertex counts of the frames that measured a vertex where it is and that looked through it."""

    seen: np.ndarray
    through: np.ndarray

    def carved(self, min_through: int, ratio: float, min_seen: int = 0) -> np.ndarray:
        """Vertices looked through often enough, and more often than seen (times `ratio`); with
        `min_seen` > 0 also those fewer views measured where they are."""
        out = (self.through >= min_through) & (self.through > ratio * self.seen)
        return out | (self.seen < min_seen) if min_seen > 0 else out


def _to_mm(depth_m: np.ndarray) -> np.ndarray:
    """Metres (inf or NaN: no reading) as uint16 millimetres (0: no reading, beyond 65.5 m clipped)."""
    ok = np.isfinite(depth_m)
    return np.where(ok, np.clip(np.round(np.where(ok, depth_m, 0) * _MM), 0, 65535), 0).astype(np.uint16)


def _in_image(pts: np.ndarray, k: np.ndarray, pose: np.ndarray,
              shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Which map points a view holds in its (stored) image: their indices, pixel columns and rows, and
    depths along the optical axis (camera-to-map `pose`, intrinsics `k` of the stored image)."""
    rot, t = pose[:3, :3], pose[:3, 3]
    cam = (pts - t) @ rot  # map -> camera: R^T (p - t)
    z = cam[:, 2]
    front = z > 1e-6
    zs = np.where(front, z, 1.0)
    u = np.rint(k[0, 0] * cam[:, 0] / zs + k[0, 2]).astype(np.int64)
    v = np.rint(k[1, 1] * cam[:, 1] / zs + k[1, 2]).astype(np.int64)
    h, w = shape[0], shape[1]
    idx = np.flatnonzero(front & (u >= 0) & (u < w) & (v >= 0) & (v < h))
    return idx, u[idx], v[idx], z[idx]


class FreeSpaceViews:
    """The stored label-frame views (module doc) and the looked-through test of surface vertices."""

    def __init__(self, cfg: FreeSpaceConfig, voxel_size_m: float):
        self.cfg = cfg
        self.voxel_size_m = float(voxel_size_m)
        self.depth_mm: list[np.ndarray] = []
        self.near_mm: list[np.ndarray] = []
        self.intrinsics: list[np.ndarray] = []
        self.poses: list[np.ndarray] = []
        #: Only every `stride`-th offered view is kept; doubled each time the store is thinned.
        self.stride = 1
        self.offered = 0

    def __len__(self) -> int:
        return len(self.depth_mm)

    def add(self, depth: np.ndarray, intrinsic: np.ndarray, pose: np.ndarray) -> None:
        """Offer one label frame: `depth` in metres (0 = no reading, in range), its 3x3 intrinsics and
        camera-to-map pose (the map's local frame, as integrated)."""
        take = self.offered % self.stride == 0
        self.offered += 1
        if not take:
            return
        s = max(1, int(self.cfg.downsample))
        d = np.asarray(depth, np.float32)
        # the nearest reading of each pixel's neighbourhood: far readings just beside a silhouette must
        # not look through the object's edge (no reading = +inf, so it never hides a nearer one)
        reading = np.where(d > 0, d, np.float32(np.inf))
        near = reading
        size = 2 * int(self.cfg.edge_margin_px) + 1
        if size > 1:
            near = cv2.erode(reading, np.ones((size, size), np.uint8), borderType=cv2.BORDER_REPLICATE)
        k = np.asarray(intrinsic, np.float64).copy()
        k[:2] /= s  # pixel centres: u_small = u / s for u a multiple of s
        self.depth_mm.append(_to_mm(reading[::s, ::s]))
        self.near_mm.append(_to_mm(near[::s, ::s]))
        self.intrinsics.append(k)
        self.poses.append(np.asarray(pose, np.float64).copy())
        if len(self.depth_mm) > max(1, int(self.cfg.max_views)):
            self.depth_mm, self.near_mm = self.depth_mm[::2], self.near_mm[::2]
            self.intrinsics, self.poses = self.intrinsics[::2], self.poses[::2]
            self.stride *= 2

    def count(self, points: np.ndarray, base_tolerance_m: float | None = None) -> SeenThrough:
        """For each map point, how many stored views measured it within the tolerance (seen) and how
        many measured something farther along its ray (looked through); views where it is behind a
        nearer reading, outside the image or without a reading count as neither.

        ``base_tolerance_m``: the tolerance's fixed part (None: ``tolerance_voxels`` room voxels). The
        5 mm surface of small things (`fine_surface`) closes a face seen from one side 2 cm (its
        truncation band) behind it, which the room's 2 cm took for measured surface
        (``FreeSpaceConfig.fine_tolerance_m``)."""
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        seen = np.zeros(len(pts), np.int32)
        through = np.zeros(len(pts), np.int32)
        if len(pts) == 0:
            return SeenThrough(seen, through)
        base_tol = float(self.cfg.tolerance_voxels) * self.voxel_size_m if base_tolerance_m is None \
            else float(base_tolerance_m)
        rel_tol = float(self.cfg.tolerance_per_m)
        for depth_mm, near_mm, k, pose in zip(self.depth_mm, self.near_mm, self.intrinsics, self.poses, strict=True):
            idx, u, v, zi = _in_image(pts, k, pose, depth_mm.shape)
            if idx.size == 0:
                continue
            d = depth_mm[v, u].astype(np.float64) / _MM
            near = near_mm[v, u].astype(np.float64) / _MM
            tol = base_tol + rel_tol * zi
            # seen: the pixel's own reading or the nearest of its neighbourhood is where the point is (a
            # slanted surface's neighbourhood holds nearer readings); looked through: even the nearest
            # reading of the neighbourhood lies beyond it
            hit = ((d > 0) & (np.abs(d - zi) <= tol)) | ((near > 0) & (np.abs(near - zi) <= tol))
            seen[idx[hit]] += 1
            through[idx[(near > 0) & (near > zi + tol)]] += 1
        return SeenThrough(seen, through)

    def observed(self, points: np.ndarray, tolerance: float, min_views: int = 1) -> np.ndarray:
        """Per map point: did at least ``min_views`` stored views observe it, i.e. hold it in their image
        with a reading at least as far as the point (less ``tolerance``, m)? A point behind every
        reading, outside every image or only where the sensor returned nothing is unknown
        (``recon_core.geometry.observed_space``)."""
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        need = max(1, int(min_views))
        views = np.zeros(len(pts), np.int32)
        for depth_mm, k, pose in zip(self.depth_mm, self.intrinsics, self.poses, strict=True):
            todo = np.flatnonzero(views < need)
            if todo.size == 0:
                break
            idx, u, v, z = _in_image(pts[todo], k, pose, depth_mm.shape)
            d = depth_mm[v, u].astype(np.float64) / _MM
            reached = (d > 0) & (d >= z - tolerance)
            views[todo[idx[reached]]] += 1
        return views >= need

    def observed_space(self, lower: np.ndarray, upper: np.ndarray, max_cells: int) -> ObservedSpace | None:
        """The observed/unknown grid over the box ``lower``..``upper`` (None: no views stored). A cell
        counts as observed when as many views observed its centre as a thing's surface needs to stay
        core (``min_seen``): a strip one view glimpsed at the edge of its frame is as unknown as the
        surface there, which the core leaves out."""
        if not self.depth_mm:
            return None
        grid = ObservedSpace.unknown(lower, upper, max_cells)
        seen = self.observed(grid.centres(), 0.5 * grid.cell, max(1, int(self.cfg.min_seen)))
        return ObservedSpace(grid.origin, grid.cell, seen.reshape(grid.shape))

    def carved(self, points: np.ndarray, base_tolerance_m: float | None = None, owner: np.ndarray | None = None,
               min_seen_share: float = 0.0) -> np.ndarray:
        """Boolean per point: measured by too few views or looked through (`SeenThrough.carved`, the config);
        ``base_tolerance_m`` as in `count`.

        With ``owner`` (the thing each point belongs to) and ``min_seen_share`` > 0, also the points measured
        by fewer than that share of the median number of views that measured their thing's points: the
        truncation band's shadow past an edge no camera saw. A book lying on a cabinet, every camera on one
        side, had its top closed 1.6-4.5 cm past its far edge, measured there by 1-3 views where the rest of
        it was by a median 14, enough for the absolute `min_seen` (2) but not for its share of the object."""
        if not self.depth_mm or len(points) == 0:
            return np.zeros(len(points), bool)
        cfg = self.cfg
        counts = self.count(points, base_tolerance_m)
        out = counts.carved(int(cfg.min_through), float(cfg.through_ratio), int(cfg.min_seen))
        if owner is None or min_seen_share <= 0.0:
            return out
        ids, group = np.unique(np.asarray(owner).reshape(-1), return_inverse=True)
        order = np.argsort(group, kind="stable")
        bounds = np.searchsorted(group[order], np.arange(len(ids) + 1))
        seen = counts.seen[order]
        # per thing, the median count (a loop over the things, not over their points)
        median = np.array([np.median(seen[a:b]) for a, b in itertools.pairwise(bounds)])
        return out | (counts.seen < float(min_seen_share) * median[group])

    # ------------------------------------------------------------------ persistence
    def state(self) -> dict[str, np.ndarray]:
        """The views as arrays (map.npz): each view's pixels raveled one after another with its (rows,
        columns) beside them, so views of a camera whose resolution changed mid-recording save too."""
        n = len(self.depth_mm)
        return {"depth_mm": np.concatenate([d.ravel() for d in self.depth_mm]) if n else np.zeros(0, np.uint16),
                "near_mm": np.concatenate([d.ravel() for d in self.near_mm]) if n else np.zeros(0, np.uint16),
                "shapes": np.array([d.shape for d in self.depth_mm], np.int64).reshape(n, 2),
                "intrinsics": np.stack(self.intrinsics) if n else np.zeros((0, 3, 3)),
                "poses": np.stack(self.poses) if n else np.zeros((0, 4, 4)),
                "counters": np.array([self.stride, self.offered], np.int64)}

    def load_state(self, state: dict[str, np.ndarray]) -> None:
        shapes = np.asarray(state["shapes"], np.int64).reshape(-1, 2)
        ends = np.cumsum(shapes[:, 0] * shapes[:, 1])
        depth, near = np.asarray(state["depth_mm"], np.uint16), np.asarray(state["near_mm"], np.uint16)
        if len(depth) != (ends[-1] if len(ends) else 0) or len(near) != len(depth):
            raise ValueError("free-space views: pixel count does not match the views' shapes")
        starts = ends - shapes[:, 0] * shapes[:, 1]
        self.depth_mm = [depth[a:b].reshape(h, w) for a, b, (h, w) in zip(starts, ends, shapes, strict=True)]
        self.near_mm = [near[a:b].reshape(h, w) for a, b, (h, w) in zip(starts, ends, shapes, strict=True)]
        self.intrinsics = [np.asarray(k, np.float64).reshape(3, 3) for k in state["intrinsics"]]
        self.poses = [np.asarray(p, np.float64).reshape(4, 4) for p in state["poses"]]
        if not len(self.depth_mm) == len(self.intrinsics) == len(self.poses):
            raise ValueError("free-space views: depth, intrinsics and poses differ in number")
        self.stride, self.offered = (int(x) for x in state["counters"])
