"""Decode YOLO detection outputs (`yolox`, `yolov5`, `yolov8`); masks come from the depth image.

* `yolox`  (1, N, 5 + nc), one row per grid location of strides 8/16/32 in order (row-major within a
  level: x fastest), as Megvii's `tools/export_onnx.py` writes it. Raw grid predictions are decoded as
  `yolox/utils/demo_utils.py: demo_postprocess` does: cx, cy = (p + cell) * stride,
  w, h = exp(p) * stride. Objectness and class scores are probabilities (the head applies the
  sigmoid in inference; `yolox.apply_sigmoid` for heads exported without it); score = obj * cls.
* `yolov5` (1, N, 5 + nc): cx, cy, w, h in input pixels, objectness, class probabilities
  (`models/yolo.py` Detect in export mode); score = obj * cls.
* `yolov8` (1, 4 + nc, N): cx, cy, w, h in input pixels, class probabilities, no objectness
  (ultralytics `nn/modules/head.py` Detect).

Only rows that can pass the threshold are touched: with objectness, score = obj * cls <= obj, so the
rows are first filtered on objectness alone; without, on the best class score.
"""

from __future__ import annotations

import functools

import numpy as np

from panoptic_mapping.segmentation.decode_common import DecodeContext, cxcywh_to_xyxy, squeeze_batch
from panoptic_mapping.segmentation.decode_detection import detections_to_candidates, require_depth
from panoptic_mapping.segmentation.types import SegmentationError, SegmentCandidate

#: A raw YOLOX box value (a cell offset or a log-size) beyond this is a pixel coordinate: the
#: export decoded its boxes (`--decode_in_inference`). Raw offsets stay within about [-1, 2] and
#: log-sizes below log(640 / 8) = 4.4; a decoded box with all four values below 16 px would be a
#: speck in the image's top-left corner.
DECODED_BOX_LIMIT = 16.0


def decode_yolo_detection(predictions: np.ndarray, ctx: DecodeContext) -> list[SegmentCandidate]:
    """Decode one YOLO detection output per `ctx.config.convention` (yolox | yolov5 | yolov8)."""
    cfg = ctx.config
    conv = cfg.convention
    require_depth(ctx)
    pred = squeeze_batch(predictions, 2, f"{conv} predictions")
    nc = len(ctx.class_map)
    objectness = True if conv == "yolox" else cfg.yolo.has_objectness(conv)
    width = 4 + int(objectness) + nc
    rows = _rows(pred, width, "channels_last" if conv == "yolox" else cfg.yolo.predictions_layout, conv, nc,
                 objectness)
    thr = cfg.score_threshold
    c0 = 4 + int(objectness)
    sigmoid = conv == "yolox" and cfg.yolox.apply_sigmoid
    if objectness:
        obj = rows[:, 4].astype(np.float64)
        if sigmoid:
            obj = _sigmoid(obj)
        elif obj.size and (obj.max() > 1.0 + 1e-4 or obj.min() < -1e-4):
            ctx.warn_once(f"{conv}-logits", f"{conv} objectness values outside [0, 1] (seen {obj.min():.3g} .. "
                          f"{obj.max():.3g}): the export left them as logits; set yolox.apply_sigmoid: true"
                          if conv == "yolox" else f"{conv} objectness values outside [0, 1]: not a {conv} export?")
        sel = np.flatnonzero(obj >= thr)
        cls = rows[sel, c0:c0 + nc].astype(np.float64)
        if sigmoid:
            cls = _sigmoid(cls)
        cls *= obj[sel, None]
    else:
        best = rows[:, c0:c0 + nc].max(axis=1)
        sel = np.flatnonzero(best >= thr)
        cls = rows[sel, c0:c0 + nc].astype(np.float64)
    if sel.size == 0:
        return []
    idx = np.argmax(cls, axis=1)
    score = cls[np.arange(sel.size), idx]
    # The best class decides what the box is; a box whose best class is unmapped is dropped, not relabelled.
    ok = (score >= thr) & ctx.class_map.kept[idx]
    sel, idx, score = sel[ok], idx[ok], score[ok]
    if sel.size == 0:
        return []
    boxes = rows[sel, :4].astype(np.float64)
    if conv == "yolox" and not _yolox_decoded(boxes, ctx):
        boxes = _yolox_grid_decode(boxes, sel, rows.shape[0], ctx)
    return detections_to_candidates(cxcywh_to_xyxy(boxes), score, idx, ctx, nms_needed=True)


def _rows(pred: np.ndarray, width: int, layout: str, conv: str, nc: int, objectness: bool) -> np.ndarray:
    """(N, width) view of the predictions whatever the export's layout (no copy)."""
    if layout == "auto":
        layout = "channels_first" if pred.shape[0] == width and pred.shape[1] != width else "channels_last"
    rows = pred.T if layout == "channels_first" else pred
    if rows.shape[1] != width:
        obj = " + objectness" if objectness else ""
        raise SegmentationError(
            f"{conv} predictions of shape {pred.shape} ({layout}) do not have 4 box values{obj} + {nc} class scores "
            f"per detection (= {width}); check class_names (and the convention: yolox | yolov5 | yolov8)"
        )
    return rows


def _yolox_decoded(boxes: np.ndarray, ctx: DecodeContext) -> bool:
    setting = ctx.config.yolox.decoded
    if setting != "auto":
        return setting == "true"
    decoded = bool(np.abs(boxes).max() > DECODED_BOX_LIMIT)
    if decoded:
        ctx.warn_once("yolox-decoded", "YOLOX output carries decoded boxes (exported with --decode_in_inference); "
                                       "set yolox.decoded: true to skip this check")
    return decoded


def _yolox_grid_decode(p: np.ndarray, rows: np.ndarray, n: int, ctx: DecodeContext) -> np.ndarray:
    """Raw predictions of rows `rows` -> cx, cy, w, h in input pixels (demo_postprocess)."""
    lb = ctx.letterbox
    cells, strides = _yolox_grid(lb.dst_w, lb.dst_h, tuple(ctx.config.yolox.strides))
    if cells.shape[0] != n:
        raise SegmentationError(
            f"YOLOX output has {n} predictions but a {lb.dst_w}x{lb.dst_h} input has {cells.shape[0]} grid cells "
            f"over strides {ctx.config.yolox.strides}: set preprocess.input_size to the export size (or yolox.strides)"
        )
    s = strides[rows, None]
    out = np.empty_like(p)
    out[:, :2] = (p[:, :2] + cells[rows]) * s
    with np.errstate(over="ignore"):
        out[:, 2:4] = np.exp(p[:, 2:4]) * s
    return out


@functools.lru_cache(maxsize=8)
def _yolox_grid(width: int, height: int, strides: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Cell (x, y) and stride of every prediction row: levels in stride order, rows y-major, x fastest."""
    cells, per_row = [], []
    for s in strides:
        hs, ws = height // s, width // s
        xv, yv = np.meshgrid(np.arange(ws), np.arange(hs))
        cells.append(np.stack([xv.ravel(), yv.ravel()], axis=1))
        per_row.append(np.full(hs * ws, s))
    grid = np.concatenate(cells).astype(np.float64)
    stride = np.concatenate(per_row).astype(np.float64)
    grid.setflags(write=False)
    stride.setflags(write=False)
    return grid, stride


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-np.clip(x, -60.0, 60.0)))
