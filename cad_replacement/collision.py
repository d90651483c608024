"""Collision geometry and inertials of CAD links: primitives, exact box CSG, convex pieces.

Physics engines collide every mesh as its convex hull, so a hollow part (a cabinet carcass, a
shelf, a fridge, a cup) given as one visual mesh becomes a solid block and throws out whatever
stands inside it. This module turns a link into shapes that are each exactly what they claim:

* ``box_csg``: a union of axis-aligned boxes minus axis-aligned cut boxes, decomposed *exactly*
  into disjoint boxes (the grid of all breakpoints, cells inside an additive box and outside every
  cut, greedily merged into few boxes). The procedural builders make carcasses, shelves and
  drawers from overlapping panels, so their links decompose without any approximation.
* ``cylinder_shape`` / ``ring_pieces``: a cylinder stays a cylinder primitive; a cylinder minus a
  coaxial cylinder (a cup) becomes solid end caps plus one convex prism per tessellation segment
  of the wall (the same 32-gon as the visual mesh).
* ``convex_pieces``: meshes without primitives (imported assets) are decomposed with CoACD
  (cached on disk by mesh hash as ``.npz``), or, where CoACD is missing, into the convex hull of
  each connected component.

Inertials are computed from the shapes (``inertial_from_shapes``): closed forms for primitives,
trimesh mass properties for convex pieces, summed with the parallel-axis theorem. Scaling a model
(``transform_shapes`` / ``transform_inertial``) keeps a box a box when the scale acts along its
axes and a cylinder a cylinder when its cross-section scales uniformly; otherwise the shape
becomes the convex mesh it is mapped to (an affine image of a convex set is convex), so the
collision geometry always equals the scaled solid.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import logging
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from recon_core.io import write_bytes_atomic
from recon_core.kinematic_tree import CollisionShape, Inertial

log = logging.getLogger(__name__)

#: Segments of tessellated cylinders (same as the procedural visual meshes: vertices on +-x/+-y).
CYLINDER_SEGMENTS = 32
#: Breakpoints closer than this (m) are one grid line of the box CSG.
CSG_TOL = 1e-9
#: CoACD concavity threshold (its default); smaller gives more, tighter pieces.
COACD_THRESHOLD = 0.05
#: Bump when the decomposition settings change: invalidates cached convex pieces.
CONVEX_CACHE_VERSION = "1"

_AXIS_ROTATIONS = {
    2: np.eye(3),
    0: np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]),  # +90 deg about y: z -> x
    1: np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]),  # -90 deg about x: z -> y
}


# ---------------------------------------------------------------------------- box CSG
def box_csg(adds: ArrayLike, cuts: ArrayLike | None = None, tol: float = CSG_TOL) -> NDArray[np.float64]:
    """Disjoint boxes whose union is exactly ``union(adds) - union(cuts)``; shape (K, 2, 3) (lo, hi).

    ``adds``/``cuts``: arrays (N, 2, 3) of axis-aligned boxes. Every breakpoint of every box spans
    the grid, so each grid cell is wholly inside or outside each box and the result is exact; the
    occupied cells are merged greedily (along z, then y, then x) into maximal boxes.
    """
    a = np.asarray(adds, dtype=np.float64).reshape(-1, 2, 3)
    c = np.zeros((0, 2, 3)) if cuts is None else np.asarray(cuts, dtype=np.float64).reshape(-1, 2, 3)
    if len(a) == 0:
        return np.zeros((0, 2, 3))
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(c))):
        raise ValueError("box_csg: non-finite box bounds")
    everything = np.concatenate([a, c])
    lines = []
    for axis in range(3):
        v = np.sort(everything[:, :, axis].ravel())
        keep = np.r_[True, np.diff(v) > tol]
        lines.append(v[keep])
    mids = [0.5 * (ln[1:] + ln[:-1]) for ln in lines]
    occupied = _grid_union(a, mids) & ~_grid_union(c, mids)
    boxes = []
    for (i0, i1), (j0, j1), (k0, k1) in _greedy_boxes(occupied):
        lo = np.array([lines[0][i0], lines[1][j0], lines[2][k0]])
        hi = np.array([lines[0][i1], lines[1][j1], lines[2][k1]])
        boxes.append(np.stack([lo, hi]))
    return np.asarray(boxes, dtype=np.float64).reshape(-1, 2, 3)


def _grid_union(boxes: NDArray[np.float64], mids: Sequence[NDArray[np.float64]]) -> NDArray[np.bool_]:
    """Cells (by centre) inside any of ``boxes``."""
    out = np.zeros(tuple(len(m) for m in mids), dtype=bool)
    for lo, hi in boxes:
        ix, iy, iz = ((mids[k] > lo[k]) & (mids[k] < hi[k]) for k in range(3))
        out |= ix[:, None, None] & iy[None, :, None] & iz[None, None, :]
    return out


IndexBox = tuple[tuple[int, int], tuple[int, int], tuple[int, int]]


def _greedy_boxes(occupied: NDArray[np.bool_]) -> list[IndexBox]:
    """Cover the occupied cells with disjoint index boxes ``[(i0, i1), (j0, j1), (k0, k1)]`` (exclusive ends)."""
    free = occupied.copy()
    nx, ny, nz = free.shape
    out: list[IndexBox] = []
    flat = free.reshape(-1)
    while True:
        first = int(np.argmax(flat))
        if not flat[first]:
            break
        i, j, k = np.unravel_index(first, free.shape)
        k1 = k + 1
        while k1 < nz and free[i, j, k1]:
            k1 += 1
        j1 = j + 1
        while j1 < ny and free[i, j1, k:k1].all():
            j1 += 1
        i1 = i + 1
        while i1 < nx and free[i1, j:j1, k:k1].all():
            i1 += 1
        free[i:i1, j:j1, k:k1] = False
        out.append(((int(i), int(i1)), (int(j), int(j1)), (int(k), int(k1))))
    return out


# ---------------------------------------------------------------------------- primitive shapes
def box_shape(lo: ArrayLike, hi: ArrayLike) -> CollisionShape:
    """Axis-aligned box ``lo..hi`` (link frame) as a collision box centred at its middle."""
    lo_a, hi_a = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    origin = np.eye(4)
    origin[:3, 3] = 0.5 * (lo_a + hi_a)
    return CollisionShape("box", origin=origin, size=hi_a - lo_a)


def cylinder_shape(center: ArrayLike, radius: float, length: float, axis: int = 2) -> CollisionShape:
    """Cylinder along coordinate ``axis`` (0, 1, 2) centred at ``center`` (URDF cylinders run along z)."""
    origin = np.eye(4)
    origin[:3, :3] = _AXIS_ROTATIONS[axis]
    origin[:3, 3] = np.asarray(center, dtype=np.float64)
    return CollisionShape("cylinder", origin=origin, radius=float(radius), length=float(length))


def mesh_shape(mesh: trimesh.Trimesh) -> CollisionShape:
    """A convex mesh piece given in the link frame, stored centred (origin at its bounds centre)."""
    centre = 0.5 * (mesh.bounds[0] + mesh.bounds[1])
    local = trimesh.Trimesh(np.asarray(mesh.vertices) - centre, np.asarray(mesh.faces), process=False)
    origin = np.eye(4)
    origin[:3, 3] = centre
    return CollisionShape("mesh", origin=origin, mesh=local)


def _polygon(radius: float, segments: int) -> NDArray[np.float64]:
    t = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    return np.stack([radius * np.cos(t), radius * np.sin(t)], axis=1)


def ring_pieces(center: ArrayLike, r_in: float, r_out: float, length: float, axis: int = 2,
                segments: int = CYLINDER_SEGMENTS) -> list[CollisionShape]:
    """A tube wall (``r_in..r_out``) as one convex prism per polygon segment (the visual 32-gon)."""
    if not 0.0 < r_in < r_out:
        raise ValueError(f"ring needs 0 < r_in < r_out, got {r_in}, {r_out}")
    outer, inner = _polygon(r_out, segments), _polygon(r_in, segments)
    rot = _AXIS_ROTATIONS[axis]
    c = np.asarray(center, dtype=np.float64)
    pieces = []
    for k in range(segments):
        n = (k + 1) % segments
        xy = np.stack([inner[k], outer[k], outer[n], inner[n]])
        pts = np.concatenate([np.c_[xy, np.full(4, -0.5 * length)], np.c_[xy, np.full(4, 0.5 * length)]])
        pieces.append(mesh_shape(trimesh.convex.convex_hull(pts @ rot.T + c)))
    return pieces


def shape_mesh(shape: CollisionShape, segments: int = CYLINDER_SEGMENTS) -> trimesh.Trimesh:
    """The shape as a closed mesh in the link frame (cylinders/spheres tessellated)."""
    if shape.kind == "box":
        m = trimesh.creation.box(extents=shape.size)
    elif shape.kind == "cylinder":
        m = trimesh.creation.cylinder(radius=shape.radius, height=shape.length, sections=segments)
    elif shape.kind == "sphere":
        m = trimesh.creation.icosphere(subdivisions=3, radius=shape.radius)
    else:
        assert shape.mesh is not None
        m = shape.mesh.copy()
    m.apply_transform(shape.origin)
    return m


# ---------------------------------------------------------------------------- mass properties
def shape_mass_properties(shape: CollisionShape) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """Volume, centroid (link frame) and inertia about the centroid per unit density (link axes).

    Closed forms for primitives; a convex mesh piece uses trimesh's exact polyhedral integrals.
    """
    rot, t = shape.origin[:3, :3], shape.origin[:3, 3]
    if shape.kind == "box":
        a, b, c = shape.size ** 2
        vol = float(np.prod(shape.size))
        local = vol / 12.0 * np.diag([b + c, a + c, a + b])
        centre = t
    elif shape.kind == "cylinder":
        r2, h2 = shape.radius ** 2, shape.length ** 2
        vol = float(np.pi * r2 * shape.length)
        side = vol * (3.0 * r2 + h2) / 12.0
        local = np.diag([side, side, 0.5 * vol * r2])
        centre = t
    elif shape.kind == "sphere":
        vol = float(4.0 / 3.0 * np.pi * shape.radius ** 3)
        local = np.eye(3) * 0.4 * vol * shape.radius ** 2
        centre = t
    else:
        assert shape.mesh is not None
        props = shape.mesh.mass_properties  # density 1: mass == volume
        vol = float(props.volume)
        if vol < 0.0:  # inward-facing winding: the same solid, integrals change sign
            vol, local, com = -vol, -np.asarray(props.inertia), np.asarray(props.center_mass)
        else:
            local, com = np.asarray(props.inertia), np.asarray(props.center_mass)
        centre = rot @ com + t
    return vol, np.asarray(centre, dtype=np.float64), rot @ local @ rot.T


def shapes_volume(shapes: Iterable[CollisionShape]) -> float:
    """Summed volume of the shapes (their true solid volume when they are disjoint)."""
    return float(sum(shape_mass_properties(s)[0] for s in shapes))


def inertial_from_shapes(shapes: Sequence[CollisionShape], density: float) -> Inertial:
    """Mass (volume x density), centre of mass and inertia about it of a link made of ``shapes``.

    The pieces are summed with the parallel-axis theorem; the box CSG makes box pieces disjoint,
    so the sum is the solid's own inertia (where a cylinder overlaps a box by a fuse depth the
    overlap counts twice: below 1 % of a link's mass for the procedural models).
    """
    if not (np.isfinite(density) and density > 0.0):
        raise ValueError(f"density must be positive and finite, got {density}")
    if not shapes:
        raise ValueError("a link without collision shapes has no volume to derive a mass from")
    props = [shape_mass_properties(s) for s in shapes]
    vols = np.array([p[0] for p in props])
    centres = np.array([p[1] for p in props])
    inertias = np.array([p[2] for p in props])
    total = float(vols.sum())
    if not total > 0.0:
        raise ValueError("collision shapes have no volume")
    com = (vols[:, None] * centres).sum(axis=0) / total
    d = centres - com
    parallel = vols[:, None, None] * (np.einsum("ni,ni->n", d, d)[:, None, None] * np.eye(3)
                                      - d[:, :, None] * d[:, None, :])
    inertia = (inertias + parallel).sum(axis=0) * density
    inertia = 0.5 * (inertia + inertia.T)
    return Inertial(mass=total * density, center_of_mass=com, inertia=inertia)


# ---------------------------------------------------------------------------- affine maps
def transform_inertial(inertial: Inertial, affine: ArrayLike) -> Inertial:
    """The inertial of the solid mapped by ``affine`` (4x4, any invertible linear part), density kept.

    With the second moment ``C = tr(I)/2 E - I`` about the centre of mass, an affine map gives
    ``C' = |det L| L C L^T``, ``m' = |det L| m``, ``c' = L c + t`` and ``I' = tr(C') E - C'``.
    """
    a = np.asarray(affine, dtype=np.float64)
    lin, t = a[:3, :3], a[:3, 3]
    det = abs(float(np.linalg.det(lin)))
    if not det > 0.0:
        raise ValueError("transform_inertial needs an invertible linear part")
    second = 0.5 * np.trace(inertial.inertia) * np.eye(3) - inertial.inertia
    second = det * lin @ second @ lin.T
    inertia = np.trace(second) * np.eye(3) - second
    return Inertial(mass=inertial.mass * det, center_of_mass=lin @ inertial.center_of_mass + t,
                    inertia=0.5 * (inertia + inertia.T))


def transform_shapes(shapes: Iterable[CollisionShape], affine: ArrayLike,
                     tol: float = 1e-9) -> tuple[CollisionShape, ...]:
    """Shapes mapped by ``affine`` (rigid or scaling): primitives stay primitives where they can.

    A box whose axes the linear part keeps orthogonal stays a box (sizes stretched); a cylinder
    stays a cylinder when its cross-section scales uniformly and its axis stays perpendicular;
    a sphere only under a similarity. Anything else becomes the convex mesh it maps to (cylinders
    tessellated with ``CYLINDER_SEGMENTS``), so the collision solid equals the mapped solid.
    """
    a = np.asarray(affine, dtype=np.float64)
    out = []
    for s in shapes:
        m = a[:3, :3] @ s.origin[:3, :3]  # shape axes after the map
        norms = np.linalg.norm(m, axis=0)
        gram = m.T @ m
        orthogonal = np.allclose(gram - np.diag(np.diag(gram)), 0.0, atol=tol * max(1.0, float(norms.max()) ** 2))
        new_origin = np.eye(4)
        new_origin[:3, 3] = a[:3, :3] @ s.origin[:3, 3] + a[:3, 3]
        rot = m / norms
        if np.linalg.det(rot) < 0.0:  # a mirror: boxes and cylinders are symmetric, flip one axis
            rot[:, 0] = -rot[:, 0]
        new_origin[:3, :3] = rot
        if s.kind == "box" and orthogonal:
            out.append(CollisionShape("box", origin=new_origin, size=s.size * norms))
        elif s.kind == "cylinder" and orthogonal and abs(norms[0] - norms[1]) <= tol * norms[0]:
            out.append(CollisionShape("cylinder", origin=new_origin, radius=s.radius * norms[0],
                                      length=s.length * norms[2]))
        elif s.kind == "sphere" and orthogonal and np.ptp(norms) <= tol * norms[0]:
            out.append(CollisionShape("sphere", origin=new_origin, radius=s.radius * norms[0]))
        else:
            # An affine image of a convex solid is convex with the same faces: map the vertices
            # (trimesh re-orients the faces of a mirroring map) instead of recomputing a hull,
            # which made scaling a CAD model cost ~30 ms per link.
            mesh = shape_mesh(s)
            mesh.apply_transform(a)
            out.append(mesh_shape(mesh))
    return tuple(out)


# ---------------------------------------------------------------------------- convex decomposition
def default_convex_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/scene_recon/convex_pieces`` (``~/.cache/...`` when unset)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "scene_recon" / "convex_pieces"


def mesh_digest(mesh: trimesh.Trimesh, method: str) -> str:
    """SHA-256 of the mesh arrays (float64 vertices, int64 faces) and the decomposition settings."""
    h = hashlib.sha256()
    h.update(json.dumps({"version": CONVEX_CACHE_VERSION, "method": method, "threshold": COACD_THRESHOLD}).encode())
    h.update(np.ascontiguousarray(mesh.vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
    return h.hexdigest()


def _coacd_module() -> Any:
    """CoACD, imported after open3d (REFERENCE.md sec. 4: the other order crashes); None when missing."""
    with contextlib.suppress(ImportError):
        import open3d  # noqa: F401
    try:
        import coacd
    except ImportError:
        return None
    coacd.set_log_level("error")  # its progress log goes to stdout otherwise
    return coacd


def _hull_pieces(mesh: trimesh.Trimesh, ground: float | None = None) -> list[trimesh.Trimesh]:
    """Convex hull of each connected component (fallback without CoACD); with ``ground``, of each
    component and its drop to that height (``observed_collisions``)."""
    parts = mesh.split(only_watertight=False) if len(mesh.faces) else []
    out = []
    for part in parts or [mesh]:
        try:
            hull = (part if ground is None else _grounded(part, ground)).convex_hull
        except Exception:  # flat/degenerate component: no solid hull, nothing to collide with
            continue
        if len(hull.faces) and hull.volume > 0.0:
            out.append(hull)
    return out


#: An observed mesh (a scanned object with no CAD model) at most this large (m) collides as one convex
#: hull; a larger one as boxes over the grid cells its surface occupies. Never CoACD: the scan is a partial,
#: open surface that changes with every map update, and CoACD took 18-48 s per small object on real
#: scans (88-129 vertices: 20-49 pieces), every time its mesh changed.
OBSERVED_HULL_MAX_EXTENT = 0.6
#: The same for a grounded (movable) observed mesh: one stacked on another (a TV split into two
#: detections) or bled into its neighbour must be able to lose the cells that overlap it.
OBSERVED_GROUNDED_HULL_MAX_EXTENT = 0.2
#: Thickness (m) given to a flat observed mesh's box (a scan of one face has no volume).
OBSERVED_MIN_THICKNESS = 0.01
#: A large observed mesh collides as boxes over the grid cells its surface occupies: cells of at least
#: this size (m), coarser until there are at most ``OBSERVED_MAX_CELLS`` of them.
OBSERVED_CELL = 0.1
OBSERVED_MAX_CELLS = 120


def _surface_points(mesh: trimesh.Trimesh, spacing: float) -> NDArray[np.float64]:
    """Vertices plus even samples (about one per ``spacing``^2 / 4) of an observed surface."""
    v = np.asarray(mesh.vertices, np.float64)
    count = int(min(20000, max(200, 4.0 * float(mesh.area) / (spacing * spacing))))
    samples, _ = trimesh.sample.sample_surface_even(mesh, count, seed=0) if len(mesh.faces) else (v[:0], None)
    return np.r_[v, np.asarray(samples, np.float64)]


def _cell_boxes(mesh: trimesh.Trimesh, grounded: bool, ground_z: float) -> tuple[CollisionShape, ...]:
    """A large observed surface as boxes over the grid cells it occupies (convex pieces that follow a
    concave scan: a table's top and legs, not their hull, which swallowed the chairs under it).

    Each occupied cell gives the box of its surface points (at least ``OBSERVED_MIN_THICKNESS`` thick);
    ``grounded``: one box per occupied column, from ``ground_z`` (at most the mesh's lowest point) to the
    column's top (a movable object kept as its scan rests on its whole footprint). Boxes overlap by at most the
    thickening, so their volumes and inertias add up."""
    lo = np.asarray(mesh.bounds[0], np.float64)
    cell = OBSERVED_CELL
    pts = _surface_points(mesh, cell)
    while True:
        keys = np.floor((pts - lo) / cell).astype(np.int64)
        if grounded:
            keys[:, 2] = 0
        uniq, inv = np.unique(keys, axis=0, return_inverse=True)
        if len(uniq) <= OBSERVED_MAX_CELLS:
            break
        cell *= 1.25
    inv = inv.reshape(-1)
    order = np.argsort(inv, kind="stable")
    bounds = np.r_[0, np.cumsum(np.bincount(inv, minlength=len(uniq)))]
    out = []
    for k in range(len(uniq)):
        p = pts[order[bounds[k]:bounds[k + 1]]]
        c_lo = lo + uniq[k] * cell
        b_lo = np.maximum(p.min(axis=0), c_lo)
        b_hi = np.minimum(p.max(axis=0), c_lo + cell)
        if grounded:  # the column: from the ground to its highest point
            b_lo[2], b_hi[2] = ground_z, p[:, 2].max()
        # thin (a face seen edge-on or flat): thickened about its middle, a column upwards only (its
        # bottom stays on the ground it rests on)
        pad = np.maximum(OBSERVED_MIN_THICKNESS - (b_hi - b_lo), 0.0) / 2.0
        up = pad.copy()
        if grounded:
            up[2], pad[2] = 2.0 * pad[2], 0.0
        out.append(box_shape(b_lo - pad, b_hi + up))
    return tuple(out)


def _grounded(mesh: trimesh.Trimesh, z: float) -> trimesh.Trimesh:
    """``mesh`` with a copy of its vertices dropped to height ``z`` (hull input: a prism to the ground)."""
    v = np.asarray(mesh.vertices, np.float64)
    low = v.copy()
    low[:, 2] = z
    return trimesh.Trimesh(np.r_[v, low], np.asarray(mesh.faces), process=False)


def observed_collisions(mesh: trimesh.Trimesh, grounded: bool = False,
                        ground_z: float | None = None) -> tuple[CollisionShape, ...]:
    """Collision shapes of an observed mesh: its convex hull (small), boxes over the grid cells its
    surface occupies (large: ``_cell_boxes``), or its bounding box thickened to
    ``OBSERVED_MIN_THICKNESS`` when it is flat.

    ``grounded``: every hull reaches down to the mesh's lowest point, or to ``ground_z`` when that is
    lower (the bottom of the object's box, which the scan did not reach: ``PlacedObject.resting_height``);
    the hull of its vertices and of their drops to that height. A scan seen from one side, a chair's front
    legs and seat, would otherwise stand on an edge and tip over; a grounded convex piece rests on a
    footprint that holds its own centre of mass, so an object kept as its observed mesh stays where it
    was seen."""
    if len(mesh.faces) == 0:
        return ()
    lo, hi = np.asarray(mesh.bounds[0], np.float64), np.asarray(mesh.bounds[1], np.float64)
    pieces: list[trimesh.Trimesh] = []
    # a movable scan is cut into cells from a smaller size on: the pieces of it inside another object
    # (``observed_physics``) can then go without the rest
    ground = float(lo[2]) if ground_z is None else min(float(lo[2]), float(ground_z))
    limit = min(OBSERVED_HULL_MAX_EXTENT, OBSERVED_GROUNDED_HULL_MAX_EXTENT) if grounded else OBSERVED_HULL_MAX_EXTENT
    if float(np.max(hi - lo)) <= limit:
        try:
            hull = (_grounded(mesh, ground) if grounded else mesh).convex_hull
            if len(hull.faces) and hull.volume > 1e-12:
                pieces = [hull]
        except Exception:  # coplanar points: no solid hull
            pieces = []
    else:
        return _cell_boxes(mesh, grounded, ground)
    if pieces:
        return tuple(mesh_shape(p) for p in pieces)
    pad = np.maximum(OBSERVED_MIN_THICKNESS - (hi - lo), 0.0) / 2.0
    return (box_shape(lo - pad, hi + pad),)


def convex_pieces(mesh: trimesh.Trimesh, cache_dir: str | Path | None = None,
                  use_coacd: bool = True) -> list[trimesh.Trimesh]:
    """Convex pieces covering ``mesh`` (CoACD when available, else hulls of its components).

    A mesh that already is convex (its volume equals its hull's) is one piece. CoACD results are
    cached by ``mesh_digest`` as ``<digest>.npz`` (vertex and face arrays, no pickle) under
    ``cache_dir`` (default ``default_convex_cache_dir()``); ``preprocess_mode="off"`` for closed
    meshes (CoACD's manifold preprocessing would only remesh them), ``"auto"`` otherwise.
    """
    if len(mesh.faces) == 0:
        return []
    if mesh.is_watertight and mesh.is_volume:
        try:
            hull = mesh.convex_hull
            if abs(hull.volume - mesh.volume) <= 1e-9 + 1e-6 * hull.volume:
                return [hull]
        except Exception:
            pass
    coacd = _coacd_module() if use_coacd else None
    if coacd is None:
        return _hull_pieces(mesh)
    folder = Path(cache_dir) if cache_dir is not None else default_convex_cache_dir()
    path = folder / f"{mesh_digest(mesh, 'coacd')}.npz"
    if path.is_file():
        try:
            with np.load(path, allow_pickle=False) as data:
                counts = data["vertex_counts"]
                verts = np.split(data["vertices"], np.cumsum(counts)[:-1])
                return [trimesh.convex.convex_hull(v) for v in verts]
        except (OSError, KeyError, ValueError) as exc:
            log.warning("ignoring unreadable convex cache %s: %s", path, exc)
    mode = "off" if mesh.is_watertight else "auto"
    result = coacd.run_coacd(coacd.Mesh(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)),
                             threshold=COACD_THRESHOLD, preprocess_mode=mode, seed=0)
    hulls = [trimesh.convex.convex_hull(np.asarray(v, np.float64)) for v, _f in result]
    hulls = [h for h in hulls if len(h.faces) and h.volume > 0.0]
    if not hulls:
        return _hull_pieces(mesh)
    buf = io.BytesIO()
    np.savez(buf, vertices=np.concatenate([h.vertices for h in hulls]),
             vertex_counts=np.array([len(h.vertices) for h in hulls], dtype=np.int64))
    try:
        write_bytes_atomic(path, buf.getvalue())
    except OSError as exc:  # a read-only cache only costs time
        log.warning("cannot write convex cache %s: %s", path, exc)
    return hulls


def mesh_collisions(mesh: trimesh.Trimesh, cache_dir: str | Path | None = None,
                    use_coacd: bool = True) -> tuple[CollisionShape, ...]:
    """Convex mesh pieces of a mesh without primitives (never the concave mesh as one hull)."""
    return tuple(mesh_shape(p) for p in convex_pieces(mesh, cache_dir, use_coacd))


__all__ = [
    "COACD_THRESHOLD",
    "CYLINDER_SEGMENTS",
    "box_csg",
    "box_shape",
    "convex_pieces",
    "cylinder_shape",
    "default_convex_cache_dir",
    "inertial_from_shapes",
    "mesh_collisions",
    "mesh_digest",
    "mesh_shape",
    "observed_collisions",
    "ring_pieces",
    "shape_mass_properties",
    "shape_mesh",
    "shapes_volume",
    "transform_inertial",
    "transform_shapes",
]
