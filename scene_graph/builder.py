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

from recon_core.contact_graph import ROOT_ID, ContactGraph, GraphNode, SupportEdge, root_node
from recon_core.entity import Entity, EntityError
from scene_graph.blas import single_blas_thread
from scene_graph.broadphase import candidate_pairs
from scene_graph.classify import LAYOUT, classify
from scene_graph.config import SceneGraphConfig, load_scene_graph_config
from scene_graph.features import NodeFeatures, compute_features
from scene_graph.fragments import drop_fragments
from scene_graph.joints import SupportJointTable, load_support_joints
from scene_graph.layout import split_layout
from scene_graph.merge import fragment_hosts, merged_entity
from scene_graph.proximal import proximal_relations
from scene_graph.refine import refine_box
from scene_graph.support import SupportInference

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

    @property
    def ids(self) -> list[int]:
        """Ids of the entities held (source ids: a split layout entity is listed once)."""
        return sorted(self._cache)

    def features(self, entity_id: int) -> NodeFeatures:
        """The (first) node of an entity; its ``entity.revision`` is the entity's revision."""
        return self._cache[entity_id].nodes[0]


    def update(self, entities: Iterable[Entity]) -> list[int]:
        """Add or refresh entities; only those with a new (id, revision) are recomputed. Returns them."""
        rebuilt = []
        for e in entities:
            if e.class_name in self.cfg.ignore_classes:  # e.g. the map's unclaimed surface (entity 0)
                self._cache.pop(e.id, None)
                self.skipped[e.id] = f"class {e.class_name!r} is ignored"
                continue
            if e.id == ROOT_ID:
                raise EntityError(f"entity {e.name!r}: id {ROOT_ID} is reserved for the scene root")
            cached = self._cache.get(e.id)
            if cached is not None and cached.revision == e.revision and e.id not in self.skipped:
                continue
            sup = self.cfg.support
            try:
                with single_blas_thread():
                    parts = split_layout(e, self.cfg.layout, sup.wall_classes, sup.floor_classes + sup.ceiling_classes)
                    if classify(e.class_name, e.category, self.cfg.class_table).category != LAYOUT:
                        parts = [drop_fragments(e, self.cfg.fragments)]
                    feats = [compute_features(p, self.cfg) for p in parts]
            except EntityError as exc:
                log.warning("skipping entity %s: %s", e.id, exc)
                self._cache.pop(e.id, None)
                self.skipped[e.id] = str(exc)
                continue
            self.skipped.pop(e.id, None)
            self._cache[e.id] = _Cached(e.revision, feats, len(feats) > 1)
            rebuilt.append(e.id)
        return rebuilt

    def remove(self, ids: Iterable[int]) -> None:
        for i in ids:
            self._cache.pop(int(i), None)
            self.skipped.pop(int(i), None)

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
        t1 = time.perf_counter()

        graph = ContactGraph(name=name, frame_id=frame_id, nodes={ROOT_ID: root_node()})
        refined = {}
        for f in feats:
            d = support.decisions[f.id]
            refined[f.id] = refine_box(f.box, d, cfg.refine)
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
            "layout_parts": layout_parts, "merged_fragments": merged,
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
        for sid in self.ids:
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
