"""Planes of the shared core: ``Plane`` (n . x + d = 0, outward unit normal) and ``SurfacePlane``.

A plane is the one geometric primitive every stage exchanges: RANSAC planes of CAD models and of
reconstructed meshes (paper Sec. 2.2 / 4.1), the supporting planes of the contact graph (Eq. (1)-(2))
and the plane-matching term of CAD matching (Eq. 9). ``SurfacePlane`` adds what the contact graph
keeps with a node's plane: where it came from and, for a supporting plane, the region (triangles
or points projected to the floor plane) that Eq. (2) measures.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from recon_core.geometry.gravity import GRAVITY, UP
from recon_core.geometry.polygon import EPS
from recon_core.geometry.transforms import EPS_NORM

#: A plane whose unit normal has ``n . up`` above this is horizontal and facing up (paper: 0.9).
SUPPORT_NORMAL_COS = 0.9

#: Sources of a surface plane: RANSAC, a height group of upward faces, or inferred (an invisible
#: supporting plane registered from a child's bottom, Sec. 2.2).
SOURCES = ("ransac", "height_group", "inferred")


def finite_vector(value: ArrayLike, size: int, what: str) -> NDArray[np.float64]:
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
        n = finite_vector(self.normal, 3, "plane normal")
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


@dataclass(eq=False)
class SurfacePlane:
    """A plane n . x + d = 0 (outward unit n) of a node, with its supporting region if horizontal.

    ``region_triangles`` (F, 3, 2): the node's triangles on the plane, in map x-y; ``region_points``
    (N, 2): the same for point input. Both empty for non-supporting planes and inferred planes
    (an inferred plane's region is its owner's box footprint, set by the support step).
    """

    plane: Plane
    source: str = "ransac"
    region_triangles: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3, 2)))
    region_points: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))

    _bounds: tuple[NDArray[np.float64], NDArray[np.float64]] | None = field(default=None, repr=False)

    def region_bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Per-triangle x-y bounds (F, 2) lo/hi of the region, computed once (Eq. (2) runs per child)."""
        if self._bounds is None or len(self._bounds[0]) != len(self.region_triangles):
            self._bounds = (self.region_triangles.min(axis=1), self.region_triangles.max(axis=1))
        return self._bounds

    @property
    def normal(self) -> NDArray[np.float64]:
        return self.plane.normal

    @property
    def d(self) -> float:
        return self.plane.d

    def is_support(self, a_th: float) -> bool:
        """Eq. (1), first condition: n . g <= a_th (horizontal, facing against gravity)."""
        return bool(self.plane.normal @ GRAVITY <= a_th)

    def height_at(self, xy: NDArray[np.float64]) -> float:
        """z of the plane above map point ``xy`` (guarded: vertical planes have no height)."""
        n = self.plane.normal
        if abs(n[2]) < EPS:
            return float("nan")
        return float(-(self.plane.d + n[0] * xy[0] + n[1] * xy[1]) / n[2])

    def to_dict(self) -> dict[str, Any]:
        return {"normal": self.plane.normal.tolist(), "d": self.plane.d, "area": self.plane.area,
                "source": self.source}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SurfacePlane:
        return cls(Plane(normal=d["normal"], d=d["d"], area=d.get("area", 0.0)), d.get("source", "ransac"))
