"""Decode per-pixel semantic logits (1, C, h, w) into panoptic candidates.

Everything up to the segment map happens on the logit grid (cropped to the letterbox content),
which is typically 1/4 of the input: argmax, top-class probability, model -> project classes, and
the segments themselves (stuff: one per class; things: one instance per 8-connected component).
Only the finished segment map is resized to the image, with nearest neighbour: cheaper than
resizing C channels or labelling components at full resolution, and exact when the grid matches
the image. A segment's score is its mean top-class probability.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from panoptic_mapping.segmentation.decode_common import DecodeContext, squeeze_batch
from panoptic_mapping.segmentation.types import MaskCrop, SegmentationError, SegmentCandidate

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
    # Several model classes may map to one project class (wall-brick, wall-tile -> wall): work on project ids.
    project = ctx.class_map.project_ids[cls]
    segments, infos = _segment_map(project, ctx)
    w, h = ctx.image_size
    if segments.shape != (h, w):
        segments = cv2.resize(segments, (w, h), interpolation=cv2.INTER_NEAREST)
        prob = cv2.resize(prob.astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST)
    n = len(infos)
    flat = segments.ravel()
    areas = np.bincount(flat, minlength=n + 1)
    sums = np.bincount(flat, weights=prob.ravel(), minlength=n + 1)
    out: list[SegmentCandidate] = []
    for k, sl in enumerate(ndimage.find_objects(segments, max_label=n), start=1):
        info = infos[k - 1]
        if sl is None or (info.is_thing and areas[k] < cfg.semantic.min_instance_area_px):
            continue
        score = float(sums[k] / areas[k])
        if score >= cfg.score_threshold:
            out.append(SegmentCandidate(MaskCrop(sl[1].start, sl[0].start, segments[sl] == k), info, score))
    return out


def _segment_map(project: np.ndarray, ctx: DecodeContext) -> tuple[np.ndarray, list]:
    """int32 map of segment numbers (0 = dropped class) on the grid, and each segment's class."""
    segments = np.zeros(project.shape, np.int32)
    infos = []
    present = np.flatnonzero(np.bincount(project.ravel() + 1)[1:])  # counts[1 + id] -> project ids present
    for pid in present:
        info = ctx.class_map.project_class(int(pid))
        mask = project == pid
        if not info.is_thing:
            infos.append(info)
            segments[mask] = len(infos)
            continue
        n, comp = cv2.connectedComponents(mask.astype(np.uint8), connectivity=_CONNECTIVITY)
        segments[mask] = comp[mask] + len(infos)
        infos.extend([info] * (n - 1))
    return segments, infos
