"""Matching features of a CAD model (paper Sec. 2.1 / 4.1): box, surface planes, support surfaces.

These are plain data: they are computed once per model (analytically for procedural models, by
RANSAC for imported ones, see ``features.py``), cached as JSON by ``CadLibrary`` and compared
against the features of reconstructed object meshes by the matching stage. Everything is expressed
in the model's canonical frame (z up, front +x, origin at the bottom centre of the closed model).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from recon_core.geometry.gravity import UP
from recon_core.geometry.plane import SUPPORT_NORMAL_COS, Plane, finite_vector, merge_planes
from recon_core.geometry.polygon import points_in_polygon, polygon_area


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
        s = finite_vector(factors, 3, "scale factors")
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
        object.__setattr__(self, "box_center", finite_vector(self.box_center, 3, "box centre"))
        size = finite_vector(self.box_size, 3, "box size")
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
