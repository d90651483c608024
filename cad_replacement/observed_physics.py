"""Objects kept as their observed mesh, made fit for a simulator (issue 22, item 5).

An object no CAD model explains is exported as its scan (``replacer.observed_mesh_object``), which
collides as convex pieces (``collision.observed_collisions``). A real scan is not a clean solid:

* the detector's mask bleeds onto what lies behind or under the object (a chair's mask carries a
  strip of the wall and of the table top it stands at), so some pieces sit inside the wall slab or
  the table: a simulator throws the object out of them;
* what stands on the object hides the surface under it (a cup on a table scanned as its
  observation: no table top under the cup), so the child falls through.

``settle_observed(objects)`` runs on the placed scene: before the physical check, a movable observed
object drops the pieces that reach more than ``PIECE_DEPTH`` into another object (they are that
object's surface), never all of them, and a fixed one those reaching into a movable object resting
on it (a book standing on a cabinet scan whose mask took the book's lower half: the simulator threw
the book off); after it, again, and every observed object gets a thin support patch under each
object resting on it, at the height the child ended up.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np
import trimesh
from numpy.typing import NDArray

from cad_replacement.cad.model import CadModel, Link
from cad_replacement.collision import box_shape, shape_mesh
from cad_replacement.scene_model import PlacedObject
from recon_core.kinematic_tree import CollisionShape

#: A piece of a scan reaching deeper than this (m) into another object belongs to that object.
PIECE_DEPTH = 0.01
#: Spacing (m) of the probe points along a piece's edges (thinner slabs than twice this may be missed).
EDGE_STEP = 0.005
#: Thickness (m) of the support patch under an object resting on an observed mesh.
PATCH_THICKNESS = 0.02
#: A scan's box piece under a child may reach this far (m) above the child's bottom before it is clipped.
CLIP_TOLERANCE = 0.001
#: A piece clipped thinner than this (m) goes.
CLIP_MIN_THICKNESS = 0.002


def _world_pieces(obj: PlacedObject) -> list[trimesh.Trimesh]:
    """Every collision piece of ``obj`` as a closed convex mesh in the map."""
    out = []
    poses = obj.link_poses()
    for link in obj.model.links:
        shapes = link.collisions
        if shapes is None:  # collides as its visual mesh (layout slabs): its hull
            if len(link.mesh.faces):
                out.append(link.mesh.convex_hull.copy().apply_transform(poses[link.name]))
            continue
        for shape in shapes:
            m = shape_mesh(shape)
            m.apply_transform(poses[link.name])
            out.append(m)
    return out


#: Link-frame corners bounding each collision piece of recently seen models (``settle_observed`` runs
#: twice per scene, and at every replacement of a running node's graph): model id -> (the model, pieces).
_LOCAL_PIECES: OrderedDict[int, tuple[CadModel, list[tuple[Link, CollisionShape | None, NDArray[np.float64]]]]] = \
    OrderedDict()
_LOCAL_PIECES_SIZE = 256
#: Margin (m) added to piece bounds computed from link-frame corners: they must contain the exact
#: bounds (a pair whose bounds do not overlap has no probe inside the other piece), rounding included.
_BOUNDS_PAD = 1e-9


def _corners(shape: CollisionShape) -> NDArray[np.float64]:
    """Points whose hull contains ``shape_mesh(shape)``: the corners of the primitive's box (a cylinder's
    and a sphere's circumscribed one), or a mesh piece's vertices, in the link frame."""
    if shape.kind in ("box", "cylinder", "sphere"):
        if shape.kind == "box":
            half = 0.5 * np.asarray(shape.size, np.float64)
        elif shape.kind == "cylinder":
            half = np.array([shape.radius, shape.radius, 0.5 * shape.length], np.float64)
        else:
            half = np.full(3, shape.radius, np.float64)
        local = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64) * half
    else:
        assert shape.mesh is not None
        local = np.asarray(shape.mesh.vertices, np.float64)
    origin = np.asarray(shape.origin, np.float64)
    return local @ origin[:3, :3].T + origin[:3, 3]


def _local_pieces(model: CadModel) -> list[tuple[Link, CollisionShape | None, NDArray[np.float64]]]:
    """(link, its collision shape or None for the hull of its visual mesh, link-frame bounding points) of
    every piece ``_world_pieces`` builds, in its order."""
    hit = _LOCAL_PIECES.get(id(model))
    if hit is not None and hit[0] is model:
        _LOCAL_PIECES.move_to_end(id(model))
        return hit[1]
    out: list[tuple[Link, CollisionShape | None, NDArray[np.float64]]] = []
    for link in model.links:
        shapes = link.collisions
        if shapes is None:
            if len(link.mesh.faces):  # the hull's vertices are some of the mesh's
                out.append((link, None, np.asarray(link.mesh.vertices, np.float64)))
            continue
        out.extend((link, shape, _corners(shape)) for shape in shapes)
    _LOCAL_PIECES[id(model)] = (model, out)
    while len(_LOCAL_PIECES) > _LOCAL_PIECES_SIZE:
        _LOCAL_PIECES.popitem(last=False)
    return out


class _PlacedPieces:
    """The collision pieces of one placed object in the map: bounds that contain each piece at once
    (from link-frame corners), each closed mesh only when a test needs it (most pieces are far from
    every observed object; building every piece of every object took 1-2 s per call on a 20-object
    scene). Larger bounds only let more pairs reach the exact test, so what is dropped is unchanged."""

    def __init__(self, obj: PlacedObject) -> None:
        self._local = _local_pieces(obj.model)
        self._poses = obj.link_poses()
        self._built: dict[int, trimesh.Trimesh] = {}
        corners = []
        for link, _shape, points in self._local:
            if len(points) == 0:
                corners.append(_bounds(trimesh.Trimesh()))
                continue
            pose = np.asarray(self._poses[link.name], np.float64)
            v = points @ pose[:3, :3].T + pose[:3, 3]
            corners.append(np.array([v.min(axis=0) - _BOUNDS_PAD, v.max(axis=0) + _BOUNDS_PAD]))
        self.bounds = np.array(corners, np.float64).reshape(-1, 2, 3)

    def __len__(self) -> int:
        return len(self._local)

    def local_pieces(self) -> list[tuple[Link, CollisionShape | None, NDArray[np.float64]]]:
        """(link, shape, link-frame bounding points) of every piece (``_local_pieces``)."""
        return self._local

    def link_pose(self, link: str) -> NDArray[np.float64]:
        """The map pose of one of the object's links."""
        return np.asarray(self._poses[link], np.float64)

    def piece(self, k: int) -> trimesh.Trimesh:
        """The ``k``-th piece in the map, built as ``_world_pieces`` builds it."""
        hit = self._built.get(k)
        if hit is None:
            link, shape, _points = self._local[k]
            if shape is None:
                hit = link.mesh.convex_hull.copy().apply_transform(self._poses[link.name])
            else:
                hit = shape_mesh(shape)
                hit.apply_transform(self._poses[link.name])
            self._built[k] = hit
        return hit


def _inside(points: NDArray[np.float64], piece: trimesh.Trimesh) -> NDArray[np.bool_]:
    """Which points lie inside a closed convex mesh (behind every face plane)."""
    if len(piece.faces) == 0:
        return np.zeros(len(points), dtype=bool)
    n = np.asarray(piece.face_normals, np.float64)
    v0 = np.asarray(piece.triangles[:, 0], np.float64)
    d = np.einsum("pfj,fj->pf", points[:, None, :] - v0[None, :, :], n)
    return np.all(d < 0.0, axis=1)


def _probes(piece: trimesh.Trimesh, depth: float) -> NDArray[np.float64]:
    """The piece's vertices pulled ``depth`` towards its centre, and the centre: inside another solid
    only when the piece reaches deeper than about ``depth`` into it."""
    v = np.asarray(piece.vertices, np.float64)
    c = v.mean(axis=0)
    r = v - c
    length = np.linalg.norm(r, axis=1, keepdims=True)
    pulled = c + r * np.maximum(length - depth, 0.0) / np.maximum(length, 1e-12)
    # and points every ``EDGE_STEP`` along its edges: a thin slab (a table top) crossing a tall column
    # misses every corner
    edges = np.asarray(piece.edges_unique, np.int64)
    out = [pulled, c[None, :]]
    lengths = np.linalg.norm(pulled[edges[:, 1]] - pulled[edges[:, 0]], axis=1)
    for (i, j), n in zip(edges, np.ceil(lengths / EDGE_STEP).astype(np.int64), strict=True):
        if n > 1:
            t = np.linspace(0.0, 1.0, n + 1)[1:-1, None]
            out.append(pulled[i] * (1.0 - t) + pulled[j] * t)
    return np.concatenate(out)


def _bounds(piece: trimesh.Trimesh) -> NDArray[np.float64]:
    """Min/max corners of a piece; an empty one overlaps nothing."""
    if len(piece.vertices) == 0:
        return np.array([[np.inf] * 3, [-np.inf] * 3])
    return np.asarray(piece.bounds, np.float64)


def _overlaps(box: NDArray[np.float64], others: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Which of ``others`` ((n, 2, 3) min/max corners) overlap ``box`` ((2, 3)), touching included."""
    return np.all(box[0] <= others[:, 1], axis=1) & np.all(others[:, 0] <= box[1], axis=1)


def settle_observed(objects: Sequence[PlacedObject], *, drop: bool = True,
                    patch: bool = True) -> dict[str, dict[str, int]]:
    """Drop bled pieces of movable observed objects (``drop``) and add support patches (``patch``: after
    the physical check, which may still move what rests on them); returns what changed per object
    (``dropped`` pieces, ``patches``). Objects are edited in place (their ``model``)."""
    observed = [o for o in objects if o.model.source == "observed" and len(o.model.links) == 1]
    if not observed:
        return {}
    # every object's pieces and their bounds, only when some piece may be dropped (the bounds once per
    # piece: trimesh's cached ``bounds`` hashes the mesh at every read, 95k reads took 3 s on a 20-object scene)
    carried = {o.parent for o in objects if o.movable}
    dropping = drop and any(o.model.links[0].collisions and (o.movable or o.name in carried) for o in observed)
    world = {o.name: _PlacedPieces(o) for o in objects} if dropping else {}
    bounds = {name: pieces.bounds for name, pieces in world.items()}
    changes: dict[str, dict[str, int]] = {}
    for obj in observed:
        link = obj.model.links[0]
        shapes: list[CollisionShape] = list(link.collisions or ())
        kept = shapes
        dropped = 0
        if drop and shapes and (obj.movable or obj.name in carried):
            # a movable scan yields to everything but what rests on it; a fixed one (a cabinet, a table)
            # to the movable objects resting on it: the piece is their surface, which its mask took
            names = [o.name for o in objects if o.name != obj.name and o.parent != obj.name] if obj.movable \
                else [o.name for o in objects if o.parent == obj.name and o.movable]
            others = [(world[n], k) for n in names for k in range(len(world[n]))]
            other_bounds = np.concatenate([bounds[n] for n in names]) if names else np.zeros((0, 2, 3))
            own = world[obj.name]
            keep = []
            for k, (shape, box) in enumerate(zip(shapes, bounds[obj.name], strict=True)):
                probes = _probes(own.piece(k), PIECE_DEPTH)
                near = np.flatnonzero(_overlaps(box, other_bounds))
                hit = any(bool(np.any(_inside(probes, others[i][0].piece(others[i][1])))) for i in near)
                if not hit:
                    keep.append(shape)
            if keep and len(keep) < len(shapes):
                dropped = len(shapes) - len(keep)
                kept = keep
        children = [o for o in objects if o.parent == obj.name and o.movable]
        kept, clipped, gone = _clipped_under(obj, kept, children) if drop and children else (kept, 0, 0)
        dropped += gone
        if drop and obj.movable and kept:
            above = [world[o.name] for o in objects if o.name != obj.name and o.parent != obj.name]
            kept, clipped_below, gone = _cleared_below(obj, kept, above, world[obj.name].bounds)
            clipped += clipped_below
            dropped += gone
        patches = [_patch(obj, child) for child in objects if child.parent == obj.name] if patch else []
        patches_ok = [p for p in patches if p is not None]
        if not dropped and not clipped and not patches_ok:
            continue
        new_link = Link(link.name, link.mesh, link.color, collisions=tuple(kept) + tuple(patches_ok),
                        inertial=link.inertial)
        obj.model = replace(obj.model, links=(new_link,))
        changes[obj.name] = {"dropped": dropped, "clipped": clipped, "patches": len(patches_ok)}
    return changes


def _cleared_below(obj: PlacedObject, shapes: list[CollisionShape], others: Sequence[_PlacedPieces],
                   own_bounds: NDArray[np.float64] | None = None) -> tuple[list[CollisionShape], int, int]:
    """``obj``'s box pieces whose top reaches less than ``PIECE_DEPTH`` into the underside of another
    object's piece (deeper ones the probe test dropped) end ``CLIP_TOLERANCE`` below it (those left
    thinner than ``CLIP_MIN_THICKNESS`` go); returns the pieces, how many were clipped and how many went.

    Two observed surfaces do not overlap; a few millimetres of overlap is mapping noise, and a movable
    scan yields. The 7-Scenes kitchen (stride 4): a chair pushed under a table, its seat's cell boxes 9 mm
    into the table's apron once the table scan stood at its observed height; PyBullet pushed the chair
    2.4 cm out.

    ``own_bounds``: the map bounds of ``obj``'s pieces (``_PlacedPieces.bounds``); only the other pieces
    whose map bounds overlap them are brought into ``obj``'s frame (default: every piece)."""
    inv = np.linalg.inv(np.asarray(obj.link_poses()[obj.model.links[0].name], np.float64))
    reach = None if own_bounds is None or not len(own_bounds) else \
        np.array([own_bounds[:, 0].min(axis=0), own_bounds[:, 1].max(axis=0)])
    boxes = []
    for other in others:
        pieces = other.local_pieces()
        near = range(len(pieces)) if reach is None else np.flatnonzero(_overlaps(reach, other.bounds))
        for k in near:
            link, _shape, points = pieces[k]
            if len(points) == 0:
                continue
            pose = np.asarray(other.link_pose(link.name), np.float64)
            local = (points @ pose[:3, :3].T + pose[:3, 3]) @ inv[:3, :3].T + inv[:3, 3]
            boxes.append((local.min(axis=0), local.max(axis=0)))
    if not boxes:
        return shapes, 0, 0
    b_lo = np.array([b[0] for b in boxes])
    b_hi = np.array([b[1] for b in boxes])

    def below_what_is_above(lo: NDArray[np.float64], hi: NDArray[np.float64]) -> float:
        over = np.all((b_lo[:, :2] < hi[:2] - CLIP_TOLERANCE) & (lo[:2] + CLIP_TOLERANCE < b_hi[:, :2]), axis=1)
        into = over & (b_lo[:, 2] < hi[2]) & (b_lo[:, 2] > hi[2] - PIECE_DEPTH) & (b_hi[:, 2] > hi[2])
        return float(b_lo[into, 2].min()) - CLIP_TOLERANCE if np.any(into) else float(hi[2])

    return _lowered_tops(shapes, below_what_is_above)


def _lowered_tops(shapes: list[CollisionShape],
                  top_of: Callable[[NDArray[np.float64], NDArray[np.float64]], float],
                  ) -> tuple[list[CollisionShape], int, int]:
    """Each axis-aligned box piece (link frame ``lo``..``hi``) ends at ``top_of(lo, hi)`` where that is lower
    than its top; one left thinner than ``CLIP_MIN_THICKNESS`` goes; other pieces stay. Returns the pieces, how
    many were clipped and how many went; never none of them (then ``shapes`` unchanged)."""
    out: list[CollisionShape] = []
    clipped = gone = 0
    for shape in shapes:
        origin = np.asarray(shape.origin, np.float64)
        if shape.kind != "box" or not np.allclose(origin[:3, :3], np.eye(3)):
            out.append(shape)
            continue
        half = 0.5 * np.asarray(shape.size, np.float64)
        lo, hi = origin[:3, 3] - half, origin[:3, 3] + half
        top = min(float(hi[2]), top_of(lo, hi))
        if top >= hi[2]:
            out.append(shape)
        elif top - lo[2] >= CLIP_MIN_THICKNESS:
            out.append(box_shape(lo, [hi[0], hi[1], top]))
            clipped += 1
        else:
            gone += 1
    if not out:
        return shapes, 0, 0
    return out, clipped, gone


def _footprint_box(parent: PlacedObject, child: PlacedObject) -> NDArray[np.float64] | None:
    """Min/max corners (2, 3) of ``child`` in ``parent``'s link frame (None: no geometry)."""
    meshes = [m for m in child.model.posed_link_meshes(child.joint_values).values() if len(m.vertices)]
    if not meshes:
        return None
    v = np.concatenate([np.asarray(m.vertices, np.float64) for m in meshes]) @ child.pose[:3, :3].T + child.pose[:3, 3]
    inv = np.linalg.inv(parent.pose)
    local = v @ inv[:3, :3].T + inv[:3, 3]
    return np.array([local.min(axis=0), local.max(axis=0)])


def _clipped_under(parent: PlacedObject, shapes: list[CollisionShape], children: Sequence[PlacedObject],
                   ) -> tuple[list[CollisionShape], int, int]:
    """``parent``'s box pieces that reach above the bottom of a movable object resting on it, under its
    footprint, and end inside it, end at that bottom instead (those left thinner than ``CLIP_MIN_THICKNESS``
    go); returns the pieces, how many were clipped and how many went.

    The child was seen where it stands, so what of the scan rises into it is its surface, which the scan's
    mask took; the probe test above drops such a piece only when it lies mostly inside the child. A cell box
    at the child's edge, mostly beside it but reaching 2 cm up into its corner (bench-small, draw 1: a book
    on a cabinet scan), threw the child off once the child stood on the scan's own top rather than on the
    bled pieces."""
    feet = [f for f in (_footprint_box(parent, c) for c in children) if f is not None]
    if not feet:
        return shapes, 0, 0

    def at_the_bottom_of_what_rests(lo: NDArray[np.float64], hi: NDArray[np.float64]) -> float:
        top = float(hi[2])
        for f_lo, f_hi in feet:
            over = bool(np.all(lo[:2] < f_hi[:2]) and np.all(f_lo[:2] < hi[:2]))
            # under the child and ending inside it: a piece rising past the child's top (a side panel
            # beside a book on an inner shelf) is the scan's own
            if over and top > f_lo[2] + CLIP_TOLERANCE and hi[2] <= f_hi[2] + CLIP_TOLERANCE:
                top = min(top, float(f_lo[2]))
        return top

    return _lowered_tops(shapes, at_the_bottom_of_what_rests)


def _patch(parent: PlacedObject, child: PlacedObject) -> CollisionShape | None:
    """A thin box in ``parent``'s link frame under ``child``'s footprint, its top where the child's
    lowest point is."""
    foot = _footprint_box(parent, child)
    if foot is None:
        return None
    lo, hi = foot
    bottom = float(lo[2])
    return box_shape([lo[0], lo[1], bottom - PATCH_THICKNESS], [hi[0], hi[1], bottom])


__all__ = ["PATCH_THICKNESS", "PIECE_DEPTH", "settle_observed"]
