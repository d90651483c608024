"""Contact-graph metrics: node matching, graph edit distance (Table 5), oriented-box mAP (Table 4)."""

from __future__ import annotations

from typing import Any

from recon_core.contact_graph import ContactGraph
from scene_graph.config import MatchConfig
from scene_recon.evaluation.graph_metrics.box_map import BoxMapResult, average_precision, box_map
from scene_recon.evaluation.graph_metrics.ged import GedResult, constrained_tree_edit_distance, graph_edit_distance
from scene_recon.evaluation.graph_metrics.matching import NodeMatching, match_nodes


def restrict_to_seen(pred: ContactGraph, gt: ContactGraph, seen: set[int],
                     cfg: MatchConfig | None = None) -> tuple[ContactGraph, ContactGraph, list[str]]:
    """Both graphs without what the camera never saw: the ground truth keeps the ``seen`` nodes;
    predictions matched (against the full ground truth) to an unseen node leave as well, neither
    right nor wrong (as void segments in panoptic quality). Children of a dropped node hang off its
    nearest kept ancestor. Returns (pred, gt, names of the predictions left out)."""
    matching = match_nodes(pred, gt, cfg)
    void = {p for p, g in matching.pred_to_gt.items() if p != pred.root_id and g not in seen}
    pred_r = pred.restricted(set(pred.nodes) - void)
    gt_r = gt.restricted({g for g in gt.nodes if g in seen})
    return pred_r, gt_r, sorted(pred.nodes[p].name for p in void)


def evaluate_graph(pred: ContactGraph, gt: ContactGraph, cfg: MatchConfig | None = None,
                   seen: set[int] | None = None) -> dict[str, Any]:
    """GED (Table 5 accounting + exact TED) and box mAP of refined and unrefined boxes.

    With ``seen`` (ids of the ground-truth entities the recording saw), the same figures restricted
    to what the camera saw are added under ``"seen_only"`` (``restrict_to_seen``).
    """
    cfg = cfg or MatchConfig()
    ged = graph_edit_distance(pred, gt, cfg)
    refined = box_map(pred, gt, cfg.map_iou, unrefined=False)
    unrefined = box_map(pred, gt, cfg.map_iou, unrefined=True)
    out: dict[str, Any] = {"ged": ged.to_dict(), "box_map_refined": refined.to_dict(),
                           "box_map_unrefined": unrefined.to_dict()}
    if seen is not None:
        pred_r, gt_r, void = restrict_to_seen(pred, gt, seen, cfg)
        r = evaluate_graph(pred_r, gt_r, cfg)
        r["unseen_gt_nodes"] = [gt.nodes[g].name for g in sorted(gt.nodes) if g != gt.root_id and g not in seen]
        r["void_predictions"] = void
        out["seen_only"] = r
    return out


__all__ = [
    "BoxMapResult",
    "GedResult",
    "NodeMatching",
    "average_precision",
    "box_map",
    "constrained_tree_edit_distance",
    "evaluate_graph",
    "graph_edit_distance",
    "match_nodes",
    "restrict_to_seen",
]
