"""Floor, walls and ceiling from the map's geometry when the segmenter has no layout classes.

A COCO detector labels chairs and tables but never the floor or a wall, so a map made with one
holds all layout surface in its "unknown" entity (entity 0: reconstructed surface no entity
claims, ``panoptic_mapping.mapper``); yet support inference needs a floor and walls. NOT in the
paper (its segmenter has layout classes). Two steps, both in the gravity-aligned map frame (z up;
``scene-recon map --gravity`` makes it so):

* ``give_up_layout_planes``: a detected thing never claims layout. A thing whose mesh holds a
  horizontal or vertical planar part (``layout_planes``) much larger than its class can be
  (``max_size_m`` of ``config/classes.yaml`` times ``size_factor``) and a real share of its area
  has swallowed floor or wall (a mask bleeding onto the wall behind a chair): that part leaves the
  thing and joins the unlabelled surface. A thing that is itself larger than its class can be gives
  up its large vertical planar parts too, all but its largest part, however short each is (a table
  box over the cabinet fronts of an L-shaped kitchen counter behind it: two fronts of 2.1 and 1.7 m,
  each shorter than a table, made a 4.1 m "table" on real frames).
* ``layout_from_geometry``: in the unlabelled surface, horizontal faces are grouped by height
  (area-weighted modes): the **floor** is the lowest large group (its faces within ``thickness``
  above and below: both faces of a slab), the **ceiling** the highest large group at least
  ``ceiling_min_height`` above the floor and ``ceiling_min_floor_share`` of the floor's area. The
  rest is split into vertical planar parts (``layout.wall_parts``); a part is a **wall** when it is
  large (``wall_min_area``, ``wall_min_height`` tall; or a strip seen above the furniture in front of
  it: ``wall_strip_min_area``, ``wall_strip_min_height`` tall, its top ``wall_strip_min_top`` above
  the floor, as a kitchen's tiles above the counter) and bounds the room: at most
  ``wall_outside_share`` of all the map's surface lies more than ``wall_outside_margin`` beyond
  it (a cabinet front has the wall behind it; a wall has nothing).

The builder (``ContactGraphBuilder``) runs the first step on every thing and the second only when
no entity of a floor or wall class is present, so maps with layout labels (the oracle, a panoptic
network) build exactly as before.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from recon_core.entity import Entity
from scene_graph.config import GeometricLayoutConfig, LayoutConfig
from scene_graph.layout import HORIZONTAL_NZ, _faces, sub_entity, wall_parts

log = logging.getLogger(__name__)

#: Up in the gravity-aligned map frame.
Z_UP = np.array([0.0, 0.0, 1.0])
#: Bin of the height histogram (m).
HEIGHT_BIN = 0.02


@dataclass
class PlanarPart:
    """A horizontal or vertical planar part of a mesh: its faces, kind, largest in-plane extent, area."""

    mask: NDArray
    kind: str  # "horizontal" | "vertical"
    extent: float
    area: float
    height: float = 0.0


def concat_entities(base: Entity, others: list[Entity]) -> Entity:
    """``base`` with the others' geometry appended (base's id, name and class)."""
    verts, faces, offset = [base.vertices], [base.faces], len(base.vertices)
    for e in others:
        verts.append(e.vertices)
        faces.append(e.faces + offset)
        offset += len(e.vertices)
    return replace(base, vertices=np.concatenate(verts), faces=np.concatenate(faces))


def height_groups(z: NDArray, area: NDArray, min_area: float, thickness: float,
                  max_groups: int = 16) -> list[tuple[float, float]]:
    """(height, area) of the area-weighted modes of face heights holding at least ``min_area``
    (faces within ``thickness`` of a mode are its group), in the order found (heaviest first)."""
    out: list[tuple[float, float]] = []
    if len(z) == 0:
        return out
    remaining = np.ones(len(z), bool)
    lo = float(z.min())
    for _ in range(max_groups):
        if area[remaining].sum() < min_area:
            break
        bins = np.floor((z[remaining] - lo) / HEIGHT_BIN).astype(np.int64)
        mass = np.convolve(np.bincount(bins, weights=area[remaining]), np.ones(3), mode="same")
        centre = lo + (int(np.argmax(mass)) + 0.5) * HEIGHT_BIN
        near = remaining & (np.abs(z - centre) <= 1.5 * HEIGHT_BIN)
        h = float(np.average(z[near], weights=np.maximum(area[near], 1e-12))) if near.any() else centre
        member = remaining & (np.abs(z - h) <= thickness)
        a = float(area[member].sum())
        remaining &= ~member
        if a >= min_area:
            out.append((h, a))
    return out


def _extent(points: NDArray) -> float:
    """Largest extent of 2D points along their principal axes."""
    if len(points) < 2:
        return 0.0
    c = points - points.mean(axis=0)
    _u, _s, vt = np.linalg.svd(c, full_matrices=False)
    return float(np.ptp(c @ vt.T, axis=0).max())


def layout_planes(entity: Entity, cfg: GeometricLayoutConfig) -> list[PlanarPart]:
    """Large horizontal (height groups) and vertical (``wall_parts``) planar parts of a mesh."""
    if not entity.has_faces:
        return []
    centroid, normal, area = _faces(entity)
    parts: list[PlanarPart] = []
    flat = (np.abs(normal[:, 2]) >= HORIZONTAL_NZ) & (area > 0)
    for h, a in height_groups(centroid[flat, 2], area[flat], cfg.give_up_min_area, cfg.plane_thickness):
        mask = flat & (np.abs(centroid[:, 2] - h) <= cfg.plane_thickness)
        verts = entity.vertices[np.unique(entity.faces[mask])]
        parts.append(PlanarPart(mask, "horizontal", _extent(verts[:, :2]), a, h))
    wcfg = LayoutConfig(min_area=cfg.give_up_min_area, min_length=0.1, thickness=cfg.plane_thickness,
                        max_gap=cfg.plane_max_gap)
    masks, _dropped = wall_parts(entity, wcfg)
    for m in masks:
        verts = entity.vertices[np.unique(entity.faces[m])]
        length = _extent(verts[:, :2])
        parts.append(PlanarPart(m, "vertical", max(length, float(np.ptp(verts[:, 2]))), float(area[m].sum())))
    return parts


def give_up_layout_planes(entity: Entity, max_size_m: float,
                          cfg: GeometricLayoutConfig) -> tuple[Entity, Entity | None]:
    """Split off the planar parts of a thing larger than its class can be (see the module doc).

    Returns (the thing without them, the given-up faces as an entity of class "unknown" or None).
    A thing that would keep nothing keeps everything (it is all plane: let the graph judge it).
    """
    if not entity.has_faces or max_size_m <= 0:
        return entity, None
    _c, _n, area = _faces(entity)
    total = float(area.sum())
    give = np.zeros(len(entity.faces), bool)
    parts = layout_planes(entity, cfg)
    limit = cfg.size_factor * max_size_m
    # a thing larger than its class can be that holds several large planar parts: its vertical ones
    # other than its largest part are surface its mask bled onto (a table's box over the cabinet
    # fronts behind it: each front shorter than a table, together with the table 4 m long)
    oversized = _extent(entity.vertices[:, :2]) > limit
    largest = max((p.area for p in parts), default=0.0)
    for p in parts:
        if p.area < cfg.give_up_min_share * total:
            continue
        if p.extent > limit or (oversized and p.kind == "vertical" and p.area < largest):
            give |= p.mask
    if not give.any() or give.all():
        return entity, None
    log.info("entity %s (%s): %.2f m^2 of floor/wall surface given up to the layout", entity.id, entity.class_name,
             float(area[give].sum()))
    kept = sub_entity(entity, ~give)
    given = sub_entity(entity, give, class_name="unknown", name=f"layout_from_{entity.id}", is_thing=False,
                       category="unknown")
    return kept, given


@dataclass(frozen=True)
class LayoutPlane:
    """A derived floor / ceiling (horizontal, at ``offset`` = height) or wall part (``normal`` horizontal,
    ``offset`` = centroid . normal, spanning ``span`` along the horizontal in-plane direction)."""

    role: str
    normal: NDArray
    offset: float
    span: tuple[float, float] = (-np.inf, np.inf)


def layout_from_geometry(surface: Entity, context: list[Entity], cfg: GeometricLayoutConfig,
                         layout: LayoutConfig, planes: list[LayoutPlane] | None = None) -> dict[str, Entity]:
    """Floor / wall / ceiling entities (role -> entity with ``surface``'s faces; ids and names are the
    caller's) found in the unlabelled ``surface``; ``context``: every other mesh of the map (the
    boundary test of walls). ``planes``, when given, receives the plane of the floor, the ceiling and
    each wall part (for ``faces_on_layout``)."""
    if not surface.has_faces:
        return {}
    centroid, normal, area = _faces(surface)
    flat = (np.abs(normal[:, 2]) >= HORIZONTAL_NZ) & (area > 0)
    tri_z = surface.vertices[surface.faces][:, :, 2]
    groups = height_groups(centroid[flat, 2], area[flat], cfg.floor_min_area, cfg.plane_thickness)
    # The floor is seen from above: its candidates are up-facing surface only (a camera under a ceiling
    # with no floor in view mapped the ceiling as the lowest large horizontal surface, and every object
    # was then stood on it; a real TUM-layout desk recording, docs/REAL_DATA_TUM.md)
    up = flat & (normal[:, 2] > 0)
    up_groups = height_groups(centroid[up, 2], area[up], cfg.floor_min_area, cfg.plane_thickness)
    out: dict[str, Entity] = {}
    used = np.zeros(len(area), bool)
    z_floor: float | None = None
    largest = max((a for _h, a in groups), default=0.0)
    floors = sorted((h, a) for h, a in up_groups if a >= cfg.floor_min_share * largest)
    if floors:
        big = sorted((h, a) for h, a in groups if a >= cfg.floor_min_share * largest)
        z_floor, floor_area = floors[0]
        # every face within the band (both faces of a slab and its rim, the foot of a wall)
        fmask = np.all(np.abs(tri_z - z_floor) <= cfg.thickness, axis=1)
        out["floor"] = sub_entity(surface, fmask)
        if planes is not None:
            z_plane = _weighted_median(centroid[flat & fmask, 2], area[flat & fmask], z_floor)
            planes.append(LayoutPlane("floor", Z_UP, z_plane))
        used |= fmask
        high = [(h, a) for h, a in big if h >= z_floor + cfg.ceiling_min_height
                and a >= max(cfg.ceiling_min_area, cfg.ceiling_min_floor_share * floor_area)]
        if high:
            z_ceil = high[-1][0]
            cmask = ~used & np.all(np.abs(tri_z - z_ceil) <= cfg.thickness, axis=1)
            if cmask.any():
                out["ceiling"] = sub_entity(surface, cmask)
                if planes is not None:
                    planes.append(LayoutPlane("ceiling", Z_UP, _weighted_median(centroid[flat & cmask, 2],
                                                                                area[flat & cmask], z_ceil)))
                used |= cmask
    rest_idx = np.flatnonzero(~used)
    if len(rest_idx):
        rest = sub_entity(surface, ~used)
        strips = z_floor is not None and cfg.wall_strip_min_area < cfg.wall_min_area
        wcfg = replace(layout, min_area=cfg.wall_strip_min_area if strips else cfg.wall_min_area,
                       min_length=cfg.wall_min_length)
        masks, _dropped = wall_parts(rest, wcfg)
        ctx_c, ctx_a = _context_faces([surface, *context])
        keep = np.zeros(len(rest.faces), bool)
        rc, rn, ra = _faces(rest)
        for m in masks:
            vert = m & (np.abs(rn[:, 2]) < layout.vertical_max_nz)
            if not vert.any():
                continue
            u = _wall_normal(rn[vert], ra[vert])
            s0 = float(np.average(rc[vert] @ u, weights=np.maximum(ra[vert], 1e-12)))
            zs = rest.vertices[np.unique(rest.faces[vert])][:, 2]
            part_area = float(ra[m].sum())
            large = part_area >= cfg.wall_min_area and float(np.ptp(zs)) >= cfg.wall_min_height
            # a wall seen only above the furniture in front of it: a high strip
            strip = (z_floor is not None and part_area >= cfg.wall_strip_min_area
                     and float(np.ptp(zs)) >= cfg.wall_strip_min_height
                     and float(zs.max()) >= z_floor + cfg.wall_strip_min_top)
            if not (large or strip):
                continue
            d = ctx_c @ u - s0
            margin = cfg.wall_outside_margin
            beyond = min(float(ctx_a[d > margin].sum()), float(ctx_a[d < -margin].sum()))
            if beyond > cfg.wall_outside_share * float(ctx_a.sum()):
                continue
            keep |= m
            if planes is not None:
                t = rest.vertices[np.unique(rest.faces[vert])] @ np.cross(Z_UP, u)
                offset = _weighted_median(rc[vert] @ u, ra[vert], s0)  # robust to clutter on the wall's band
                planes.append(LayoutPlane("wall", u, offset, (float(t.min()), float(t.max()))))
        if keep.any():
            out["wall"] = sub_entity(rest, keep)
    return out


def faces_on_layout(entity: Entity, planes: list[LayoutPlane], band: float, max_angle_deg: float,
                    margin: float) -> NDArray:
    """Faces of ``entity`` lying in a layout plane: within ``band`` (m) of it, their normal within
    ``max_angle_deg`` of its normal (either side), and (walls) within its span grown by ``margin``."""
    if not entity.has_faces or not planes:
        return np.zeros(len(entity.faces), bool)
    c, n, a = _faces(entity)
    cos = float(np.cos(np.radians(max_angle_deg)))
    on = np.zeros(len(a), bool)
    for p in planes:
        hit = (np.abs(n @ p.normal) >= cos) & (np.abs(c @ p.normal - p.offset) <= band) & (a > 0)
        if p.role == "wall":
            t = c @ np.cross(Z_UP, p.normal)
            hit &= (t >= p.span[0] - margin) & (t <= p.span[1] + margin)
        on |= hit
    return on


def _weighted_median(values: NDArray, weights: NDArray, default: float) -> float:
    """Area-weighted median (``default`` when there is nothing to weigh)."""
    if len(values) == 0 or float(weights.sum()) <= 0.0:
        return float(default)
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][int(np.searchsorted(cum, 0.5 * cum[-1]))])


def _wall_normal(normals: NDArray, areas: NDArray) -> NDArray:
    """Area-weighted horizontal normal of a wall's faces (both sides folded onto one)."""
    ref = normals[int(np.argmax(areas))]
    signs = np.where(normals @ ref < 0, -1.0, 1.0)
    u = (normals * (signs * areas)[:, None]).sum(axis=0)
    u[2] = 0.0
    n = float(np.linalg.norm(u))
    return u / n if n > 0 else np.array([1.0, 0.0, 0.0])


def _context_faces(entities: list[Entity]) -> tuple[NDArray, NDArray]:
    """Face centroids and areas of all the meshes (vertices with unit weight for point entities)."""
    cs, as_ = [np.zeros((0, 3))], [np.zeros(0)]
    for e in entities:
        if e.has_faces:
            c, _n, a = _faces(e)
            cs.append(c)
            as_.append(a)
    return np.concatenate(cs), np.concatenate(as_)
