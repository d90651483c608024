"""Matching features of a CAD model (paper Sec. 2.1 / 4.1): box, surface planes, support surfaces.

These are plain data: they are computed once per model (analytically for procedural models, by
RANSAC for imported ones, see ``features.py``), cached as JSON by ``CadLibrary`` and compared
against the features of reconstructed object meshes by the matching stage. Everything is expressed
in the model's canonical frame (z up, front +x, origin at the bottom centre of the closed model).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .transforms import EPS_NORM

#: A plane whose unit normal has ``n . up`` above this is horizontal and facing up (paper: 0.9).
SUPPORT_NORMAL_COS = 0.9
#: Up direction of the canonical frame.
UP = np.array([0.0, 0.0, 1.0])


def _vec(value: ArrayLike, size: int, what: str) -> NDArray[np.float64]:
    arr = np.array(value, dtype=np.float64).reshape(size)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} must be finite, got {arr.tolist()}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Plane:
    """Plane ``normal . x + d = 0`` with a unit, outward-pointing normal.

    ``area`` is the (approximate) surface area that lies on the plane; the matching stage uses it
    to weight planes. ``support`` marks upward horizontal planes that can carry other objects.
    """

    normal: NDArray[np.float64]
    d: float
    area: float = 0.0

    def __post_init__(self) -> None:
        n = _vec(self.normal, 3, "plane normal")
        length = float(np.linalg.norm(n))
        if length < EPS_NORM:
            raise ValueError("plane normal must be non-zero")
        n = n / length
        n.setflags(write=False)
        object.__setattr__(self, "normal", n)
        object.__setattr__(self, "d", float(self.d) / length)
        object.__setattr__(self, "area", float(self.area))

    @property
    def support(self) -> bool:
        """Whether the plane is horizontal and faces up (a potential supporting plane)."""
        return bool(self.normal @ UP > SUPPORT_NORMAL_COS)

    def signed_distance(self, points: ArrayLike) -> NDArray[np.float64]:
        """Signed distance of (N, 3) points, positive on the outward side."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return p @ self.normal + self.d

    def as_vector(self) -> NDArray[np.float64]:
        """Homogeneous ``[n, d]`` 4-vector (paper notation)."""
        return np.append(self.normal, self.d)

    def to_dict(self) -> dict[str, Any]:
        return {"normal": self.normal.tolist(), "d": self.d, "area": self.area}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Plane:
        return cls(normal=data["normal"], d=data["d"], area=data.get("area", 0.0))


def polygon_area(polygon: ArrayLike) -> float:
    """Signed-area-free (absolute) area of a simple 2D polygon (shoelace)."""
    p = np.asarray(polygon, dtype=np.float64).reshape(-1, 2)
    if len(p) < 3:
        return 0.0
    x, y = p[:, 0], p[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


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
    safe_dy = np.where(np.abs(dy) < EPS_NORM, 1.0, dy)
    x_cross = a[..., 0] + (py - a[..., 1]) * (b[..., 0] - a[..., 0]) / safe_dy
    crossings = straddles & (px < x_cross)
    return (np.count_nonzero(crossings, axis=1) % 2) == 1


@dataclass(frozen=True, eq=False)
class SupportSurface:
    """A horizontal, upward surface on which small objects can stand.

    ``polygon`` is the (N, 2) outline (counter-clockwise) in the model frame's x-y plane at the closed
    configuration, ``height`` its z. ``clearance`` is the free height above it (e.g. the spacing
    to the next shelf level); ``None`` means unbounded (a table top). ``link`` is the link carrying
    the surface (a drawer bottom moves with the drawer) and ``enclosed`` says whether the surface is
    hidden behind doors/drawers when closed (not visible to a camera, so not a matching plane).
    """

    height: float
    polygon: NDArray[np.float64]
    clearance: float | None = None
    link: str = "body"
    enclosed: bool = False

    def __post_init__(self) -> None:
        poly = np.array(self.polygon, dtype=np.float64).reshape(-1, 2)
        if len(poly) < 3 or not np.all(np.isfinite(poly)):
            raise ValueError("support polygon needs at least 3 finite vertices")
        x, y = poly[:, 0], poly[:, 1]
        if float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) < 0.0:
            poly = poly[::-1].copy()
        poly.setflags(write=False)
        object.__setattr__(self, "polygon", poly)
        object.__setattr__(self, "height", float(self.height))
        if self.clearance is not None:
            c = float(self.clearance)
            if not math.isfinite(c) or c < 0.0:
                raise ValueError(f"clearance must be a finite non-negative number, got {c}")
            object.__setattr__(self, "clearance", c)

    @property
    def area(self) -> float:
        return polygon_area(self.polygon)

    @property
    def plane(self) -> Plane:
        """The supporting plane ``z - height = 0`` (normal +z)."""
        return Plane(normal=UP, d=-self.height, area=self.area)

    def contains(self, xy: ArrayLike) -> NDArray[np.bool_]:
        """Which (N, 2) points lie inside the outline."""
        return points_in_polygon(xy, self.polygon)

    def scaled(self, factors: ArrayLike) -> SupportSurface:
        s = _vec(factors, 3, "scale factors")
        return SupportSurface(
            height=self.height * s[2],
            polygon=self.polygon * s[:2],
            clearance=None if self.clearance is None else self.clearance * s[2],
            link=self.link,
            enclosed=self.enclosed,
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "height": self.height,
            "polygon": self.polygon.tolist(),
            "clearance": self.clearance,
            "link": self.link,
            "enclosed": self.enclosed,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SupportSurface:
        return cls(
            height=data["height"],
            polygon=data["polygon"],
            clearance=data.get("clearance"),
            link=str(data.get("link", "body")),
            enclosed=bool(data.get("enclosed", False)),
        )


@dataclass(frozen=True, eq=False)
class ModelFeatures:
    """Precomputed matching features of one model in its canonical frame (closed configuration).

    * ``box_center``/``box_size``: the gravity-aligned (here axis-aligned) bounding box;
    * ``planes``: outward surface planes (support planes are those with ``plane.support``);
    * ``support_surfaces``: the support planes with their extents and free clearance.
    """

    box_center: NDArray[np.float64]
    box_size: NDArray[np.float64]
    planes: tuple[Plane, ...] = ()
    support_surfaces: tuple[SupportSurface, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        object.__setattr__(self, "box_center", _vec(self.box_center, 3, "box centre"))
        size = _vec(self.box_size, 3, "box size")
        if np.any(size < 0.0):
            raise ValueError(f"box size must be non-negative, got {size.tolist()}")
        object.__setattr__(self, "box_size", size)
        object.__setattr__(self, "planes", tuple(self.planes))
        object.__setattr__(self, "support_surfaces", tuple(self.support_surfaces))

    @property
    def support_planes(self) -> tuple[Plane, ...]:
        return tuple(p for p in self.planes if p.support)

    def plane_array(self) -> NDArray[np.float64]:
        """(K, 4) array of ``[n, d]`` rows (empty (0, 4) when there are no planes)."""
        if not self.planes:
            return np.zeros((0, 4))
        return np.stack([p.as_vector() for p in self.planes])

    def scaled(self, factors: ArrayLike | float) -> ModelFeatures:
        """Features of the model scaled by ``diag(factors)`` about the model origin (exact).

        A plane ``n.x + d = 0`` maps to ``(S^-1 n).x' + d = 0``, renormalised.
        """
        s = np.broadcast_to(np.asarray(factors, dtype=np.float64), (3,)).copy()
        if np.any(~np.isfinite(s)) or np.any(s <= 0.0):
            raise ValueError(f"scale factors must be positive, got {s.tolist()}")
        planes = []
        for p in self.planes:
            n = p.normal / s
            length = float(np.linalg.norm(n))
            # Area scales with the product of the two in-plane factors: |det S| * |S^-T n|.
            area_scale = float(np.prod(s)) * length
            planes.append(Plane(normal=n / length, d=p.d / length, area=p.area * area_scale))
        return ModelFeatures(
            box_center=self.box_center * s,
            box_size=self.box_size * s,
            planes=tuple(planes),
            support_surfaces=tuple(sf.scaled(s) for sf in self.support_surfaces),
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "box_center": self.box_center.tolist(),
            "box_size": self.box_size.tolist(),
            "planes": [p.to_dict() for p in self.planes],
            "support_surfaces": [s.to_dict() for s in self.support_surfaces],
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ModelFeatures:
        return cls(
            box_center=data["box_center"],
            box_size=data["box_size"],
            planes=tuple(Plane.from_dict(p) for p in data.get("planes", ())),
            support_surfaces=tuple(SupportSurface.from_dict(s) for s in data.get("support_surfaces", ())),
        )


def merge_planes(planes: Sequence[Plane], normal_cos: float = 0.999, offset_tol: float = 1e-3) -> list[Plane]:
    """Merge near-identical planes (same outward normal, same offset), keeping the larger area."""
    kept: list[Plane] = []
    for p in planes:
        for i, q in enumerate(kept):
            if float(p.normal @ q.normal) > normal_cos and abs(p.d - q.d) < offset_tol:
                if p.area > q.area:
                    kept[i] = p
                break
        else:
            kept.append(p)
    return kept


__all__ = [
    "SUPPORT_NORMAL_COS",
    "UP",
    "ModelFeatures",
    "Plane",
    "SupportSurface",
    "merge_planes",
    "points_in_polygon",
    "polygon_area",
]
