"""Decode per-pixel semantic logits (1, C, h, w) into panoptic candidates.

argmax per pixel (on the logit grid, cropped to the letterbox content, then resized to the image
with nearest neighbour: cheaper than resizing C channels and exact when the grid matches the
image), model classes -> project classes, then stuff = one segment per class and things = one
instance per connected component. A segment's score is its mean top-class probability.
"""

from __future__ import annotations

import cv2
import numpy as np

from .decode_common import DecodeContext, squeeze_batch
from .types import MaskCrop, SegmentationError, SegmentCandidate

_CONNECTIVITY = 8


def decode_semantic(logits: np.ndarray, ctx: DecodeContext) -> list[SegmentCandidate]:
    cfg = ctx.config
    x = squeeze_batch(logits, 3, "semantic logits")
    nc = len(ctx.class_map)
    if x.shape[0] != nc:
        raise SegmentationError(f"semantic logits have {x.shape[0]} channels but the model config lists {nc} classes")
    x0, y0, x1, y1 = ctx.letterbox.content_in_grid(x.shape[2], x.shape[1])
    x = x[:, y0:y1, x0:x1].astype(np.float32, copy=False)
    cls = np.argmax(x, axis=0)
    top = np.take_along_axis(x, cls[None], axis=0)[0]
    # softmax probability of the top class: 1 / sum(exp(l - l_max)), unless the model outputs probabilities
    prob = top if cfg.semantic.probabilities else 1.0 / np.exp(x - top[None]).sum(axis=0)
    w, h = ctx.image_size
    if cls.shape != (h, w):
        cls = cv2.resize(cls.astype(np.uint16), (w, h), interpolation=cv2.INTER_NEAREST).astype(np.int64)
        prob = cv2.resize(prob.astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST)
    # Several model classes may map to one project class (wall-brick, wall-tile -> wall): work on project ids.
    project = ctx.class_map.project_ids[cls]
    present = np.flatnonzero(np.bincount(project.ravel() + 1)[1:])  # counts[1 + id] -> project ids present
    out: list[SegmentCandidate] = []
    for pid in present:
        info = ctx.class_map.project_class(int(pid))
        mask = project == pid
        if not info.is_thing:
            crop = MaskCrop.from_full(mask)
            score = float(prob[mask].mean())
            if crop is not None and score >= cfg.score_threshold:
                out.append(SegmentCandidate(crop, info, score))
            continue
        n, comp, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=_CONNECTIVITY)
        sums = np.bincount(comp.ravel(), weights=prob.ravel(), minlength=n)
        for k in range(1, n):
            cx, cy, cw, ch, area = (int(v) for v in stats[k])
            score = float(sums[k] / area)
            if area < cfg.semantic.min_instance_area_px or score < cfg.score_threshold:
                continue
            out.append(SegmentCandidate(MaskCrop(cx, cy, comp[cy : cy + ch, cx : cx + cw] == k), info, score))
    return out
