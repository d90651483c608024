"""Proximal relations E (paper Sec. 2.1): non-supporting pairs whose 3D boxes overlap.

Only pairs with Vol(B_1 ∩ B_2) > 0 get a relation (their meshes must not interpenetrate, Sec.
4.4), which is what keeps the relation set small. Candidate pairs come from the sort-and-prune
broad phase on the (margin-inflated) axis-aligned bounds; only those reach the exact yaw-box
test (footprint separating-axis test plus z overlap). Support parent-child pairs are excluded.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from recon_core.geometry.box import GravityBox
from recon_core.geometry.polygon import rectangle, rectangles_overlap
from scene_graph.broadphase import candidate_pairs
from scene_graph.config import ProximalConfig


@dataclass
class ProximalResult:
    pairs: list[tuple[int, int]] = field(default_factory=list)
    #: Pairs the broad phase passed on, and pairs that reached the exact box test.
    broadphase_pairs: int = 0
    exact_tests: int = 0


def inflated_aabbs(boxes: list[GravityBox], margin: float) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) lo/hi bounds of the boxes grown by ``margin`` on every side."""
    if not boxes:
        return np.zeros((0, 3)), np.zeros((0, 3))
    lo, hi = (np.array(a) for a in zip(*(b.aabb() for b in boxes), strict=True))
    return lo - margin, hi + margin


def boxes_overlap(a: GravityBox, b: GravityBox, margin: float) -> bool:
    """Exact test of two yaw boxes, each grown by ``margin`` (touching counts)."""
    if a.z_min - margin > b.z_max + margin or b.z_min - margin > a.z_max + margin:
        return False
    ra = rectangle(a.center[:2], a.size[:2] + 2 * margin, a.yaw)
    rb = rectangle(b.center[:2], b.size[:2] + 2 * margin, b.yaw)
    return rectangles_overlap(ra, rb)


def proximal_relations(ids: list[int], boxes: list[GravityBox], parent: Mapping[int, int],
                       cfg: ProximalConfig, skip: set[int] | None = None, exact_test=boxes_overlap) -> ProximalResult:
    """Proximal pairs (id_a < id_b) among the nodes; ``skip`` ids take no part (e.g. layout)."""
    skip = skip or set()
    keep = [k for k, i in enumerate(ids) if i not in skip]
    ids_k = [ids[k] for k in keep]
    boxes_k = [boxes[k] for k in keep]
    lo, hi = inflated_aabbs(boxes_k, cfg.margin)
    cand = candidate_pairs(lo, hi, cfg.broadphase)
    result = ProximalResult(broadphase_pairs=len(cand))
    for a, b in cand:
        ia, ib = ids_k[a], ids_k[b]
        if parent.get(ia) == ib or parent.get(ib) == ia:
            continue
        result.exact_tests += 1
        if exact_test(boxes_k[a], boxes_k[b], cfg.margin):
            result.pairs.append((min(ia, ib), max(ia, ib)))
    result.pairs.sort()
    return result
