"""Oriented (gravity-aligned) 3D box mAP@0.5 over thing classes (paper Sec. 5.2, Table 4).

Per class: predictions ranked by confidence are true positives when their exact yaw-box IoU
with a not yet taken ground-truth box of the class reaches the threshold (greedy, as in VOC/COCO);
AP is the area under the interpolated precision-recall curve (all points); mAP averages the
classes present in the ground truth. Layout ("stuff") nodes are not evaluated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recon_core.contact_graph import SCENE, ContactGraph
from recon_core.geometry.box import GravityBox
from scene_graph.classify import LAYOUT


@dataclass
class BoxMapResult:
    mean_ap: float
    per_class: dict[str, float]
    iou_threshold: float

    def to_dict(self) -> dict:
        return {"mAP": self.mean_ap, "per_class": self.per_class, "iou_threshold": self.iou_threshold}


def average_precision(tp: np.ndarray, num_gt: int) -> float:
    """All-point interpolated AP of a ranked list of true/false positives."""
    if num_gt == 0:
        return 0.0
    if len(tp) == 0:
        return 0.0
    tp = np.asarray(tp, dtype=np.float64)
    ctp = np.cumsum(tp)
    cfp = np.cumsum(1.0 - tp)
    recall = ctp / num_gt
    precision = ctp / np.maximum(ctp + cfp, 1e-12)
    r = np.r_[0.0, recall, 1.0]
    p = np.r_[0.0, precision, 0.0]
    p = np.maximum.accumulate(p[::-1])[::-1]
    steps = np.flatnonzero(r[1:] != r[:-1])
    return float(np.sum((r[steps + 1] - r[steps]) * p[steps + 1]))


def _things(graph: ContactGraph, unrefined: bool) -> list[tuple[str, float, GravityBox]]:
    out = []
    for n in graph.nodes.values():
        if n.category in (LAYOUT, SCENE) or n.box is None:
            continue
        box = (n.box_unrefined or n.box) if unrefined else n.box
        out.append((n.class_name, n.confidence, box))
    return out


def box_map(pred: ContactGraph, gt: ContactGraph, iou_threshold: float = 0.5, unrefined: bool = False) -> BoxMapResult:
    """mAP of the predicted node boxes (refined, or ``unrefined``) against the ground-truth boxes."""
    preds = _things(pred, unrefined)
    gts = _things(gt, False)
    classes = sorted({c for c, _, _ in gts})
    per_class: dict[str, float] = {}
    for cls in classes:
        g = [b for c, _, b in gts if c == cls]
        p = sorted([(s, b) for c, s, b in preds if c == cls], key=lambda t: -t[0])
        taken = np.zeros(len(g), dtype=bool)
        tp = np.zeros(len(p))
        for k, (_, box) in enumerate(p):
            ious = np.array([box.iou(x) for x in g])
            ious[taken] = -1.0
            if len(ious) and ious.max() >= iou_threshold:
                j = int(np.argmax(ious))
                taken[j] = True
                tp[k] = 1.0
        per_class[cls] = average_precision(tp, len(g))
    mean = float(np.mean(list(per_class.values()))) if per_class else 0.0
    return BoxMapResult(mean, per_class, iou_threshold)
