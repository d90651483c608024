"""Support patches from observed, undetected surfaces (issue 22). NOT in the paper.

A movable thing that support inference leaves without a carrying plane (``fallback_root``: no floor
in view; ``fallback_floor`` without a plane, its bottom too high above the floor for its class to
reach down) falls in a simulator. Often the surface it stands on *was* observed but not detected as
an entity: a desk top a COCO detector has no box for, a counter left unlabelled. Its faces are then
in the map's unlabelled surface (the ``unknown`` entity), and the thing's own mask usually bled onto
it (the lowest faces of the thing's mesh face up).

``observed_supports`` looks, under each such thing's footprint, for upward faces (``n_z >= -a_th``)
within ``band`` of its bottom, in the unlabelled surface and among the thing's own faces. With
enough of them (``min_area``, or ``min_share`` of the footprint for small things) a static layout
node is derived: a slab ``thickness`` thick whose top is the observed surface's height (the
area-weighted median of those faces), covering the thing's footprint grown by ``margin`` (the
surface continues unseen under the thing, as the floor does), with one supporting plane there. The
thing stands on it (kind ``observed_surface``, Eq. (1) distance to that plane). Without evidence
nothing changes: a thing floating in view is not given a surface nobody saw.

Stage 4 exports a layout node as a box (``cad_replacement.replacer.layout_object``: bottom at the
box bottom, so the slab's top is the surface), fixed to the map.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from recon_core.entity import Entity
from recon_core.geometry.box import GravityBox
from recon_core.geometry.gravity import UP
from recon_core.geometry.plane import Plane, SurfacePlane
from recon_core.geometry.polygon import EPS
from scene_graph.classify import LAYOUT, class_info, classify
from scene_graph.config import SceneGraphConfig
from scene_graph.features import NodeFeatures
from scene_graph.support import ROOT_ID, SupportDecision, SupportResult, footprint_triangles

#: Kind of the support edge of a thing standing on a derived surface patch, and of the patch's own edge.
KIND = "observed_surface"
PATCH_KIND = "root"


@dataclass
class SurfacePatch:
    """A derived support patch: its node, the thing it carries and the evidence behind it."""

    node: NodeFeatures
    child_id: int
    height: float
    #: Area (m^2) of upward faces found, from the unlabelled surface and from the thing's own mesh.
    area_unlabelled: float
    area_own: float

    @property
    def id(self) -> int:
        return self.node.id


def _upward_faces(entity: Entity | None, up_cos: float) -> tuple[NDArray, NDArray, NDArray]:
    """Centroids (F, 3), areas (F,) and vertex triples (F, 3, 3) of an entity's upward faces."""
    if entity is None or not entity.has_faces:
        return np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3, 3))
    tri = entity.vertices[entity.faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    nz = cross[:, 2] / np.maximum(norm, EPS)
    up = (nz >= up_cos) & (norm > 0.0)
    return tri[up].mean(axis=1), 0.5 * norm[up], tri[up]


def unsupported(node: NodeFeatures, decision: SupportDecision, nodes: Mapping[int, NodeFeatures],
                cfg: SceneGraphConfig) -> bool:
    """Whether a thing has nothing under it in the graph that a simulator would carry it on.

    ``fallback_root``, or ``fallback_floor`` without a plane when the thing is too high above the floor
    for its class to reach down to it (stage 4 stands a thing no taller than its class can be on the
    floor: a table seen as its top)."""
    if node.category == LAYOUT or (cfg.surfaces.movable_only and not node.node_class.movable):
        return False
    if decision.kind == "fallback_root":
        return True
    if decision.kind != "fallback_floor" or decision.plane is not None:
        return False
    floor = nodes.get(decision.parent_id)
    if floor is None:
        return True
    info = class_info(node.node_class.class_name, cfg.class_table)
    max_size = info.max_size_m if info is not None else None
    return max_size is None or node.box.z_max - floor.box.z_max > max_size


def _in_footprint(box: GravityBox, xy: NDArray, margin: float) -> NDArray:
    if len(xy) == 0:
        return np.zeros(0, dtype=bool)
    local = box.to_local_xy(xy)
    return np.all(np.abs(local) <= 0.5 * box.size[:2] + margin, axis=1)


def surface_patch(node: NodeFeatures, unlabelled: Entity | None, cfg: SceneGraphConfig,
                  patch_id: int) -> SurfacePatch | None:
    """The support patch under ``node`` from the observed upward faces near its bottom, or None."""
    sc = cfg.surfaces
    up_cos = -cfg.support.a_th
    box = node.box
    bottom = box.z_min
    # the thing's own faces count only in its lower part: a thin thing's top is not its support
    own_top = bottom + min(sc.band, 0.25 * float(box.size[2]))
    found = []
    areas = []
    for source, top in ((unlabelled, bottom + sc.band), (node.entity, own_top)):
        c, a, tri = _upward_faces(source, up_cos)
        keep = (c[:, 2] >= bottom - sc.band) & (c[:, 2] <= top) if len(c) else np.zeros(0, dtype=bool)
        keep[keep] = _in_footprint(box, c[keep, :2], sc.margin)
        found.append((c[keep], a[keep], tri[keep]))
        areas.append(float(a[keep].sum()))
    area = sum(areas)
    need = min(sc.min_area, sc.min_share * box.footprint_area)
    if area <= 0.0 or area < need:
        return None
    z = np.concatenate([f[0][:, 2] for f in found])
    w = np.concatenate([f[1] for f in found])
    order = np.argsort(z)
    cum = np.cumsum(w[order])
    height = float(z[order][int(np.searchsorted(cum, 0.5 * cum[-1]))])  # area-weighted median
    size = np.array([box.size[0] + 2.0 * sc.margin, box.size[1] + 2.0 * sc.margin, sc.thickness])
    patch_box = GravityBox(np.array([box.center[0], box.center[1], height - 0.5 * sc.thickness]), size, box.yaw)
    tri = np.concatenate([f[2] for f in found])
    name = sc.class_name
    nc = classify(name, LAYOUT, cfg.class_table)
    entity = Entity(patch_id, name, tri.reshape(-1, 3).astype(np.float64),
                    np.arange(3 * len(tri), dtype=np.int64).reshape(-1, 3),
                    name=f"{name}_under_{node.name or node.id}", class_id=nc.class_id, category=LAYOUT,
                    is_thing=False, confidence=1.0, revision=int(node.entity.revision))
    plane = SurfacePlane(Plane(normal=UP, d=-height, area=float(size[0] * size[1])), KIND,
                         footprint_triangles(patch_box))
    return SurfacePatch(NodeFeatures(entity, nc, patch_box, [plane]), node.id, height, areas[0], areas[1])


def observed_supports(nodes: Mapping[int, NodeFeatures], support: SupportResult, unlabelled: Entity | None,
                      cfg: SceneGraphConfig) -> list[SurfacePatch]:
    """Derive a support patch for every unsupported movable thing with an observed surface under it;
    ``support.decisions`` gets the things' new edges and the patches' own (to the root)."""
    if not cfg.surfaces.enabled:
        return []
    out = []
    for nid in sorted(nodes):
        node = nodes[nid]
        decision = support.decisions.get(nid)
        if decision is None or not unsupported(node, decision, nodes, cfg):
            continue
        patch = surface_patch(node, unlabelled, cfg, cfg.surfaces.id_base + nid)
        if patch is None or patch.id in nodes:
            continue
        plane = patch.node.planes[0]
        dist = node.box.z_min - patch.height
        score = 1.0 - min(1.0, abs(dist) / cfg.support.distance_scale)  # Eq. (3), the patch covers the footprint
        support.decisions[nid] = SupportDecision(nid, patch.id, KIND, score, 1.0, dist, plane)
        support.decisions[patch.id] = SupportDecision(patch.id, ROOT_ID, PATCH_KIND, 1.0, 1.0, 0.0, None)
        out.append(patch)
    return out


__all__ = ["KIND", "SurfacePatch", "observed_supports", "surface_patch", "unsupported"]
