"""Which space around an entity the cameras observed: a coarse boolean grid (issue 22, item 4).

A camera that measured depth ``d`` along a ray observed everything on that ray up to ``d``: the
space in front of the surface is free, the surface itself is measured. What lies behind the
surface, outside every frustum or beyond the sensor's range is *unknown*. An object's unseen back,
a table's far half outside every frame and a cup's handle behind its body are unknown, not absent:
a CAD model may put surface there without contradicting the observation. Stage 4 reads this grid
to leave such model surface out of its "missing data" terms (``cad_replacement.alignment``) and
to know on which sides an observed box may grow (``cad_replacement.matching``).

The grid is axis-aligned in the (gravity-aligned) map frame around one entity; a cell is
``True`` when enough stored views observed its centre (measured it or looked past it) or when it
holds another entity's surface. The mapper builds it from its label-frame views
(``panoptic_mapping.free_space``, ``FreeSpaceViews.observed_space``); outside the grid
nothing is known about the views, and ``observed_at`` answers ``True`` there, which is what stage
4 assumed before the grid existed (every side a camera direction covers counts as seen).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from recon_core.errors import InputError
from recon_core.geometry.box import GravityBox

#: Most cells along one axis of a grid (the cell size follows the region's largest extent).
MAX_CELLS_PER_AXIS = 32
#: ``room``: probe lines per direction (across the face, up its height).
ROOM_LINES = 6


@dataclass(frozen=True, eq=False)
class ObservedSpace:
    """Observed (``True``) and unknown (``False``) cells of an axis-aligned grid in the map frame.

    ``origin`` is the corner of cell (0, 0, 0), ``cell`` the edge length (m) of the cubic cells and
    ``observed`` the (nx, ny, nz) boolean grid.
    """

    origin: NDArray[np.float64]
    cell: float
    observed: NDArray[np.bool_]

    def __post_init__(self) -> None:
        origin = np.asarray(self.origin, dtype=np.float64).reshape(-1)
        grid = np.asarray(self.observed, dtype=bool)
        if origin.shape != (3,) or not np.all(np.isfinite(origin)):
            raise InputError(f"observed space: origin must be 3 finite numbers, got {origin.tolist()}")
        if not (np.isfinite(self.cell) and self.cell > 0):
            raise InputError(f"observed space: cell size must be positive and finite, got {self.cell}")
        if grid.ndim != 3 or min(grid.shape) < 1:
            raise InputError(f"observed space: the grid must be 3-D and non-empty, got shape {grid.shape}")
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "cell", float(self.cell))
        object.__setattr__(self, "observed", grid)

    @property
    def shape(self) -> tuple[int, int, int]:
        nx, ny, nz = self.observed.shape
        return int(nx), int(ny), int(nz)

    @property
    def upper(self) -> NDArray[np.float64]:
        """The corner opposite ``origin``."""
        return self.origin + self.cell * np.asarray(self.shape, dtype=np.float64)

    @classmethod
    def unknown(cls, lower: ArrayLike, upper: ArrayLike, max_cells: int = MAX_CELLS_PER_AXIS) -> ObservedSpace:
        """An all-unknown grid over the box ``lower``..``upper`` (cubic cells, at most ``max_cells`` along
        the longest side), to be filled in. The region's extent must be finite and positive."""
        lo = np.asarray(lower, dtype=np.float64).reshape(3)
        hi = np.asarray(upper, dtype=np.float64).reshape(3)
        extent = hi - lo
        if not (np.all(np.isfinite(extent)) and np.all(extent > 0)):
            raise InputError(f"observed space: region {lo.tolist()}..{hi.tolist()} is empty or not finite")
        cell = float(extent.max()) / max(1, int(max_cells))
        shape = tuple(int(n) for n in np.maximum(np.ceil(extent / cell - 1e-9), 1).astype(np.int64))
        return cls(lo, cell, np.zeros(shape, dtype=bool))

    def _cells(self, points: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
        """Integer cell indices of points (any leading shape, last axis xyz) and whether each lies in the grid."""
        q = np.floor((points - self.origin) / self.cell)
        inside = np.all((q >= 0) & (q < np.asarray(self.shape)), axis=-1)
        return np.where(np.isfinite(q), q, -1).astype(np.int64), inside

    def centres(self) -> NDArray[np.float64]:
        """(nx * ny * nz, 3) cell centres in C order (the order of ``observed.ravel()``)."""
        idx = np.indices(self.shape).reshape(3, -1).T
        return self.origin + (idx + 0.5) * self.cell

    def observed_at(self, points: ArrayLike) -> NDArray[np.bool_]:
        """Per point: observed (``True``), or unknown (``False``); outside the grid ``True`` (nothing known)."""
        q, inside = self._cells(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        out = np.ones(len(q), dtype=bool)
        qi = q[inside]
        out[inside] = self.observed[qi[:, 0], qi[:, 1], qi[:, 2]]
        return out

    def room(self, box: GravityBox) -> NDArray[np.float64]:
        """(2, 2) metres: how far unknown space reaches beyond the box's -x/+x (row 0) and -y/+y (row 1)
        face, in the box frame. There the observed extent is only a lower bound: the object may go on
        where no camera looked (a table's far half outside every frame), but not through space a camera
        saw empty nor through another surface (the wall behind a cabinet stops it; the unknown space
        behind the wall is not the cabinet's).

        Probed along ``ROOM_LINES`` x ``ROOM_LINES`` lines normal to the face, over the middle 80 % of
        its width and from 10 % of the box's height to its top, cell by cell outwards from the face:
        a line's room is the distance to its first observed cell (or to the grid's edge), and the
        side's the median over its lines. 0 where the face's lines leave the grid at once.
        """
        half = 0.5 * np.asarray(box.size[:2], dtype=np.float64)
        steps = (np.arange(2 * MAX_CELLS_PER_AXIS) + 0.5) * self.cell
        frac = (np.arange(ROOM_LINES) + 0.5) / ROOM_LINES
        across, heights = 0.8 * frac - 0.4, box.z_min + (box.z_max - box.z_min) * (0.1 + 0.9 * frac)
        c_idx, z = (g.ravel() for g in np.meshgrid(across, heights, indexing="ij"))
        rot = box.rotation()[:2, :2]
        shape = np.asarray(self.shape)
        out = np.zeros((2, 2))
        for k in (0, 1):
            for e, sign in enumerate((-1.0, 1.0)):
                local = np.zeros((len(c_idx), len(steps), 2))
                local[..., k] = sign * (half[k] + steps[None, :])
                local[..., 1 - k] = (c_idx * 2.0 * half[1 - k])[:, None]
                xy = local @ rot.T + np.asarray(box.center[:2], dtype=np.float64)
                pts = np.concatenate([xy, np.broadcast_to(z[:, None, None], (*xy.shape[:2], 1))], axis=2)
                q, inside = self._cells(pts)
                qc = np.clip(q, 0, shape - 1)
                blocked = ~inside | self.observed[qc[..., 0], qc[..., 1], qc[..., 2]]
                first = np.where(blocked.any(axis=1), blocked.argmax(axis=1), len(steps))
                out[k, e] = float(np.median(first)) * self.cell
        return out

    def with_surface(self, points: ArrayLike) -> ObservedSpace:
        """This grid with every cell that holds one of ``points`` (other objects' measured surface)
        marked observed: space something else takes is not room for this object."""
        q, inside = self._cells(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        if not np.any(inside):
            return self
        qi = q[inside]
        grid = self.observed.copy()
        grid[qi[:, 0], qi[:, 1], qi[:, 2]] = True
        return ObservedSpace(self.origin, self.cell, grid)

    @property
    def observed_share(self) -> float:
        return float(self.observed.mean())

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form: the grid bit-packed (C order) as hex, beside origin, cell and shape."""
        return {"origin": self.origin.tolist(), "cell": self.cell, "shape": list(self.shape),
                "bits": self.packed().tobytes().hex()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ObservedSpace:
        try:
            shape = tuple(int(n) for n in d["shape"])
            bits = np.frombuffer(bytes.fromhex(str(d["bits"])), dtype=np.uint8)
            return cls.from_packed(d["origin"], float(d["cell"]), shape, bits)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"observed space: cannot read {exc}") from exc

    @classmethod
    def from_packed(cls, origin: ArrayLike, cell: float, shape: tuple[int, ...], bits: ArrayLike) -> ObservedSpace:
        """From the bit-packed grid (``numpy.packbits`` of the C-order cells) of a message or a file."""
        if len(shape) != 3 or min(shape) < 1:
            raise InputError(f"observed space: shape must be 3 positive sizes, got {list(shape)}")
        n = int(np.prod(shape))
        packed = np.asarray(bits, dtype=np.uint8).reshape(-1)
        if len(packed) != (n + 7) // 8:
            raise InputError(f"observed space: {len(packed)} bytes for {n} cells (expected {(n + 7) // 8})")
        grid = np.unpackbits(packed, count=n).astype(bool).reshape(shape)
        return cls(np.asarray(origin, dtype=np.float64), float(cell), grid)

    def packed(self) -> NDArray[np.uint8]:
        return np.packbits(self.observed.ravel())


__all__ = ["MAX_CELLS_PER_AXIS", "ROOM_LINES", "ObservedSpace"]
