"""Which predicted node is which ground-truth node: class + 3D box overlap, Hungarian assignment.

Predicted and annotated graphs share no ids (a mapper numbers its entities as it likes), so the
metrics first pair nodes by geometry (never by id).

Objects (rigid / articulated): the similarity is the exact box IoU; a pair qualifies when IoU >=
``min_iou`` or when the predicted box lies largely inside the true one (share of the *predicted*
box inside the ground-truth box >= ``min_containment``: a partially observed cabinet has a small
box inside the true one). Only that direction counts: a ground-truth book inside a large
predicted box is not evidence that the two are the same entity. Cross-class pairs may match at an
extra cost and count as label substitutions (a wrong detection, Sec. 5.3).

Layout nodes (floor, walls, ceiling) are matched to layout nodes of the same class only, by
containment of the observed part: the share of the predicted box inside the ground-truth box
grown by ``layout_margin`` (a mapped floor is a partial, thin surface at the top of a 5 cm
ground-truth slab; a mapped wall the inner face of a 10 cm one) must reach
``layout_min_containment``; the cost is 1 - that share. Box IoU is meaningless there (a seen
quarter of a wall has IoU ~0.25 with the wall, a floor surface ~0 with the slab). Layout and
object nodes never match each other.

The roots always match. Boxes are padded to ``min_extent`` per axis for matching only: an
observed wall or floor is one face, a box without volume."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from recon_core.contact_graph import ContactGraph
from recon_core.geometry.box import GravityBox, iou_matrix
from scene_graph.classify import LAYOUT
from scene_graph.config import MatchConfig

#: Cost of a forbidden pair in the assignment (larger than any allowed cost).
FORBIDDEN = 1e6


@dataclass
class NodeMatching:
    """pred id -> gt id for matched nodes (roots included), the IoU of each pair, and substitutions."""

    pred_to_gt: dict[int, int] = field(default_factory=dict)
    iou: dict[int, float] = field(default_factory=dict)
    substituted: set[int] = field(default_factory=set)

    @property
    def gt_to_pred(self) -> dict[int, int]:
        return {g: p for p, g in self.pred_to_gt.items()}


def _containment(pred: GravityBox, gt: GravityBox) -> float:
    """Share of the predicted box's volume inside the ground-truth box (0 for a box without volume)."""
    return pred.intersection_volume(gt) / pred.volume if pred.volume > 0.0 else 0.0


def _grown(box: GravityBox, margin: float) -> GravityBox:
    return GravityBox(box.center, box.size + 2.0 * margin, box.yaw)


def match_nodes(pred: ContactGraph, gt: ContactGraph, cfg: MatchConfig | None = None,
                unrefined: bool = False) -> NodeMatching:
    """Hungarian matching of non-root nodes on (1 - IoU) + class mismatch cost."""
    cfg = cfg or MatchConfig()
    out = NodeMatching({pred.root_id: gt.root_id}, {pred.root_id: 1.0})
    p_ids = [i for i, n in pred.nodes.items() if i != pred.root_id and n.box is not None]
    g_ids = [i for i, n in gt.nodes.items() if i != gt.root_id and n.box is not None]
    if not p_ids or not g_ids:
        return out

    def box_of(graph: ContactGraph, i: int) -> GravityBox:
        n = graph.nodes[i]
        b: GravityBox = (n.box_unrefined or n.box) if unrefined else n.box  # type: ignore[assignment]
        return GravityBox(b.center, np.maximum(b.size, cfg.min_extent), b.yaw)

    pb = [box_of(pred, i) for i in p_ids]
    gb = [box_of(gt, i) for i in g_ids]
    iou = iou_matrix(pb, gb)
    same = np.array([[pred.nodes[p].class_name == gt.nodes[g].class_name for g in g_ids] for p in p_ids])
    p_layout = np.array([pred.nodes[p].category == LAYOUT for p in p_ids])
    g_layout = np.array([gt.nodes[g].category == LAYOUT for g in g_ids])
    # Objects: IoU, or containment of the predicted box where the boxes intersect at all.
    contain = np.zeros_like(iou)
    for i, j in np.argwhere(iou > 0.0):
        contain[i, j] = _containment(pb[i], gb[j])
    ok = (iou >= cfg.min_iou) | (contain >= cfg.min_containment)
    if not cfg.allow_class_mismatch:
        ok &= same
    cost = 1.0 - iou + np.where(same, 0.0, cfg.class_mismatch_cost)
    # Layout: same class, the observed part inside the (grown) ground-truth element.
    ok &= ~(p_layout[:, None] | g_layout[None, :])
    grown = {j: _grown(gb[j], cfg.layout_margin) for j in np.flatnonzero(g_layout)}
    for i in np.flatnonzero(p_layout):
        for j in grown:
            if not same[i, j]:
                continue
            share = _containment(pb[i], grown[j])
            if share >= cfg.layout_min_containment:
                ok[i, j] = True
                cost[i, j] = 1.0 - share
    cost = np.where(ok, cost, FORBIDDEN)
    rows, cols = linear_sum_assignment(cost)
    for r, c in zip(rows, cols, strict=True):
        if cost[r, c] >= FORBIDDEN:
            continue
        out.pred_to_gt[p_ids[r]] = g_ids[c]
        out.iou[p_ids[r]] = float(iou[r, c])
        if not same[r, c]:
            out.substituted.add(p_ids[r])
    return out
