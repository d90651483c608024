"""Decode detection-only outputs (boxes, scores, classes); masks come from the depth image."""

from __future__ import annotations

import numpy as np

from panoptic_mapping.segmentation.decode_common import DecodeContext, cxcywh_to_xyxy, squeeze_batch
from panoptic_mapping.segmentation.depth_mask import depth_mask_in_box
from panoptic_mapping.segmentation.letterbox import box_pixels
from panoptic_mapping.segmentation.nms import nms
from panoptic_mapping.segmentation.types import SegmentationError, SegmentCandidate


def decode_detection(
    boxes: np.ndarray, scores: np.ndarray, classes: np.ndarray, ctx: DecodeContext
) -> list[SegmentCandidate]:
    cfg, dcfg = ctx.config, ctx.config.detection
    if ctx.depth is None:
        raise SegmentationError(
            "detection-only models cut instance masks out of the depth image; call segment(color, depth) "
            "(over ROS: set has_depth and fill depth in the SegmentImage request)"
        )
    b = squeeze_batch(boxes, 2, "detection boxes").astype(np.float64)
    s = squeeze_batch(scores, 1, "detection scores").astype(np.float64)
    c = np.rint(squeeze_batch(classes, 1, "detection classes")).astype(np.int64)
    if b.shape[1] != 4 or not b.shape[0] == s.shape[0] == c.shape[0]:
        raise SegmentationError(f"detection outputs disagree: boxes {b.shape}, scores {s.shape}, classes {c.shape}")
    nc = len(ctx.class_map)
    if c.size and (c.min() < 0 or c.max() >= nc):
        bad = sorted({int(v) for v in c[(c < 0) | (c >= nc)]})
        raise SegmentationError(
            f"detection class indices {bad[:10]} are outside the model's {nc} class names; "
            "list the model's classes in `class_names` (use placeholders for unused ids)"
        )
    sel = np.flatnonzero((s >= cfg.score_threshold) & ctx.class_map.kept[c])
    if sel.size == 0:
        return []
    xyxy = _to_xyxy(b[sel], dcfg.box_format)
    if dcfg.normalized:
        xyxy *= np.array([ctx.letterbox.dst_w, ctx.letterbox.dst_h] * 2, np.float64)
    if dcfg.nms:
        kept = nms(xyxy, s[sel], cfg.nms_iou, c[sel], cfg.max_detections)
    else:
        kept = np.argsort(-s[sel], kind="stable")[: cfg.max_detections]
    pixels = box_pixels(ctx.letterbox.boxes_to_source(xyxy[kept]), *ctx.image_size)
    out = []
    for k, i in enumerate(sel[kept]):
        mask = depth_mask_in_box(ctx.depth, pixels[k], dcfg.depth_mask)
        info = ctx.class_map[int(c[i])]
        if mask is not None and info is not None:
            out.append(SegmentCandidate(mask, info, float(s[i])))
    return out


def _to_xyxy(b: np.ndarray, box_format: str) -> np.ndarray:
    if box_format == "xyxy":
        return b.copy()
    if box_format == "cxcywh":
        return cxcywh_to_xyxy(b)
    return np.concatenate([b[:, :2], b[:, :2] + b[:, 2:4]], axis=1)  # xywh
