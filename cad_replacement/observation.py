"""What stage 4 (CAD replacement, paper Sec. 4) knows about one segmented entity, and its front side.

An ``ObjectObservation`` is the input of matching (Sec. 4.2) and alignment (Sec. 4.3): the entity's
surface points in the map frame (z against gravity), optional normals, its gravity-aligned box
``B_x`` (paper Sec. 2.1), the height of the plane it stands on (the support constraint of Eq. 11)
and, optionally, a hint on which horizontal direction its front faces. The paper has no front
term; without one a closed cabinet and the same cabinet turned by 180 degrees fit the data almost
equally well, so the hint (open space in front, camera positions) breaks that tie.

Validation happens here, once: every later stage may assume finite float64 points, at least
``MIN_POINTS`` of them, spanning a non-degenerate (not collinear) set.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from recon_core.errors import InputError
from recon_core.geometry.box import GravityBox
from recon_core.geometry.box_fit import fit_gravity_box
from recon_core.geometry.observed_space import ObservedSpace
from recon_core.geometry.plane import Plane
from recon_core.geometry.plane_fit import sample_mesh

#: Fewest points an observation may have: three define a plane, more are needed to fit 6 parameters.
MIN_POINTS = 8
#: Points drawn from a mesh when an observation is built from one.
MESH_SAMPLES = 4000
#: Second singular value (m) of the centred points below which they are considered collinear.
COLLINEAR_TOL = 1e-4
#: Norm below which a direction is treated as zero.
EPS = 1e-12


class ObservationError(InputError):
    """The observation cannot be matched (empty, non-finite or degenerate points, bad fields)."""


def _unit2(v: ArrayLike | None) -> NDArray[np.float64] | None:
    if v is None:
        return None
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.size not in (2, 3) or not np.all(np.isfinite(a)):
        raise ObservationError(f"front_hint must be a finite 2D direction, got {a.tolist()}")
    a = a[:2]
    n = float(np.linalg.norm(a))
    if n < 1e-9:
        raise ObservationError("front_hint must be non-zero (use None for 'unknown')")
    return a / n


@dataclass(frozen=True, eq=False)
class ObjectObservation:
    """One segmented entity as seen by stage 4 (map frame, z up, float64).

    ``points`` (N, 3): surface samples of the entity; ``normals`` (N, 3) optional outward normals
    (they sharpen the plane features and tell alignment which sides of the object were seen);
    ``box``: its gravity-aligned box (computed from the points when omitted); ``support_z``: top
    of the supporting plane (the model's bottom is put there, Eq. 11's constraint) or ``None``;
    ``front_hint``: unit xy direction towards open space/the camera, ``None`` when unknown;
    ``observed_space``: the space around the entity the cameras observed (``None``: not known), so
    model surface in unknown space is unseen rather than missing, and the box may grow into it;
    ``walls``: the room's wall planes, through which it may not grow (the space behind a cabinet
    against a wall is unknown, and so is the space behind the wall); ``neighbours``: the boxes of the
    other entities, whose surface is theirs even where the mapper joined some of it to this one;
    ``loads``: the boxes of the objects the contact graph puts on this one (what it carries), which
    hide the top under and behind them (``hidden_by_loads``).
    """

    entity_id: int
    name: str
    class_name: str
    points: NDArray[np.float64]
    box: GravityBox | None = None
    normals: NDArray[np.float64] | None = None
    support_z: float | None = None
    front_hint: NDArray[np.float64] | None = None
    mesh: trimesh.Trimesh | None = field(default=None, repr=False)
    observed_space: ObservedSpace | None = field(default=None, repr=False)
    walls: tuple[Plane, ...] = field(default=(), repr=False)
    neighbours: tuple[GravityBox, ...] = field(default=(), repr=False)
    loads: tuple[GravityBox, ...] = field(default=(), repr=False)
    #: ``room`` per box (matching and the fit's start ask for the same frames).
    _rooms: dict[tuple[float, ...], NDArray[np.float64]] = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        pts = np.array(self.points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ObservationError(f"{self.name!r}: points must be (N, 3), got shape {pts.shape}")
        if len(pts) < MIN_POINTS:
            raise ObservationError(f"{self.name!r}: needs at least {MIN_POINTS} points, got {len(pts)}")
        if not np.all(np.isfinite(pts)):
            raise ObservationError(f"{self.name!r}: points contain NaN or inf")
        centred = pts - pts.mean(axis=0)
        sv = np.linalg.svd(centred, compute_uv=False)
        if sv.size < 2 or sv[1] / np.sqrt(len(pts)) < COLLINEAR_TOL:
            raise ObservationError(f"{self.name!r}: points are degenerate (all on one line or point)")
        pts.setflags(write=False)
        object.__setattr__(self, "points", pts)
        if self.normals is not None:
            nrm = np.array(self.normals, dtype=np.float64)
            if nrm.shape != pts.shape or not np.all(np.isfinite(nrm)):
                raise ObservationError(f"{self.name!r}: normals must be finite and shaped like points")
            length = np.linalg.norm(nrm, axis=1, keepdims=True)
            nrm = np.where(length > EPS, nrm / np.maximum(length, EPS), 0.0)
            nrm.setflags(write=False)
            object.__setattr__(self, "normals", nrm)
        if self.box is None:
            object.__setattr__(self, "box", fit_gravity_box(pts))
        if self.support_z is not None:
            z = float(self.support_z)
            if not np.isfinite(z):
                raise ObservationError(f"{self.name!r}: support_z must be finite")
            object.__setattr__(self, "support_z", z)
        object.__setattr__(self, "front_hint", _unit2(self.front_hint))

    @property
    def gravity_box(self) -> GravityBox:
        """The box (always set after construction)."""
        assert self.box is not None
        return self.box

    def observed_at(self, points: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Per map point: could a camera have seen it (``True``), or does it lie in space no view
        observed (``False``: behind the surface, outside every frustum)? Everywhere ``True`` without
        an ``observed_space``."""
        if self.observed_space is None:
            return np.ones(len(points), dtype=bool)
        return self.observed_space.observed_at(points)

    def observed_in_front(self, points: NDArray[np.float64], normals: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Per model surface point with its unit outward normal: did a camera observe the space just in
        front of it (``observed_at`` one grid cell out along the normal)? Everywhere ``True`` without an
        ``observed_space``.

        A surface is contradicted by a view only where the view saw the space in front of it empty
        (or saw it): a camera that looked there would have measured the surface. The point's own
        cell is the wrong test at the grid's resolution (5-10 cm cells): the cell that holds a table
        top also holds the few millimetres of free space above it, which rays skimming the top pass,
        so the hidden far half of a table counted as observed in 15-26 % of its top cells (gen-7373)
        and pulled the fit back onto the seen half. One cell out, the same strip is unknown.
        """
        if self.observed_space is None:
            return np.ones(len(points), dtype=bool)
        out = np.asarray(points, dtype=np.float64) + self.observed_space.cell * np.asarray(normals, dtype=np.float64)
        return self.observed_space.observed_at(out)

    def hidden_by_loads(self, points: NDArray[np.float64], normals: NDArray[np.float64],
                        elevation_deg: float) -> NDArray[np.bool_]:
        """Per model surface point with its unit outward normal: is it an upward face hidden by what this
        object carries (``loads``)? A top is hidden under a load and behind it, seen from the camera's side
        (``front_hint``) along a line of sight rising at ``elevation_deg``: the point is hidden when that
        ray meets a load's box. All ``False`` without loads, without a front hint or at elevation 0.

        A monitor on a table hides the table top behind it from a camera in front: on gen-7373 the top
        behind the monitor was mapped as a sparse strip beside it, the rest of it "missing", and the fit
        shrank the table onto its seen front half (30 cm short, 20 cm off) although the strip, the far
        legs and the observed box said how long it is. The camera poses are not known here; a camera
        1.2-1.6 m high looking at a 0.75 m top from 1.5-3 m sees it at 15-30 degrees, and the lower the
        line of sight, the longer the shadow.
        """
        out = np.zeros(len(points), dtype=bool)
        if not self.loads or self.front_hint is None or not elevation_deg > 0.0:
            return out
        up = np.flatnonzero(np.asarray(normals, dtype=np.float64)[:, 2] > UP_FACE_COS)
        if len(up) == 0:
            return out
        e = np.radians(min(float(elevation_deg), 89.0))
        ray = np.r_[np.asarray(self.front_hint, dtype=np.float64) * np.cos(e), np.sin(e)]
        p = np.asarray(points, dtype=np.float64)[up]
        hit = np.zeros(len(up), dtype=bool)
        for box in self.loads:
            hit |= _ray_meets_box(p, ray, box)
        out[up[hit]] = True
        return out

    def room(self, box: GravityBox) -> NDArray[np.float64]:
        """(2, 2) metres of unknown space beyond the box's -x/+x, -y/+y faces (``ObservedSpace.room``),
        up to the nearest wall ahead of each face; none without an ``observed_space``."""
        if self.observed_space is None:
            return np.zeros((2, 2))
        key = (*box.center, *box.size, box.yaw)
        cached = self._rooms.get(key)
        if cached is None:
            cached = self._rooms[key] = self._room(box)
        return cached.copy()

    def _room(self, box: GravityBox) -> NDArray[np.float64]:
        assert self.observed_space is not None
        room = self.observed_space.room(box)
        if not self.walls:
            return room
        rot = box.rotation()[:2, :2]
        center = np.asarray(box.center, dtype=np.float64)
        for k in (0, 1):
            for e, sign in enumerate((-1.0, 1.0)):
                ahead = np.r_[sign * rot[:, k], 0.0]
                face = center + 0.5 * float(box.size[k]) * ahead
                for wall in self.walls:
                    along = float(wall.normal @ ahead)
                    if abs(along) < WALL_MIN_COS:
                        continue
                    t = -(float(wall.normal @ face) + wall.d) / along
                    if t > -WALL_BEHIND_M:
                        room[k, e] = min(room[k, e], max(t, 0.0))
        return room

    @property
    def bottom_z(self) -> float:
        """Where the model's bottom goes: the support plane when known, else the lowest point."""
        return float(self.support_z) if self.support_z is not None else float(self.points[:, 2].min())

    @classmethod
    def from_mesh(
        cls,
        entity_id: int,
        name: str,
        class_name: str,
        mesh: trimesh.Trimesh,
        *,
        samples: int = MESH_SAMPLES,
        seed: int = 0,
        **kwargs: object,
    ) -> ObjectObservation:
        """Area-uniform surface samples (with face normals) of an entity mesh given in the map frame."""
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            raise ObservationError(f"{name!r}: mesh is empty")
        pts, nrm = sample_mesh(mesh, samples, seed)
        return cls(entity_id, name, class_name, pts, normals=nrm, mesh=mesh, **kwargs)  # type: ignore[arg-type]


def grown_into_unknown(box: GravityBox, room: NDArray[np.float64], target: NDArray[np.float64]) -> GravityBox:
    """The box grown along its x/y axes towards ``target`` (box-frame sizes) into the unknown space
    beyond its faces (``room``, as ``ObservedSpace.room``).

    An observed extent with unknown space beyond it is a lower bound: a start that keeps it makes the
    fit shrink a half-seen table to its seen half. Along each axis the growth is split evenly between
    the two faces, each taking at most its room and the other face the rest of what it has room for,
    so the seen end of a half-seen object stays where it was seen."""
    size = np.asarray(box.size, dtype=np.float64).copy()
    shift = np.zeros(2)
    for k in (0, 1):
        grow = float(target[k]) - size[k]
        lo_room, hi_room = max(float(room[k, 0]), 0.0), max(float(room[k, 1]), 0.0)
        if not np.isfinite(grow) or grow <= 0.0 or lo_room + hi_room <= 0.0:
            continue
        grow = min(grow, lo_room + hi_room)
        lo = min(0.5 * grow, lo_room)
        hi = min(grow - lo, hi_room)
        lo = grow - hi
        size[k] += grow
        shift[k] = 0.5 * (hi - lo)
    if not np.any(size[:2] != box.size[:2]):
        return box
    center = np.asarray(box.center, dtype=np.float64).copy()
    center[:2] += box.rotation()[:2, :2] @ shift
    return GravityBox(center, size, box.yaw)


#: ``room``: a wall counts when a face's normal meets it at least this steeply (cosine) ...
WALL_MIN_COS = 0.5
#: ... and lies ahead of the face, or at most this far (m) behind it (an object seen into the wall).
WALL_BEHIND_M = 0.05


#: Height band (m) above the supporting plane in which up-facing points count as the support's surface.
SUPPORT_BAND = 0.015
#: Margin (m) around a supported child's box inside which the parent's points are the child's.
CHILD_MARGIN = 0.01
#: Cleaning never keeps fewer than this fraction of the points (it would be removing the object).
MIN_KEPT_FRACTION = 0.3


def _inside_box(points: NDArray[np.float64], box: GravityBox, margin: float = 0.0,
                below: float | None = None) -> NDArray[np.bool_]:
    """Per point: inside the gravity-aligned box grown by ``margin`` (its footprint, its height range; below
    its bottom by ``below`` when given, else by ``margin`` too)."""
    xy = box.to_local_xy(points[:, :2])
    half = 0.5 * np.asarray(box.size[:2], dtype=np.float64) + margin
    low = margin if below is None else below
    return (np.all(np.abs(xy) <= half, axis=1) & (points[:, 2] >= box.z_min - low)
            & (points[:, 2] <= box.z_max + margin))


def clean_entity_points(
    points: NDArray[np.float64],
    normals: NDArray[np.float64] | None,
    support_z: float | None,
    child_boxes: Sequence[GravityBox] = (),
) -> NDArray[np.bool_]:
    """Mask of an entity's points that belong to the object itself (not its support or its load).

    A mapped entity carries fragments of its neighbours: the label fringe around a cup includes a
    ring of the table top under it, and a cabinet's surface includes pieces of the bottle standing on
    it. Both inflate the box that matching and the height term (Eq. 13) start from, so a 5 cm bottle
    became 17 cm wide and a cabinet grew by the bottle's height. Removed: up-facing points within
    ``SUPPORT_BAND`` above the supporting plane, and points inside (``CHILD_MARGIN`` around) the boxes
    of the objects the contact graph puts on this one. When that would remove more than
    ``1 - MIN_KEPT_FRACTION`` of the points, nothing is removed (the graph is more likely wrong).
    """
    pts = np.asarray(points, dtype=np.float64)
    keep = np.ones(len(pts), dtype=bool)
    if support_z is not None and normals is not None:
        keep &= ~((pts[:, 2] < support_z + SUPPORT_BAND) & (np.asarray(normals)[:, 2] > 0.8))
    for b in child_boxes:
        keep &= ~_inside_box(pts, b, CHILD_MARGIN, below=0.5 * CHILD_MARGIN)
    if keep.sum() < max(MIN_POINTS, MIN_KEPT_FRACTION * len(pts)):
        return np.ones(len(pts), dtype=bool)
    return keep


#: A model surface point faces up (``ObjectObservation.hidden_by_loads``) when its normal is within
#: about 25 degrees of vertical.
UP_FACE_COS = 0.9


def _ray_meets_box(origins: NDArray[np.float64], direction: NDArray[np.float64], box: GravityBox) -> NDArray[np.bool_]:
    """Per origin: does the ray ``origin + t direction`` (t >= 0, 3-D) meet the gravity-aligned ``box`` (an
    origin inside the box meets it)?"""
    o = np.asarray(origins, dtype=np.float64)
    local = np.c_[box.to_local_xy(o[:, :2]), o[:, 2] - float(box.center[2])]
    d = np.r_[_local_direction(box, direction[:2]), direction[2]]
    return np.isfinite(_slab_entry(local, d, 0.5 * np.asarray(box.size, dtype=np.float64)))


#: A child whose observed bottom is within this (m) of its parent's observed top rests on that top.
TOP_CONTACT_M = 0.03
#: Share of a carried child's footprint (per axis, about its centre) laid on its parent's top: the
#: middle of what stands on a surface is over it; its rim may overhang the edge.
FOOTPRINT_SHARE = 0.6
#: Carried-footprint points at most this share of the observed points (the observation leads).
MAX_FOOTPRINT_SHARE = 0.5


def carried_footprint_points(
    top_z: float,
    child_boxes: Sequence[GravityBox],
    spacing: float,
    max_points: int,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Surface of a support's top hidden under what it carries: points and upward normals.

    What stands on a table hides the table top under it from every camera, and a table seen only in
    part (its far end behind a wall, under a microwave) was fitted with a short desk that ended where
    the observation did; the physical check then dragged the correctly fitted microwave 19 cm back
    onto that desk. The contact graph says the child rests on this parent (paper Eq. 1), so the top
    must extend under it: the middle ``FOOTPRINT_SHARE`` of each footprint of a child whose bottom
    is within ``TOP_CONTACT_M`` of ``top_z`` becomes a grid of points at ``top_z``, ``spacing`` apart
    (the observation's own sample spacing, so they weigh like observed surface), at most
    ``max_points`` of them in all (evenly thinned). Children inside the object (a book on a shelf
    board, a cup in a drawer) are not on its top and add nothing.
    """
    if not np.isfinite(top_z) or spacing <= 0.0 or max_points <= 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    grids = []
    for b in child_boxes:
        if abs(b.z_min - top_z) > TOP_CONTACT_M:
            continue
        half = 0.5 * FOOTPRINT_SHARE * np.asarray(b.size[:2], dtype=np.float64)
        nx, ny = (max(1, int(np.ceil(2.0 * h / spacing)) + 1) for h in half)
        u, v = np.meshgrid(np.linspace(-half[0], half[0], nx), np.linspace(-half[1], half[1], ny), indexing="ij")
        c, s = np.cos(b.yaw), np.sin(b.yaw)
        local = np.stack([u.ravel(), v.ravel()], axis=1)
        xy = b.center[:2] + local @ np.array([[c, s], [-s, c]])
        grids.append(np.column_stack([xy, np.full(len(xy), top_z)]))
    if not grids:
        return np.zeros((0, 3)), np.zeros((0, 3))
    pts = np.concatenate(grids)
    if len(pts) > max_points:
        pts = pts[np.linspace(0, len(pts) - 1, max_points).round().astype(int)]
    normals = np.zeros_like(pts)
    normals[:, 2] = 1.0
    return pts, normals


def _side_directions(box: GravityBox) -> NDArray[np.float64]:
    """(4, 2) outward unit directions of the box sides: +x, +y, -x, -y of the box frame."""
    c, s = np.cos(box.yaw), np.sin(box.yaw)
    ex, ey = np.array([c, s]), np.array([-s, c])
    return np.stack([ex, ey, -ex, -ey])


def _local_direction(box: GravityBox, direction: NDArray[np.float64]) -> NDArray[np.float64]:
    """An xy direction in the box's footprint frame (``GravityBox.to_local_xy`` without the centre)."""
    c, s = np.cos(box.yaw), np.sin(box.yaw)
    return np.array([c * direction[0] + s * direction[1], -s * direction[0] + c * direction[1]])


def _slab_entry(local: NDArray[np.float64], d: NDArray[np.float64], half: NDArray[np.float64]) -> NDArray[np.float64]:
    """Slab test in a box's own frame (2-D or 3-D): distance along ``d`` from each origin ``local`` to the box
    ``|x| <= half`` (0 for an origin inside, inf if missed)."""
    safe = np.where(np.abs(d) < EPS, EPS, d)
    t1 = (-half - local) / safe
    t2 = (half - local) / safe
    tmin = np.minimum(t1, t2)
    tmax = np.maximum(t1, t2)
    # Axis-parallel rays: inside the slab -> unbounded, outside -> never enters.
    parallel = np.abs(d) < EPS
    inside = np.abs(local) <= half
    tmin = np.where(parallel, np.where(inside, -np.inf, np.inf), tmin)
    tmax = np.where(parallel, np.where(inside, np.inf, -np.inf), tmax)
    enter = tmin.max(axis=1)
    leave = tmax.min(axis=1)
    hit = (leave >= np.maximum(enter, 0.0)) & np.isfinite(enter)
    return np.where(hit, np.maximum(enter, 0.0), np.inf)


def _ray_box_entry(
    origins: NDArray[np.float64], direction: NDArray[np.float64], box: GravityBox
) -> NDArray[np.float64]:
    """Distance along ``direction`` (xy) from each origin to the footprint of ``box`` (inf if missed)."""
    return _slab_entry(box.to_local_xy(origins), _local_direction(box, direction), 0.5 * box.size[:2])


def side_clearances(
    box: GravityBox,
    obstacle_boxes: Sequence[GravityBox] = (),
    wall_planes: Sequence[Plane] = (),
    *,
    max_range: float = 3.0,
    min_height_fraction: float = 0.5,
) -> NDArray[np.float64]:
    """Free distance (m) in front of each of the 4 box sides (+x, +y, -x, -y), capped at ``max_range``.

    Three rays per side (the side's centre and quarter points) start on the side face; the side's
    clearance is the median of their first hits with vertical wall planes and obstacle boxes.
    Only obstacles that overlap the object's height band and reach at least
    ``min_height_fraction`` of its height count: a low table in front of a chair does not make the
    chair's front inaccessible, a wall or a tall cabinet does.
    """
    dirs = _side_directions(box)
    half = 0.5 * box.size[:2]
    out = np.full(4, max_range)
    z_lo, z_hi = box.z_min, box.z_max
    blockers = [
        o
        for o in obstacle_boxes
        if min(o.z_max, z_hi) - max(o.z_min, z_lo) >= min_height_fraction * max(box.size[2], EPS)
    ]
    for k in range(4):
        d = dirs[k]
        lateral = dirs[(k + 1) % 4]
        depth = half[k % 2]
        width = half[(k + 1) % 2]
        origins = box.center[:2] + d * depth + np.outer([-0.5, 0.0, 0.5], lateral * width)
        dist = np.full(3, max_range)
        for w in wall_planes:
            n2 = np.asarray(w.normal[:2], dtype=np.float64)
            if np.linalg.norm(n2) < 0.5:  # not a vertical wall
                continue
            denom = float(n2 @ d)
            if abs(denom) < 1e-6:
                continue
            t = -(origins @ n2 + w.normal[2] * box.center[2] + w.d) / denom
            dist = np.minimum(dist, np.where(t >= -0.05, np.maximum(t, 0.0), max_range))
        for o in blockers:
            dist = np.minimum(dist, _ray_box_entry(origins, d, o))
        out[k] = float(np.median(np.minimum(dist, max_range)))
    return out


def front_direction_from_context(
    box: GravityBox,
    obstacle_boxes: Sequence[GravityBox] = (),
    wall_planes: Sequence[Plane] = (),
    camera_positions: ArrayLike | None = None,
    *,
    max_range: float = 3.0,
    min_margin: float = 0.3,
    camera_weight: float = 1.0,
) -> NDArray[np.float64] | None:
    """Unit xy direction of the box side most likely to be the object's front, or ``None``.

    A functional front must be reachable: a side whose opposite side is against a wall or a tall
    obstacle is the likely front. Each side scores ``clearance(side) - clearance(opposite)``
    (both from ``side_clearances``); with camera positions the cosine between the side's
    direction and the mean direction from the box to the cameras, times ``camera_weight`` (m),
    is added (the objects were looked at from where people stand). ``None`` when the best score
    is under ``min_margin``: nothing distinguishes the sides (a table in the middle of a room).
    """
    dirs = _side_directions(box)
    clear = side_clearances(box, obstacle_boxes, wall_planes, max_range=max_range)
    score = clear - np.roll(clear, 2)
    if camera_positions is not None:
        cams = np.asarray(camera_positions, dtype=np.float64).reshape(-1, 3)
        cams = cams[np.all(np.isfinite(cams), axis=1)]
        if len(cams):
            to_cam = cams[:, :2] - box.center[:2]
            length = np.linalg.norm(to_cam, axis=1, keepdims=True)
            mean_dir = (to_cam / np.maximum(length, EPS)).mean(axis=0)
            n = float(np.linalg.norm(mean_dir))
            if n > 1e-6:
                score = score + camera_weight * (dirs @ (mean_dir / n))
    best = int(np.argmax(score))
    if score[best] < min_margin:
        return None
    return dirs[best].copy()


#: ``handle_side``: surface more than ``HANDLE_PROUD`` (m) and less than ``HANDLE_SLAB`` before a box side's
#: plane (the outermost depth holding much of the surface facing out there), over that face, is proud of it: handles,
#: an open door's edge, a pulled-out drawer. The side holding at least ``HANDLE_MIN_AREA`` (m^2) of it and
#: ``HANDLE_DOMINANCE`` times any other side's is the front.
HANDLE_SLAB = 0.08
HANDLE_PROUD = 0.008
HANDLE_MIN_AREA = 0.002
HANDLE_DOMINANCE = 3.0
#: Surface samples drawn on the observed mesh for ``handle_side``.
HANDLE_SIDE_SAMPLES = 20000
#: ... a side's plane is the outermost 5 mm layer of surface facing out holding this share of the largest.
HANDLE_LAYER = 0.3


#: ``handle_side``: surface within this distance (m) of another entity's box counts as inside it (the two
#: meshes of a joined surface lie up to a voxel apart).
NEIGHBOUR_MARGIN = 0.01


def handle_side(mesh: trimesh.Trimesh | None, box: GravityBox,
                others: Sequence[GravityBox] = ()) -> NDArray[np.float64] | None:
    """Unit xy direction of the box side whose surface has something proud of it (the handles of doors and
    drawers, a door or drawer open), or ``None`` when no side clearly does (see ``HANDLE_DOMINANCE``).
    Surface inside one of ``others`` (the other entities' boxes) is not proud of anything: it is the
    neighbour's, joined to this mesh by the mapper (a monitor behind a microwave made its back a front).

    An articulated object's front shows itself where it was observed: the context's free space alone
    (``front_direction_from_context``) points out of either free side of a corner (issue 23: an oven in a
    corner matched sideways, its handle on the side the hint did not name)."""
    if mesh is None or len(mesh.faces) == 0 or mesh.area <= 0.0:
        return None
    samples, faces = trimesh.sample.sample_surface(mesh, HANDLE_SIDE_SAMPLES, seed=0)
    pts = np.asarray(samples, dtype=np.float64)
    nrm = np.asarray(mesh.face_normals[faces], dtype=np.float64)
    per_sample = float(mesh.area) / HANDLE_SIDE_SAMPLES
    theirs = np.zeros(len(pts), dtype=bool)
    for other in others:
        theirs |= _inside_box(pts, other, NEIGHBOUR_MARGIN)
    dirs = _side_directions(box)
    area = np.zeros(4)
    for k, d in enumerate(dirs):
        s = pts[:, :2] @ d
        facing = nrm[:, :2] @ d > 0.9
        if np.count_nonzero(facing) < 10:
            continue
        # The side's plane: the outermost depth holding a good part of the surface facing out there (5 mm
        # bins; a door's inside faces the back too, and the shelves behind it would be proud of it). Its extent
        # (across and up) bounds what counts as proud of it: a door open 80 degrees lies beyond the
        # carcass's side, not over it.
        hist, edges = np.histogram(s[facing], bins=max(1, int(np.ptp(s[facing]) / 0.005) + 1))
        top = int(np.flatnonzero(hist >= HANDLE_LAYER * hist.max())[-1])
        plane = 0.5 * float(edges[top] + edges[top + 1])
        face = facing & (np.abs(s - plane) <= 0.005)
        across = pts[:, :2] @ dirs[(k + 1) % 4]
        over = (across >= across[face].min()) & (across <= across[face].max()) \
            & (pts[:, 2] >= pts[face, 2].min()) & (pts[:, 2] <= pts[face, 2].max())
        proud = over & ~theirs & (s > plane + HANDLE_PROUD) & (s < plane + HANDLE_SLAB)
        area[k] = float(np.count_nonzero(proud)) * per_sample
    best = int(np.argmax(area))
    rest = np.delete(area, best)
    if area[best] < HANDLE_MIN_AREA or area[best] < HANDLE_DOMINANCE * float(rest.max()):
        return None
    return dirs[best].copy()


__all__ = [
    "HANDLE_MIN_AREA",
    "HANDLE_SLAB",
    "MIN_POINTS",
    "ObjectObservation",
    "ObservationError",
    "carried_footprint_points",
    "clean_entity_points",
    "front_direction_from_context",
    "handle_side",
    "side_clearances",
]
