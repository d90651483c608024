"""Over-segmented objects: a node whose box lies mostly inside a larger node of its class joins it.

A panoptic map sometimes cuts one object into instances of the same class that its instance
merging (Eq. (5): shared voxels) cannot join because they share no voxels: a table leg, the far
edge strip of a table top. As nodes they are extra detections and, worse, supporting candidates.
Two genuine instances of a class cannot occupy the same space (the non-penetration constraint of
the proximal relations, Sec. 2.1), so before supports are inferred (not in the paper):

* object nodes (not layout) of the same class are compared pairwise; a node whose box (padded to
  ``min_extent`` per axis) has at least ``min_inside`` of its volume inside the box of a node of
  the same class with a larger volume is a fragment of it (the one it overlaps most);
* chains resolve to the largest node; its mesh becomes the union of the group's meshes and its
  box and planes are recomputed; the fragments are no nodes of their own.

Complete meshes of distinct objects never nest like this (stacked books touch, they do not
overlap), so ground-truth input is unchanged.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from recon_core.entity import Entity
from recon_core.geometry.box import GravityBox
from scene_graph.classify import LAYOUT
from scene_graph.config import MergeConfig
from scene_graph.features import NodeFeatures


def _padded(box: GravityBox, min_extent: float) -> GravityBox:
    return GravityBox(box.center, np.maximum(box.size, min_extent), box.yaw)


def fragment_hosts(feats: list[NodeFeatures], cfg: MergeConfig) -> dict[int, int]:
    """Fragment node id -> the id of the node it joins (the largest of its group)."""
    if not cfg.enabled:
        return {}
    things = [f for f in feats if f.category != LAYOUT]
    boxes = {f.id: _padded(f.box, cfg.min_extent) for f in things}
    volume = {i: b.volume for i, b in boxes.items()}
    parent: dict[int, int] = {}
    by_class: dict[str, list[NodeFeatures]] = {}
    for f in things:
        by_class.setdefault(f.node_class.class_name, []).append(f)
    for group in by_class.values():
        if len(group) < 2:
            continue
        order = sorted(group, key=lambda f: (volume[f.id], f.id))
        for k, small in enumerate(order):
            best, best_share = None, cfg.min_inside
            for big in order[k + 1:]:
                lo_a, hi_a = boxes[small.id].aabb()
                lo_b, hi_b = boxes[big.id].aabb()
                if np.any(lo_a > hi_b) or np.any(lo_b > hi_a):
                    continue
                share = boxes[small.id].intersection_volume(boxes[big.id]) / volume[small.id]
                if share >= best_share:
                    best, best_share = big.id, share
            if best is not None:
                parent[small.id] = best
    hosts = {}
    for i in parent:
        root = i
        while root in parent:
            root = parent[root]
        hosts[i] = root
    return hosts


def merged_entity(host: Entity, fragments: list[Entity]) -> Entity:
    """The host entity with the fragments' geometry appended (host id, name, class and confidence).

    Every part's voted core comes first, then every part's fringe (``Entity.core_vertices``)."""
    parts = [host, *fragments]
    cores = [len(e.vertices) if e.core_vertices < 0 else e.core_vertices for e in parts]
    n_core = sum(cores)
    verts, faces = [], []
    core_at, fringe_at = 0, n_core
    for e, c in zip(parts, cores, strict=True):
        n = len(e.vertices)
        index = np.empty(n, np.int64)  # the part's vertex i -> its index in the merged entity
        index[:c] = np.arange(core_at, core_at + c)
        index[c:] = np.arange(fringe_at, fringe_at + n - c)
        core_at, fringe_at = core_at + c, fringe_at + n - c
        verts.append((index, e.vertices))
        faces.append(index[e.faces])
    merged = np.zeros((fringe_at, 3))
    for index, v in verts:
        merged[index] = v
    return replace(host, vertices=merged, faces=np.concatenate(faces), core_vertices=n_core)
