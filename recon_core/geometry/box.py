"""Gravity-aligned oriented 3D box B(p, q, s) of a graph node (paper Sec. 2.1) and its exact IoU.

The orientation q is a pure yaw about the map's z axis (z is against gravity), so a box is a
rotated rectangle (its footprint) times a z interval. Volumes, overlaps and IoU are exact:
rectangle intersection by convex clipping times the z overlap.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from recon_core.geometry.polygon import convex_intersection_area, rectangle

#: Smallest positive float: areas/volumes at or below it are no area (a flat or empty box).
_TINY = float(np.finfo(np.float64).tiny)


@dataclass(frozen=True, eq=False)
class GravityBox:
    """``center`` (map frame), ``size`` along the box's own x, y, z and ``yaw`` about +z (rad)."""

    center: NDArray[np.float64]
    size: NDArray[np.float64]
    yaw: float = 0.0

    def __post_init__(self) -> None:
        c = np.array(self.center, dtype=np.float64).reshape(3)
        s = np.array(self.size, dtype=np.float64).reshape(3)
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(s)) and np.isfinite(self.yaw)):
            raise ValueError(f"box must be finite: center={c.tolist()} size={s.tolist()} yaw={self.yaw}")
        if np.any(s < 0.0):
            raise ValueError(f"box size must be non-negative, got {s.tolist()}")
        c.setflags(write=False)
        s.setflags(write=False)
        object.__setattr__(self, "center", c)
        object.__setattr__(self, "size", s)
        object.__setattr__(self, "yaw", float(self.yaw))

    # ------------------------------------------------------------------ derived
    @property
    def z_min(self) -> float:
        return float(self.center[2] - 0.5 * self.size[2])

    @property
    def z_max(self) -> float:
        return float(self.center[2] + 0.5 * self.size[2])

    @property
    def volume(self) -> float:
        return float(np.prod(self.size))

    @property
    def footprint_area(self) -> float:
        return float(self.size[0] * self.size[1])

    def corners_xy(self) -> NDArray[np.float64]:
        """(4, 2) counter-clockwise footprint corners."""
        return rectangle(self.center[:2], self.size[:2], self.yaw)

    def corners(self) -> NDArray[np.float64]:
        """(8, 3) corners: the 4 bottom ones (CCW), then the 4 top ones."""
        xy = self.corners_xy()
        return np.r_[np.c_[xy, np.full(4, self.z_min)], np.c_[xy, np.full(4, self.z_max)]]

    def aabb(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Axis-aligned (lo, hi) of the box."""
        xy = self.corners_xy()
        return np.r_[xy.min(0), self.z_min], np.r_[xy.max(0), self.z_max]

    def rotation(self) -> NDArray[np.float64]:
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def pose(self) -> NDArray[np.float64]:
        """4x4 box frame -> map (origin at the centre)."""
        t = np.eye(4)
        t[:3, :3] = self.rotation()
        t[:3, 3] = self.center
        return t

    def bottom_pose(self) -> NDArray[np.float64]:
        """4x4 frame at the centre of the bottom face (a natural link origin for a standing object)."""
        t = self.pose()
        t[2, 3] = self.z_min
        return t

    def to_local_xy(self, xy: ArrayLike) -> NDArray[np.float64]:
        """Map-frame (N, 2) points in the box's footprint frame (centre origin, box axes)."""
        p = np.asarray(xy, dtype=np.float64).reshape(-1, 2) - self.center[:2]
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return np.c_[c * p[:, 0] + s * p[:, 1], -s * p[:, 0] + c * p[:, 1]]

    def with_z_range(self, z_lo: float, z_hi: float) -> GravityBox:
        """The same footprint over another vertical interval."""
        lo, hi = min(z_lo, z_hi), max(z_lo, z_hi)
        return GravityBox(np.r_[self.center[:2], 0.5 * (lo + hi)], np.r_[self.size[:2], hi - lo], self.yaw)

    # ------------------------------------------------------------------ overlap
    def footprint_intersection(self, other: GravityBox) -> float:
        """Exact area of the intersection of the two footprints.

        Clipped in a frame at this box's centre: in map coordinates far from the origin (100 km),
        the corners' rounding alone made the area of a 1.5 cm wide box 1e-9 relative off and the
        result depend on the order of the boxes.
        """
        if self.footprint_area <= _TINY or other.footprint_area <= _TINY:
            return 0.0
        rel = other.center[:2] - self.center[:2]
        area = convex_intersection_area(rectangle(np.zeros(2), self.size[:2], self.yaw),
                                        rectangle(rel, other.size[:2], other.yaw))
        return min(area, self.footprint_area, other.footprint_area)

    def z_overlap(self, other: GravityBox) -> float:
        """Length of the common z interval, from the centres' difference (exact far from the origin)."""
        dz = float(other.center[2] - self.center[2])
        h0, h1 = 0.5 * float(self.size[2]), 0.5 * float(other.size[2])
        return max(0.0, min(min(h0, dz + h1) - max(-h0, dz - h1), 2.0 * min(h0, h1)))

    def intersection_volume(self, other: GravityBox) -> float:
        dz = self.z_overlap(other)
        return 0.0 if dz <= 0.0 else self.footprint_intersection(other) * dz

    def iou(self, other: GravityBox) -> float:
        """Exact 3D IoU in [0, 1] (0 when either box has no volume, never NaN), symmetric."""
        a, b = (self, other) if (self.center.tolist(), self.size.tolist(), self.yaw) <= (
            other.center.tolist(), other.size.tolist(), other.yaw) else (other, self)
        inter = min(a.intersection_volume(b), a.volume, b.volume)
        union = a.volume + b.volume - inter
        # no absolute area/volume threshold: a 0.1 mm part (1e-12 m^3) has an IoU like any other box
        return float(min(1.0, inter / union)) if union > _TINY and inter > 0.0 else 0.0

    # ------------------------------------------------------------------ io
    def to_dict(self) -> dict[str, Any]:
        return {"center": self.center.tolist(), "size": self.size.tolist(), "yaw": self.yaw}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> GravityBox:
        return cls(d["center"], d["size"], float(d.get("yaw", 0.0)))

    @classmethod
    def of_points(cls, points: ArrayLike, yaw: float) -> GravityBox:
        """Tight box of (N, 3) ``points`` in the frame rotated by ``yaw`` about z."""
        c, s = np.cos(yaw), np.sin(yaw)
        v = np.asarray(points, np.float64).reshape(-1, 3)
        if len(v) == 0:
            raise ValueError("GravityBox.of_points needs at least one point")
        local = np.c_[c * v[:, 0] + s * v[:, 1], -s * v[:, 0] + c * v[:, 1], v[:, 2]]
        lo, hi = local.min(0), local.max(0)
        mid = (lo + hi) / 2
        center = np.array([c * mid[0] - s * mid[1], s * mid[0] + c * mid[1], mid[2]])
        return cls(center, hi - lo, float(yaw))


def iou_matrix(pred: list[GravityBox], gt: list[GravityBox]) -> NDArray[np.float64]:
    """(P, G) exact IoU; pairs whose axis-aligned bounds do not meet skip the exact test."""
    out = np.zeros((len(pred), len(gt)))
    if not pred or not gt:
        return out
    plo, phi = (np.array(a) for a in zip(*(b.aabb() for b in pred), strict=True))
    glo, ghi = (np.array(a) for a in zip(*(b.aabb() for b in gt), strict=True))
    meet = np.all((plo[:, None] <= ghi[None]) & (glo[None] <= phi[:, None]), axis=2)
    for i, j in zip(*np.nonzero(meet), strict=True):
        out[i, j] = pred[i].iou(gt[j])
    return out
