"""Decode YOLO-family instance segmentation outputs (YOLOv8-seg; YOLOv5-seg with `objectness`).

predictions (1, 4 [+1] + nc + nm, N): box cx, cy, w, h in input pixels, [objectness,] class scores,
mask coefficients; prototypes (1, nm, mh, mw) covering the whole (letterboxed) input. Decoding:
score threshold, class-wise NMS, then per kept box mask = sigmoid(coefficients @ prototypes),
sampled straight at the source pixels inside the box (one affine warp per instance; no full-size
mask is ever built), thresholded.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from panoptic_mapping.segmentation.decode_common import DecodeContext, cxcywh_to_xyxy, squeeze_batch
from panoptic_mapping.segmentation.letterbox import box_pixels, logit
from panoptic_mapping.segmentation.nms import nms
from panoptic_mapping.segmentation.types import MaskCrop, SegmentationError, SegmentCandidate


def decode_yolo_seg(predictions: np.ndarray, prototypes: np.ndarray, ctx: DecodeContext) -> list[SegmentCandidate]:
    cfg, ycfg = ctx.config, ctx.config.yolo
    protos = squeeze_batch(prototypes, 3, "yolo prototypes").astype(np.float32, copy=False)
    nm, nc = protos.shape[0], len(ctx.class_map)
    objectness = ycfg.has_objectness(cfg.convention)
    width = 4 + int(objectness) + nc + nm
    cols = _columns(squeeze_batch(predictions, 2, "yolo predictions"), width, ycfg.predictions_layout, nc, nm)
    c0 = 4 + int(objectness)
    cls_scores = cols[c0 : c0 + nc]
    if objectness:
        cls_scores = cls_scores * cols[4:5]
    # max first (fast), argmax only for the few columns above the threshold (numpy's argmax over the
    # class axis of 8400 columns costs milliseconds).
    sel = np.flatnonzero(cls_scores.max(axis=0) >= cfg.score_threshold)
    cls_idx = np.zeros(cols.shape[1], np.int64)
    cls_idx[sel] = np.argmax(cls_scores[:, sel], axis=0)
    scores = np.zeros(cols.shape[1], cls_scores.dtype)
    scores[sel] = cls_scores[cls_idx[sel], sel]
    # The best class decides what the box is; a box whose best class is unmapped is dropped, not relabelled.
    sel = sel[ctx.class_map.kept[cls_idx[sel]]]
    if sel.size == 0:
        return []
    boxes = cxcywh_to_xyxy(cols[:4, sel].T.astype(np.float64))
    kept = nms(boxes, scores[sel], cfg.nms_iou, cls_idx[sel], cfg.max_detections)
    keep = sel[kept]
    boxes_src = ctx.letterbox.boxes_to_source(boxes[kept])
    pixels = box_pixels(boxes_src, *ctx.image_size)
    coeffs = np.ascontiguousarray(cols[c0 + nc :, keep].T, dtype=np.float32)
    out = []
    threshold = logit(ycfg.mask_threshold)
    for k, i in enumerate(keep):
        mask = _instance_mask(protos, coeffs[k], pixels[k], ctx, threshold)
        info = ctx.class_map[int(cls_idx[i])]
        if mask is None or info is None:
            continue
        out.append(SegmentCandidate(mask, info, float(scores[i])))
    return out


def _columns(pred: np.ndarray, width: int, layout: str, nc: int, nm: int) -> np.ndarray:
    """(width, N) contiguous predictions whatever the export's layout (per-row argmax is cheapest so)."""
    if layout == "auto":
        layout = "channels_first" if pred.shape[0] == width else "channels_last"
    cols = pred if layout == "channels_first" else pred.T
    if cols.shape[0] != width:
        raise SegmentationError(
            f"yolo predictions of shape {pred.shape} ({layout}) do not have 4 box values + {nc} class scores "
            f"+ {nm} mask coefficients per detection (= {width}); check class_names and yolo.objectness"
        )
    return np.ascontiguousarray(cols)


def _instance_mask(
    protos: np.ndarray, coeffs: np.ndarray, pix: np.ndarray, ctx: DecodeContext, threshold: float
) -> MaskCrop | None:
    """Mask of one instance inside its box's pixels [c0, c1) x [r0, r1) of the source image."""
    c0, r0, c1, r1 = (int(v) for v in pix)
    if c1 <= c0 or r1 <= r0:
        return None
    lb = ctx.letterbox
    nm, mh, mw = protos.shape
    # Source pixel centre c + 0.5 -> input u = (c + 0.5) * sx + pad_x -> prototype p = u * mw / W_in - 0.5.
    ax, ay = lb.scale_x * mw / lb.dst_w, lb.scale_y * mh / lb.dst_h
    bx = (0.5 * lb.scale_x + lb.pad_x) * mw / lb.dst_w - 0.5
    by = (0.5 * lb.scale_y + lb.pad_y) * mh / lb.dst_h - 0.5
    px0 = min(max(math.floor(ax * c0 + bx), 0), mw - 1)
    py0 = min(max(math.floor(ay * r0 + by), 0), mh - 1)
    px1 = min(max(math.floor(ax * (c1 - 1) + bx) + 2, px0 + 1), mw)
    py1 = min(max(math.floor(ay * (r1 - 1) + by) + 2, py0 + 1), mh)
    crop = protos[:, py0:py1, px0:px1]
    logits = (coeffs @ crop.reshape(nm, -1)).reshape(py1 - py0, px1 - px0).astype(np.float32)
    m = np.array([[ax, 0.0, ax * c0 + bx - px0], [0.0, ay, ay * r0 + by - py0]], np.float64)
    sampled = cv2.warpAffine(logits, m, (c1 - c0, r1 - r0), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                             borderMode=cv2.BORDER_REPLICATE)
    mask = sampled.reshape(r1 - r0, c1 - c0) > threshold
    if not mask.any():
        return None
    return MaskCrop(c0, r0, mask)
