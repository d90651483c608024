"""Decode box detections (boxes, scores, classes [, masks]): the `detection` and `torchvision`
conventions, and the shared tail of every detection-only decoder (NMS, back to image pixels, masks
from the model or cut out of the depth image)."""

from __future__ import annotations

import cv2
import numpy as np

from panoptic_mapping.segmentation.decode_common import DecodeContext, cxcywh_to_xyxy, squeeze_batch
from panoptic_mapping.segmentation.depth_mask import depth_mask_in_box
from panoptic_mapping.segmentation.letterbox import box_pixels
from panoptic_mapping.segmentation.nms import nms
from panoptic_mapping.segmentation.types import MaskCrop, SegmentationError, SegmentCandidate


def decode_detection(
    boxes: np.ndarray, scores: np.ndarray, classes: np.ndarray, ctx: DecodeContext, masks: np.ndarray | None = None
) -> list[SegmentCandidate]:
    """boxes (N, 4), scores (N,), class indices (N,) (float or int), each with an optional batch of 1;
    masks (N, 1, H, W) probabilities over the network input (torchvision Mask R-CNN) or None."""
    cfg, dcfg = ctx.config, ctx.config.detection
    b = squeeze_batch(boxes, 2, "detection boxes").astype(np.float64)
    s = squeeze_batch(scores, 1, "detection scores").astype(np.float64)
    c = np.rint(squeeze_batch(classes, 1, "detection classes")).astype(np.int64)
    if b.shape[1] != 4 or not b.shape[0] == s.shape[0] == c.shape[0]:
        raise SegmentationError(f"detection outputs disagree: boxes {b.shape}, scores {s.shape}, classes {c.shape}")
    m = _mask_stack(masks, b.shape[0]) if masks is not None else None
    if m is None:
        require_depth(ctx)
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
    return detections_to_candidates(xyxy, s[sel], c[sel], ctx, nms_needed=dcfg.nms,
                                    masks=m[sel] if m is not None else None)


def require_depth(ctx: DecodeContext) -> None:
    if ctx.depth is None:
        raise SegmentationError(
            "detection-only models cut instance masks out of the depth image; call segment(color, depth) "
            "(over ROS: set has_depth and fill depth in the SegmentImage request)"
        )


def detections_to_candidates(
    xyxy: np.ndarray,
    scores: np.ndarray,
    classes: np.ndarray,
    ctx: DecodeContext,
    nms_needed: bool = True,
    masks: np.ndarray | None = None,
) -> list[SegmentCandidate]:
    """Detections above the threshold with a kept class -> candidates.

    xyxy: (K, 4) boxes in network input pixels; scores (K,); classes (K,) model class indices;
    masks: (K, H_in, W_in) probabilities over the input, or None to cut masks out of the depth image.
    """
    cfg = ctx.config
    if masks is None:
        require_depth(ctx)
    if nms_needed:
        kept = nms(xyxy, scores, cfg.nms_iou, classes, cfg.max_detections)
    else:
        kept = np.argsort(-np.asarray(scores), kind="stable")[: cfg.max_detections]
    pixels = box_pixels(ctx.letterbox.boxes_to_source(xyxy[kept]), *ctx.image_size)
    out = []
    for k, i in enumerate(kept):
        info = ctx.class_map[int(classes[i])]
        if info is None:
            continue
        if masks is not None:
            mask = _model_mask(masks[i], pixels[k], ctx)
        else:
            assert ctx.depth is not None
            mask = depth_mask_in_box(ctx.depth, pixels[k], cfg.detection.depth_mask)
        if mask is not None:
            out.append(SegmentCandidate(mask, info, float(scores[i])))
    return out


def _mask_stack(masks: np.ndarray, n: int) -> np.ndarray:
    """(N, 1, H, W), (N, H, W) or either with a batch of 1 -> (N, H, W)."""
    m = np.asarray(masks)
    while m.ndim > 4 and m.shape[0] == 1:
        m = m[0]
    if m.ndim == 4 and m.shape[0] == 1 and m.shape[1] == n and n != 1:  # (1, N, H, W)
        m = m[0]
    elif m.ndim == 4:
        if m.shape[1] != 1:
            raise SegmentationError(f"detection masks: expected (N, 1, H, W), got shape {masks.shape}")
        m = m[:, 0]
    if m.ndim != 3 or m.shape[0] != n:
        raise SegmentationError(f"detection masks of shape {masks.shape} do not fit {n} boxes")
    return m


def _model_mask(prob: np.ndarray, pix: np.ndarray, ctx: DecodeContext) -> MaskCrop | None:
    """A model's mask over the network input, sampled at the source pixels of its box and thresholded."""
    c0, r0, c1, r1 = (int(v) for v in pix)
    if c1 <= c0 or r1 <= r0:
        return None
    lb = ctx.letterbox
    if prob.shape != (lb.dst_h, lb.dst_w):
        raise SegmentationError(
            f"detection masks of {prob.shape[1]}x{prob.shape[0]} do not cover the {lb.dst_w}x{lb.dst_h} input"
        )
    # Source pixel centre c + 0.5 -> input coordinate u = (c + 0.5) * sx + pad_x -> index u - 0.5.
    m = np.array([[lb.scale_x, 0.0, (c0 + 0.5) * lb.scale_x + lb.pad_x - 0.5],
                  [0.0, lb.scale_y, (r0 + 0.5) * lb.scale_y + lb.pad_y - 0.5]], np.float64)
    sampled = cv2.warpAffine(np.ascontiguousarray(prob, np.float32), m, (c1 - c0, r1 - r0),
                             flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT)
    mask = sampled.reshape(r1 - r0, c1 - c0) > ctx.config.detection.mask_threshold
    if not mask.any():
        return None
    return MaskCrop(c0, r0, mask)


def _to_xyxy(b: np.ndarray, box_format: str) -> np.ndarray:
    if box_format == "xyxy":
        return b.copy()
    if box_format == "cxcywh":
        return cxcywh_to_xyxy(b)
    return np.concatenate([b[:, :2], b[:, :2] + b[:, 2:4]], axis=1)  # xywh
