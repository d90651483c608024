"""Contact-graph construction (paper Sec. 2.2): initialise nodes, infer supports, refine, relate.

``build_contact_graph(entities)`` is the one-shot entry point. ``ContactGraphBuilder`` keeps the
per-entity work (layout split, box, planes) cached by (entity id, revision), so a stream of mapper
updates recomputes only the entities that changed; the relations are re-derived over all nodes
every time (they are cheap next to plane extraction, and any change can move any support).

A mapped layout entity may become several nodes (``layout.py``: the map's single "wall" entity
-> one node per wall); those nodes get ids no entity uses (numbered from
max(layout.part_id_base, largest entity id + 1), in source-id order) and
``graph.stats["layout_parts"]`` lists them per source entity id.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from recon_core.contact_graph import ROOT_ID, ContactGraph, GraphNode, SupportEdge, root_node
from recon_core.entity import Entity, EntityError
from scene_graph.blas import single_blas_thread
from scene_graph.broadphase import candidate_pairs
from scene_graph.classify import LAYOUT, class_info, classify
from scene_graph.config import SceneGraphConfig, load_scene_graph_config
from scene_graph.features import NodeFeatures, compute_features
from scene_graph.fragments import drop_fragments
from scene_graph.geometric_layout import (
    LayoutPlane,
    concat_entities,
    faces_on_layout,
    give_up_layout_planes,
    layout_from_geometry,
)
from scene_graph.joints import SupportJointTable, load_support_joints
from scene_graph.layout import _faces, split_layout, sub_entity
from scene_graph.merge import fragment_hosts, merged_entity
from scene_graph.proximal import proximal_relations
from scene_graph.refine import refine_box
from scene_graph.support import SupportInference
from scene_graph.surfaces import observed_supports

log = logging.getLogger(__name__)

#: Footprint bounds are grown by this much (m) for the support broad phase (touching counts).
FOOTPRINT_EPS = 1e-6


@dataclass
class _Cached:
    revision: int
    #: The entity's nodes: one, or the parts of a split layout entity.
    nodes: list[NodeFeatures]
    split: bool = False


def support_neighbours(features: list[NodeFeatures], method: str) -> tuple[dict[int, set[int]], int]:
    """Per node, the nodes whose footprint bounds meet its own (support candidates), and the pair count."""
    ids = [f.id for f in features]
    nbrs: dict[int, set[int]] = {i: set() for i in ids}
    if len(features) < 2:
        return nbrs, 0
    bounds = [f.box.aabb() for f in features]
    lo = np.array([b[0][:2] for b in bounds]) - FOOTPRINT_EPS
    hi = np.array([b[1][:2] for b in bounds]) + FOOTPRINT_EPS
    pairs = candidate_pairs(lo, hi, method)
    for a, b in pairs:
        nbrs[ids[a]].add(ids[b])
        nbrs[ids[b]].add(ids[a])
    return nbrs, len(pairs)


class ContactGraphBuilder:
    """Incremental builder: ``update`` entities (by revision), ``remove`` ids, ``build`` the graph."""

    def __init__(self, cfg: SceneGraphConfig | None = None, joints: SupportJointTable | None = None) -> None:
        self.cfg = cfg or load_scene_graph_config()
        self.joints = joints or load_support_joints(self.cfg.support_joints or None)
        self._cache: dict[int, _Cached] = {}
        #: Merged over-segmented nodes of the last build, by their members' (id, revision, size).
        self._merged: dict[tuple, NodeFeatures] = {}
        self.skipped: dict[int, str] = {}
        #: Layout from geometry: the latest unlabelled surface, the planes things gave up (by thing id),
        #: the derived layout entities (role -> id) and what was derived (graph.stats["geometric_layout"]).
        self._unlabelled: Entity | None = None
        self._given_up: dict[int, Entity] = {}
        self._derived: dict[str, int] = {}
        self._layout_key: tuple | None = None
        self._layout_revision = 0
        self.layout_info: dict[str, dict[str, int]] = {}
        #: The derived layout's planes; per thing, its mesh before it gave up the faces in them, and
        #: which faces it gave up (their indices' digest, and their area) when it did.
        self._planes: list[LayoutPlane] = []
        self._untrimmed: dict[int, Entity] = {}
        self._trim: dict[int, tuple[bytes, float]] = {}
        #: Every entity as it was given (newest revision per id, ignored classes included): what a build
        #: from scratch starts from (``source_entities``).
        self._sources: dict[int, Entity] = {}
        #: Support patches of the last build (``surfaces.py``), by node id.
        self._patches: dict[int, Entity] = {}

    def source_entities(self) -> list[Entity]:
        """The entities held, as they were given (not the nodes' processed geometry: things without
        the layout they gave up, fragments dropped), the unlabelled surface included: a fresh builder
        given these builds the graph a batch build of the same map gives."""
        return [self._sources[i] for i in sorted(self._sources)]

    def source_revision(self, entity_id: int) -> int | None:
        """The revision of the entity held under this id (None: none is held): unchanged ones can be skipped."""
        e = self._sources.get(int(entity_id))
        return None if e is None else int(e.revision)

    @property
    def ids(self) -> list[int]:
        """Ids of the entities held (source ids: a split layout entity is listed once; layout derived
        from geometry is not listed: it has no source entity)."""
        derived = set(self._derived.values())
        return sorted(i for i in self._cache if i not in derived)

    def features(self, entity_id: int) -> NodeFeatures:
        """The (first) node of an entity; its ``entity.revision`` is the entity's revision."""
        return self._cache[entity_id].nodes[0]


    def update(self, entities: Iterable[Entity]) -> list[int]:
        """Add or refresh entities; only those with a new (id, revision) are recomputed. Returns them.

        With ``geometric_layout.enabled``: things give up layout planes larger than their class can be,
        and while no floor or wall entity is held, floor / wall / ceiling entities are derived from
        the unlabelled surface (``geometric_layout.py``; ids ``geometric_layout.id_base`` + 0/1/2).
        """
        gl = self.cfg.geometric_layout
        rebuilt = []
        for e in entities:
            self._sources[e.id] = e
            if gl.enabled and e.class_name in gl.source_classes:
                self._unlabelled = e
            if self._update_one(e):
                rebuilt.append(e.id)
        if gl.enabled:
            rebuilt += self._update_geometric_layout()
        return rebuilt

    def _update_one(self, e: Entity) -> bool:
        if e.class_name in self.cfg.ignore_classes:  # e.g. the map's unclaimed surface (entity 0)
            self._cache.pop(e.id, None)
            self.skipped[e.id] = f"class {e.class_name!r} is ignored"
            return False
        if e.id == ROOT_ID:
            raise EntityError(f"entity {e.name!r}: id {ROOT_ID} is reserved for the scene root")
        cached = self._cache.get(e.id)
        if cached is not None and cached.revision == e.revision and e.id not in self.skipped:
            return False
        revision = e.revision
        try:
            with single_blas_thread():
                e = self._give_up_layout(e)
                self._untrimmed.pop(e.id, None)
                self._trim.pop(e.id, None)
                if self._trims(e):
                    self._untrimmed[e.id] = e
                    e = self._trimmed(e)
                feats = self._features(e)
        except EntityError as exc:
            log.warning("skipping entity %s: %s", e.id, exc)
            self._cache.pop(e.id, None)
            self.skipped[e.id] = str(exc)
            return False
        self.skipped.pop(e.id, None)
        self._cache[e.id] = _Cached(revision, feats, len(feats) > 1)
        return True

    def _features(self, e: Entity) -> list[NodeFeatures]:
        """The entity's node(s): the parts of a layout entity, or the thing without its fragments."""
        sup = self.cfg.support
        parts = split_layout(e, self.cfg.layout, sup.wall_classes, sup.floor_classes + sup.ceiling_classes)
        if classify(e.class_name, e.category, self.cfg.class_table).category != LAYOUT:
            parts = [drop_fragments(e, self.cfg.fragments)]
        return [compute_features(p, self.cfg) for p in parts]

    def _trims(self, e: Entity) -> bool:
        """Whether the entity gives its faces in derived layout planes up: a thing, not `flush`."""
        if not self.cfg.geometric_layout.enabled or not e.has_faces or e.id in self._derived.values():
            return False
        info = class_info(e.class_name, self.cfg.class_table)
        return info is None or (not info.is_layout and not info.flush)

    def _layout_mask(self, e: Entity) -> NDArray:
        gl = self.cfg.geometric_layout
        return faces_on_layout(e, self._planes, gl.layout_band, gl.layout_band_deg, gl.layout_band_margin)

    def _trimmed(self, e: Entity, mask: NDArray | None = None) -> Entity:
        """The thing without its faces in the derived layout planes (a thing that is all plane keeps all)."""
        mask = self._layout_mask(e) if mask is None else mask
        if not mask.any() or mask.all():
            self._trim.pop(e.id, None)
            return e
        _c, _n, area = _faces(e)
        self._trim[e.id] = (np.flatnonzero(mask).tobytes(), float(area[mask].sum()))
        return sub_entity(e, ~mask)

    def _apply_planes(self, planes: list[LayoutPlane]) -> list[int]:
        """New derived layout planes: things whose faces in them changed get their node recomputed."""
        self._planes = planes
        changed = []
        for eid, e in list(self._untrimmed.items()):
            cached = self._cache.get(eid)
            if cached is None:
                del self._untrimmed[eid]
                self._trim.pop(eid, None)
                continue
            mask = self._layout_mask(e)
            old = self._trim.get(eid)
            new_key = np.flatnonzero(mask).tobytes() if mask.any() and not mask.all() else None
            if (old[0] if old else None) == new_key:
                continue
            try:
                with single_blas_thread():
                    cached.nodes = self._features(self._trimmed(e, mask))
            except EntityError as exc:
                log.warning("entity %s without its layout faces: %s", eid, exc)
                continue
            changed.append(eid)
        if changed:
            log.info("things without the faces they had in the floor/wall planes: %s", ", ".join(
                f"{i} ({self._trim[i][1]:.2f} m^2)" if i in self._trim else str(i) for i in changed))
        return changed

    @property
    def layout_faces_given(self) -> dict[int, float]:
        """Per thing id, the area (m^2) of its faces given to the derived floor / wall planes."""
        return {i: round(t[1], 4) for i, t in sorted(self._trim.items())}

    def _give_up_layout(self, e: Entity) -> Entity:
        """The thing without the layout planes it cannot own (recorded for the derived layout)."""
        gl = self.cfg.geometric_layout
        self._given_up.pop(e.id, None)
        if not gl.enabled or not e.has_faces or e.id in self._derived.values():
            return e
        info = class_info(e.class_name, self.cfg.class_table)
        if info is None or info.is_layout or not info.max_size_m:
            return e
        kept, given = give_up_layout_planes(e, info.max_size_m, gl)
        if given is not None:
            self._given_up[e.id] = given
        return kept

    def _has_labelled_layout(self) -> bool:
        sup = self.cfg.support
        layout = set(sup.floor_classes) | set(sup.wall_classes)
        derived = set(self._derived.values())
        return any(c.nodes and c.nodes[0].entity.class_name in layout
                   for i, c in self._cache.items() if i not in derived)

    def _update_geometric_layout(self) -> list[int]:
        """(Re)derive floor / wall / ceiling from the unlabelled surface when the map has no layout entity."""
        gl = self.cfg.geometric_layout
        for i in [i for i in self._given_up if i not in self._cache]:
            del self._given_up[i]  # removed things give nothing
        if self._has_labelled_layout():
            self._drop_derived()
            self._layout_key = None  # derive again should the labelled layout go
            return self._apply_planes([]) if self._planes else []
        pieces = [self._given_up[i] for i in sorted(self._given_up)]
        u = self._unlabelled
        key = ((u.id, u.revision, len(u.faces)) if u is not None else None,
               tuple((i, len(self._given_up[i].faces)) for i in sorted(self._given_up)))
        if key == self._layout_key:
            return []
        self._layout_key = key
        self._drop_derived()
        if u is None and not pieces:
            return self._apply_planes([]) if self._planes else []
        base = u if u is not None else pieces[0]
        surface = concat_entities(base, pieces if u is not None else pieces[1:])
        derived = set(self._derived.values())
        # the things as they were before giving up their faces in the previous planes: the walls found
        # do not depend on the order of updates (a build from scratch sees them so too)
        context = [self._untrimmed.get(i, c.nodes[0].entity) for i, c in self._cache.items()
                   if i not in derived and c.nodes]
        planes: list[LayoutPlane] = []
        with single_blas_thread():
            found = layout_from_geometry(surface, context, gl, self.cfg.layout, planes)
        self._layout_revision += 1
        table = self.cfg.class_table
        rebuilt = []
        for k, role in enumerate(("floor", "wall", "ceiling")):
            if role not in found:
                continue
            classes = {"floor": self.cfg.support.floor_classes, "wall": self.cfg.support.wall_classes,
                       "ceiling": self.cfg.support.ceiling_classes}[role]
            name = classes[0] if classes else role
            nc = classify(name, "layout", table)
            eid = gl.id_base + k
            ent = Entity(eid, name, found[role].vertices, found[role].faces, name=name, class_id=nc.class_id,
                         instance_id=0, category=LAYOUT, is_thing=False, confidence=1.0,
                         revision=self._layout_revision)
            self._derived[role] = eid
            if self._update_one(ent):
                rebuilt.append(eid)
        self.layout_info = {role: {"id": self._derived[role], "faces": len(found[role].faces)}
                            for role in self._derived}
        rebuilt += self._apply_planes(planes)
        if found:
            log.info("layout from geometry: %s", ", ".join(f"{r} ({v['faces']} faces)"
                                                            for r, v in self.layout_info.items()))
        return rebuilt

    def _drop_derived(self) -> None:
        for eid in self._derived.values():
            self._cache.pop(eid, None)
            self.skipped.pop(eid, None)
        self._derived.clear()
        self.layout_info = {}

    def remove(self, ids: Iterable[int]) -> None:
        derived = set(self._derived.values())
        for i in ids:
            if int(i) in derived:
                continue
            self._cache.pop(int(i), None)
            self.skipped.pop(int(i), None)
            self._given_up.pop(int(i), None)
            self._sources.pop(int(i), None)
            self._untrimmed.pop(int(i), None)
            self._trim.pop(int(i), None)
            if self._unlabelled is not None and self._unlabelled.id == int(i):
                self._unlabelled = None
        if self.cfg.geometric_layout.enabled:
            self._update_geometric_layout()

    def build(self, name: str = "", frame_id: str = "map") -> ContactGraph:
        """Relations over the cached nodes: supports (Eqs. (1)-(3)), refinement, proximal pairs."""
        cfg = self.cfg
        t0 = time.perf_counter()
        feats, layout_parts = self._nodes()
        feats, merged = self._merge_fragments(feats)
        names = _unique_names(feats)
        nodes_by_id = {f.id: f for f in feats}
        neighbours, support_pairs = support_neighbours(feats, cfg.proximal.broadphase)
        support = SupportInference(nodes_by_id, neighbours, cfg.support).run()
        patches = observed_supports(nodes_by_id, support, self._unlabelled, cfg)
        for p in patches:  # static slabs on observed, undetected surfaces under unsupported movable things
            feats.append(p.node)
            nodes_by_id[p.id] = p.node
            names[p.id] = p.node.name
        self._patches = {p.id: p.node.entity for p in patches}
        t1 = time.perf_counter()

        graph = ContactGraph(name=name, frame_id=frame_id, nodes={ROOT_ID: root_node()})
        refined = {}
        for f in feats:
            d = support.decisions[f.id]
            info = class_info(f.node_class.class_name, cfg.class_table)
            tallest = cfg.geometric_layout.size_factor * info.max_size_m if info and info.max_size_m else None
            refined[f.id] = refine_box(f.box, d, cfg.refine, tallest)
            parent_class = graph_class(nodes_by_id, d.parent_id)
            joint = self.joints.resolve(parent_class, f.node_class.class_name, f.node_class.movable,
                                        f.category == LAYOUT)
            graph.supports[f.id] = SupportEdge(d.parent_id, f.id, d.kind, float(d.score), float(d.contact_ratio),
                                               float(d.distance), d.plane.plane if d.plane else None, joint)
        for f in feats:
            planes = f.planes + support.inferred_planes.get(f.id, [])
            graph.nodes[f.id] = GraphNode(f.id, names[f.id], f.node_class.class_name, f.category,
                                          f.node_class.class_id, refined[f.id], f.box, planes,
                                          float(f.entity.confidence), f.node_class.movable)
        skip = set() if cfg.proximal.include_layout else {f.id for f in feats if f.category == LAYOUT}
        prox = proximal_relations([f.id for f in feats], [refined[f.id] for f in feats], graph.parents(),
                                  cfg.proximal, skip)
        graph.proximal = prox.pairs
        graph.skipped = dict(self.skipped)
        for host, frags in merged.items():
            for i in frags:
                graph.skipped[i] = f"fragment of node {host} (same class, box inside it): merged"
        t2 = time.perf_counter()
        graph.stats = {
            "layout_parts": layout_parts, "merged_fragments": merged, "geometric_layout": dict(self.layout_info),
            "layout_faces_given_m2": {str(k): v for k, v in self.layout_faces_given.items()},
            "surface_patches": {str(p.child_id): {"id": p.id, "height": round(p.height, 4),
                                                  "area_unlabelled_m2": round(p.area_unlabelled, 5),
                                                  "area_own_m2": round(p.area_own, 5)} for p in patches},
            "nodes": len(feats), "support_candidate_pairs": support_pairs, "support_plane_tests": support.plane_tests,
            "proximal_broadphase_pairs": prox.broadphase_pairs, "proximal_exact_tests": prox.exact_tests,
            "support_s": t1 - t0, "relations_s": t2 - t1,
        }
        graph.validate()
        return graph

    def _nodes(self) -> tuple[list[NodeFeatures], dict[int, list[int]]]:
        """Every node; split layout parts renumbered to ids no entity uses (source id -> part ids)."""
        next_id = max(self.cfg.layout.part_id_base, max(self._cache, default=0) + 1)
        feats: list[NodeFeatures] = []
        parts: dict[int, list[int]] = {}
        for sid in sorted(self._cache):
            cached = self._cache[sid]
            if not cached.split:
                feats.extend(cached.nodes)
                continue
            for k, f in enumerate(cached.nodes):
                if f.entity.id != next_id:
                    f = replace(f, entity=replace(f.entity, id=next_id))
                    cached.nodes[k] = f
                feats.append(f)
                parts.setdefault(sid, []).append(next_id)
                next_id += 1
        return feats, parts


    def _merge_fragments(self, feats: list[NodeFeatures]) -> tuple[list[NodeFeatures], dict[int, list[int]]]:
        """Over-segmented same-class nodes joined (``merge.py``); host id -> fragment ids."""
        hosts = fragment_hosts(feats, self.cfg.merge)
        if not hosts:
            self._merged.clear()
            return feats, {}
        by_id = {f.id: f for f in feats}
        groups: dict[int, list[int]] = {}
        for frag, host in sorted(hosts.items()):
            groups.setdefault(host, []).append(frag)
        out, cache = [], {}
        for f in feats:
            if f.id in hosts:
                continue
            if f.id not in groups:
                out.append(f)
                continue
            members = [f] + [by_id[i] for i in groups[f.id]]
            key = tuple((m.id, m.entity.revision, len(m.entity.vertices)) for m in members)
            merged = self._merged.get(key)
            if merged is None:
                with single_blas_thread():
                    merged = compute_features(merged_entity(f.entity, [m.entity for m in members[1:]]), self.cfg)
            cache[key] = merged
            out.append(merged)
        self._merged = cache
        return out, groups

    def node_entities(self) -> dict[int, Entity]:
        """Node id -> the entity (layout part, merged object) behind it, as of the last ``build``."""
        out = {f.id: f.entity for c in self._cache.values() for f in c.nodes}
        out.update({f.id: f.entity for f in self._merged.values()})
        out.update(self._patches)
        return out


def graph_class(nodes: dict[int, NodeFeatures], node_id: int) -> str:
    return "scene" if node_id == ROOT_ID else nodes[node_id].node_class.class_name


def _unique_names(feats: list[NodeFeatures]) -> dict[int, str]:
    """Entity names, made unique (a duplicate gets its id appended): names become URDF links."""
    seen: dict[str, int] = {}
    for f in feats:
        seen[f.name] = seen.get(f.name, 0) + 1
    return {f.id: (f.name or f"entity_{f.id}") if seen[f.name] == 1 and f.name else f"{f.name or 'entity'}_{f.id}"
            for f in feats}


def build_contact_graph(entities: Iterable[Entity], cfg: SceneGraphConfig | None = None,
                        joints: SupportJointTable | None = None, name: str = "", frame_id: str = "map") -> ContactGraph:
    """Build the contact graph of a set of entities in one go (see ``ContactGraphBuilder``)."""
    t0 = time.perf_counter()
    builder = ContactGraphBuilder(cfg, joints)
    builder.update(entities)
    t1 = time.perf_counter()
    graph = builder.build(name, frame_id)
    graph.stats["features_s"] = t1 - t0
    graph.stats["total_s"] = time.perf_counter() - t0
    return graph
