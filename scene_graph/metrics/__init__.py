"""Contact-graph metrics: node matching, graph edit distance (Table 5), oriented-box mAP (Table 4)."""

from __future__ import annotations

from typing import Any

from ..config import MatchConfig
from ..graph import ContactGraph
from .box_map import BoxMapResult, average_precision, box_map
from .ged import GedResult, constrained_tree_edit_distance, graph_edit_distance
from .matching import NodeMatching, match_nodes


def evaluate_graph(pred: ContactGraph, gt: ContactGraph, cfg: MatchConfig | None = None) -> dict[str, Any]:
    """GED (Table 5 accounting + exact TED) and box mAP of refined and unrefined boxes."""
    cfg = cfg or MatchConfig()
    ged = graph_edit_distance(pred, gt, cfg)
    refined = box_map(pred, gt, cfg.map_iou, unrefined=False)
    unrefined = box_map(pred, gt, cfg.map_iou, unrefined=True)
    return {"ged": ged.to_dict(), "box_map_refined": refined.to_dict(), "box_map_unrefined": unrefined.to_dict()}


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
]
