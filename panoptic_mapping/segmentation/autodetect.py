"""Which exporter made an ONNX model: its output convention, pre-processing and classes, read off the graph.

A model file alone must be enough (`scene-recon map BAG --segmenter onnx --model yolox_s.onnx`), so
`convention: auto` looks at what the exporters leave in the graph (`ModelSignature`):

* outputs named `boxes`, `labels`, `scores` (+ `masks`), or unnamed ones of those ranks and types
  (an int64 vector of labels): `torchvision` (Mask R-CNN / Faster R-CNN); `boxes`, `scores`,
  `classes`: the generic `detection` convention;
* a rank-3 and a rank-4 output: `yolo_seg` (YOLOv8-seg: (1, 4+nc+nm, N) and (1, nm, mh, mw));
* one rank-4 output (1, C, h, w): `semantic` logits;
* one rank-3 output (1, A, B): a YOLO family, told apart by the number of predictions N for the
  input size H x W. With cells = sum over strides 8/16/32 of (H/s)(W/s):
    - (1, 4+nc, N = cells): `yolov8` (ultralytics YOLOv8/YOLO11, channels first, no objectness);
    - (1, N = cells, 5+nc): `yolox` (one prediction per location, raw grid);
    - (1, N = 3 cells, 5+nc): `yolov5` (three anchors per location, decoded boxes);
  YOLOX and YOLOv5 both give 85 columns for COCO, so N is what separates them (8400 vs 25200 at
  640x640, 3549 vs 10647 at 416x416); P6 models (strides up to 64) are recognised the same way.
  Whether a YOLOX export decoded its boxes (`--decode_in_inference`) shows only in the values, so
  `yolox.decoded: auto` decides per call (see `decode_yolo_det.py`).

Shapes that the graph leaves symbolic (dynamic exports) are measured by one run on a blank image.
Everything the detection decides can be pinned in the model config (`convention`, output names,
`preprocess.*`, `class_names`, `yolox.*`); explicit values always win over detected ones.
"""

from __future__ import annotations

import ast
import copy
import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from panoptic_mapping.segmentation.class_map import CLASS_NAME_PRESETS, resolve_class_names
from panoptic_mapping.segmentation.letterbox import static_input_hw
from panoptic_mapping.segmentation.model_config import OnnxModelConfig
from panoptic_mapping.segmentation.types import SegmentationError

_log = logging.getLogger(__name__)

#: Input size used for models whose input is dynamic and whose metadata names no export size (all
#: conventions but torchvision, which is fed at the image's own size).
DEFAULT_YOLO_INPUT = (640, 640)
#: Stride sets of the YOLO heads: P5 (the usual) and P6 models.
_STRIDE_SETS: tuple[tuple[int, ...], ...] = ((8, 16, 32), (8, 16, 32, 64))
_YOLO_FAMILY = ("yolox", "yolov5", "yolov8", "yolo_seg")


@dataclass(frozen=True)
class TensorInfo:
    """One graph input or output: name, shape (None for a symbolic dimension) and element type."""

    name: str
    shape: tuple[int | None, ...]
    dtype: str = "float32"

    @property
    def rank(self) -> int:
        return len(self.shape)

    @property
    def static(self) -> bool:
        return all(d is not None for d in self.shape)

    def describe(self) -> str:
        dims = "x".join("?" if d is None else str(d) for d in self.shape)
        return f"{self.name!r} {dims} {self.dtype}"


@dataclass(frozen=True)
class ModelSignature:
    """What the graph says about a model's inputs, outputs and export metadata."""

    inputs: tuple[TensorInfo, ...]
    outputs: tuple[TensorInfo, ...]
    #: The model's custom metadata (ultralytics and YOLOv5 exports store `names`, `imgsz`, `task`).
    metadata: Mapping[str, str] = field(default_factory=dict)

    @classmethod
    def from_session(cls, session: Any) -> ModelSignature:
        """From an onnxruntime InferenceSession."""
        try:
            meta = dict(session.get_modelmeta().custom_metadata_map)
        except Exception:  # a missing or odd metadata block is no reason to refuse the model
            meta = {}
        return cls(tuple(_tensor_info(a) for a in session.get_inputs()),
                   tuple(_tensor_info(a) for a in session.get_outputs()), meta)

    def with_output_shapes(self, arrays: Sequence[np.ndarray]) -> ModelSignature:
        """The same signature with the outputs' shapes and types as measured on a run."""
        outs = tuple(TensorInfo(o.name, tuple(int(d) for d in a.shape), str(a.dtype))
                     for o, a in zip(self.outputs, arrays, strict=True))
        return ModelSignature(self.inputs, outs, self.metadata)

    def describe_outputs(self) -> str:
        return ", ".join(o.describe() for o in self.outputs) or "none"


def _tensor_info(arg: Any) -> TensorInfo:
    shape = tuple(d if isinstance(d, int) and not isinstance(d, bool) and d >= 0 else None
                  for d in (arg.shape or []))
    dtype = str(arg.type).removeprefix("tensor(").removesuffix(")")
    return TensorInfo(arg.name, shape, {"float": "float32", "double": "float64"}.get(dtype, dtype))


@dataclass
class ResolvedModel:
    """A model config with nothing left to `auto`, and how to feed the model."""

    config: OnnxModelConfig
    #: Network input (width, height); None: the image's own size (a dynamic torchvision input).
    input_size: tuple[int, int] | None
    #: The image input has a batch dimension ((1, 3, H, W)); torchvision exports take (3, H, W).
    batched: bool
    #: One line for logs: what was detected and why.
    description: str
    #: The convention was read off the graph (the config said `auto`).
    detected: bool = False


#: Runs the model once on a blank image of the given (width, height) and returns the measured signature.
Probe = Callable[[tuple[int, int]], ModelSignature]


def grid_cells(width: int, height: int, strides: Sequence[int]) -> int:
    """Grid locations of a YOLO head over the input (YOLOX's demo_postprocess: H // s by W // s)."""
    return sum((height // s) * (width // s) for s in strides)


def resolve_model(cfg: OnnxModelConfig, sig: ModelSignature, probe: Probe | None = None) -> ResolvedModel:
    """Fill every `auto` of `cfg` from the graph; explicit values are kept as they are.

    Raises SegmentationError naming what was seen and which key to set when the graph fits no
    convention.
    """
    if not sig.inputs:
        raise SegmentationError("the ONNX model has no input")
    out = copy.deepcopy(cfg)
    image = sig.inputs[0]
    batched = image.rank != 3
    fixed = _fixed_input_size(cfg, sig)
    reasons: list[str] = []
    convention = cfg.convention
    if convention == "auto":
        convention, sig = _detect(out, sig, fixed, probe, reasons)
    elif convention in _YOLO_FAMILY and not all(o.static for o in sig.outputs[:2]) and probe is not None:
        sig = probe(fixed or DEFAULT_YOLO_INPUT)
    out.convention = convention
    _bind_outputs(out, sig)
    if convention == "yolo_seg" and out.yolo.objectness is None:
        out.yolo.objectness = _yolo_seg_has_objectness(out, sig, fixed or DEFAULT_YOLO_INPUT)
    input_size = fixed
    if input_size is None and convention != "torchvision":  # torchvision resizes inside: feed the image as it is
        input_size = DEFAULT_YOLO_INPUT
        reasons.append("dynamic input: fed at 640x640 (set preprocess.input_size otherwise)")
        _log.info("ONNX model input %s is dynamic and its metadata names no size: feeding 640x640 (set "
                  "preprocess.input_size in a model config for another size)", image.describe())
    out.class_names = list(_class_names(out, sig, convention))
    out.preprocess = out.preprocess.resolved(convention)
    if input_size is not None:
        out.preprocess.input_size = [input_size[0], input_size[1]]
    desc = _describe(out, sig, input_size, reasons, detected=cfg.convention == "auto")
    return ResolvedModel(out, input_size, batched, desc, detected=cfg.convention == "auto")


# ---------------------------------------------------------------------------------------------- detect
def _detect(
    cfg: OnnxModelConfig, sig: ModelSignature, fixed: tuple[int, int] | None, probe: Probe | None,
    reasons: list[str],
) -> tuple[str, ModelSignature]:
    outs = sig.outputs
    names = {o.name.lower() for o in outs}
    if {"boxes", "labels", "scores"} <= names:
        reasons.append("outputs boxes/labels/scores")
        return "torchvision", sig
    if {"boxes", "scores", "classes"} <= names:
        reasons.append("outputs boxes/scores/classes")
        return "detection", sig
    if _torchvision_like(outs):
        reasons.append("outputs of torchvision's ranks and types (boxes Nx4, int64 labels, scores)")
        return "torchvision", sig
    ranks = [o.rank for o in outs]
    if len(outs) >= 2 and sorted(ranks[:2]) == [3, 4]:
        reasons.append("predictions and mask prototypes")
        return "yolo_seg", sig
    if len(outs) == 1 and ranks[0] == 4:
        reasons.append("one (1, C, h, w) output")
        return "semantic", sig
    if len(outs) == 1 and ranks[0] == 3:
        size = fixed or DEFAULT_YOLO_INPUT
        if not outs[0].static:
            if probe is None:
                raise SegmentationError(
                    f"the model's output {outs[0].describe()} has dynamic dimensions; set `convention` "
                    "(yolox | yolov5 | yolov8) in its model config"
                )
            sig = probe(size)
        convention = _yolo_family(cfg, sig, size, reasons)
        return convention, sig
    raise SegmentationError(
        f"cannot tell the output convention of this model from its outputs ({sig.describe_outputs()}); set "
        "`convention` in a model config (yolox | yolov5 | yolov8 | yolo_seg | torchvision | detection | semantic)"
    )


def _torchvision_like(outs: Sequence[TensorInfo]) -> bool:
    """torchvision's unbatched outputs by rank and type: (N, 4) boxes, an integer label vector, a float
    score vector, optionally (N, 1, H, W) masks (batched (1, N, ...) outputs are the `detection` kind)."""
    if len(outs) not in (3, 4):
        return False
    core = outs[:3]
    boxes = [o for o in core if o.rank == 2 and o.shape[1] in (4, None)]
    ints = [o for o in core if o.rank == 1 and o.dtype.startswith("int")]
    floats = [o for o in core if o.rank == 1 and o.dtype.startswith("float")]
    return len(boxes) == 1 and len(ints) == 1 and len(floats) == 1 and (len(outs) == 3 or outs[3].rank == 4)


def _unbatched_rank(o: TensorInfo) -> int:
    """Rank without a leading batch of 1 (some wrappers add one to torchvision's outputs); a (1, 4)
    tensor is one box."""
    if o.rank >= 2 and o.shape[0] == 1 and not (o.rank == 2 and o.shape[1] == 4):
        return o.rank - 1
    return o.rank


def _yolo_family(cfg: OnnxModelConfig, sig: ModelSignature, size: tuple[int, int], reasons: list[str]) -> str:
    """yolox, yolov5 or yolov8 from the (1, A, B) output and the input size."""
    shape = sig.outputs[0].shape
    a, b = int(shape[1] or 0), int(shape[2] or 0)
    w, h = size
    nc_hint = _class_count_hint(cfg, sig)
    stride_sets = [tuple(cfg.yolox.strides), *[s for s in _STRIDE_SETS if s != tuple(cfg.yolox.strides)]]
    for strides in stride_sets:
        cells = grid_cells(w, h, strides)
        where = f"{cells} cells of strides {'/'.join(map(str, strides))} at {w}x{h}"
        if b == cells and a < b:
            reasons.append(f"(1, 4+nc, N) with N = {where}")
            return "yolov8"
        if a == 3 * cells:
            reasons.append(f"(1, N, 5+nc) with N = 3 anchors x {where}")
            if tuple(cfg.yolox.strides) != strides:
                _log.info("YOLOv5 model with strides %s", strides)
            return "yolov5"
        if a == cells:
            if nc_hint is not None and b - 4 == nc_hint and b - 5 != nc_hint:
                reasons.append(f"(1, N, 4+nc) with N = {where} and {nc_hint} classes")
                cfg.yolo.predictions_layout = "channels_last"
                return "yolov8"
            reasons.append(f"(1, N, 5+nc) with N = {where}")
            cfg.yolox.strides = list(strides)
            return "yolox"
    # The prediction count matches no grid of this input size: guess from the layout, loudly.
    guess = "yolov8" if b > a else "yolov5"
    reasons.append(f"output {a}x{b} matches no YOLO grid at {w}x{h}: guessed {guess}")
    _log.warning("ONNX model output %s matches no YOLO grid at %dx%d; assuming %s (set `convention` in a model "
                 "config if that is wrong)", sig.outputs[0].describe(), w, h, guess)
    return guess


def _yolo_seg_has_objectness(cfg: OnnxModelConfig, sig: ModelSignature, size: tuple[int, int]) -> bool:
    """YOLOv5-seg: predictions over 3 anchors per location come with an objectness column."""
    pred = next((o for o in sig.outputs if o.name == cfg.yolo.predictions), None)
    if pred is None or pred.rank != 3 or not pred.static:
        return False
    n = max(int(pred.shape[1] or 0), int(pred.shape[2] or 0))
    return any(n == 3 * grid_cells(size[0], size[1], s) for s in _STRIDE_SETS)


# --------------------------------------------------------------------------------------------- outputs
def _bind_outputs(cfg: OnnxModelConfig, sig: ModelSignature) -> None:
    """Fill the output names the config leaves empty, from names, ranks and types in the graph."""
    outs = sig.outputs
    by_lower = {o.name.lower(): o.name for o in outs}
    conv = cfg.convention
    if conv == "yolo_seg":
        y = cfg.yolo
        y.predictions = y.predictions or _first(outs, lambda o: o.rank == 3, 0)
        y.prototypes = y.prototypes or _first(outs, lambda o: o.rank == 4, 1)
    elif conv in ("yolov5", "yolov8"):
        cfg.yolo.predictions = cfg.yolo.predictions or _first(outs, lambda o: o.rank == 3, 0)
    elif conv == "yolox":
        cfg.yolox.predictions = cfg.yolox.predictions or _first(outs, lambda o: o.rank == 3, 0)
    elif conv == "semantic":
        cfg.semantic.logits = cfg.semantic.logits or _first(outs, lambda o: o.rank == 4, 0)
    elif conv == "torchvision":
        d = cfg.detection
        d.boxes = d.boxes or by_lower.get("boxes") or _first(outs, lambda o: _unbatched_rank(o) == 2, 0)
        d.classes = d.classes or by_lower.get("labels") or _first(
            outs, lambda o: _unbatched_rank(o) == 1 and o.dtype.startswith("int"), 1)
        d.scores = d.scores or by_lower.get("scores") or _first(
            outs, lambda o: _unbatched_rank(o) == 1 and not o.dtype.startswith("int"), 2)
        if not d.masks:
            d.masks = by_lower.get("masks") or next((o.name for o in outs if o.rank == 4), "")
        d.box_format = "xyxy"
    elif conv == "detection":
        d = cfg.detection
        d.boxes = d.boxes or by_lower.get("boxes", "")
        d.scores = d.scores or by_lower.get("scores", "")
        d.classes = d.classes or by_lower.get("classes", "")
        if not d.masks and "masks" in by_lower:
            d.masks = by_lower["masks"]
    names = [o.name for o in outs]
    for key, value in _output_keys(cfg).items():
        if value and value not in names:
            raise SegmentationError(f"{key}: the model has no output {value!r}; its outputs: {names}")


def _output_keys(cfg: OnnxModelConfig) -> dict[str, str]:
    """The output-name keys the convention reads."""
    conv, y, d = cfg.convention, cfg.yolo, cfg.detection
    if conv == "yolo_seg":
        return {"yolo.predictions": y.predictions, "yolo.prototypes": y.prototypes}
    if conv in ("yolov5", "yolov8"):
        return {"yolo.predictions": y.predictions}
    if conv == "yolox":
        return {"yolox.predictions": cfg.yolox.predictions}
    if conv == "semantic":
        return {"semantic.logits": cfg.semantic.logits}
    return {"detection.boxes": d.boxes, "detection.scores": d.scores, "detection.classes": d.classes,
            "detection.masks": d.masks}


def _first(outs: Sequence[TensorInfo], pred: Callable[[TensorInfo], bool], position: int) -> str:
    """Name of the first output that fits, else of the output at `position` ("" when there is none)."""
    for o in outs:
        if pred(o):
            return o.name
    return outs[position].name if position < len(outs) else ""


# --------------------------------------------------------------------------------------------- classes
def _class_count_hint(cfg: OnnxModelConfig, sig: ModelSignature) -> int | None:
    if isinstance(cfg.class_names, list):
        return len(cfg.class_names)
    if cfg.class_names in CLASS_NAME_PRESETS:
        return len(CLASS_NAME_PRESETS[cfg.class_names])
    names = metadata_names(sig.metadata)
    return len(names) if names else None


def _metadata_literal(metadata: Mapping[str, str], key: str) -> Any:
    """A Python literal an exporter wrote into the model metadata (None when absent or unreadable)."""
    raw = metadata.get(key)
    if not raw:
        return None
    try:
        return ast.literal_eval(raw)
    except (ValueError, SyntaxError):
        return None


def metadata_names(metadata: Mapping[str, str]) -> tuple[str, ...] | None:
    """Class names an ultralytics or YOLOv5 export stores in its metadata (`names`: "{0: 'person', ...}")."""
    value = _metadata_literal(metadata, "names")
    if isinstance(value, dict) and value and all(isinstance(k, int) for k in value):
        if sorted(value) != list(range(len(value))):
            return None
        return tuple(str(value[i]) for i in range(len(value)))
    if isinstance(value, (list, tuple)) and value:
        return tuple(str(v) for v in value)
    return None


def _metadata_imgsz(metadata: Mapping[str, str]) -> tuple[int, int] | None:
    """(width, height) from ultralytics' `imgsz` metadata ([h, w])."""
    value = _metadata_literal(metadata, "imgsz")
    if isinstance(value, int):
        value = [value, value]
    if isinstance(value, (list, tuple)) and len(value) == 2 and all(isinstance(v, int) and v > 0 for v in value):
        return int(value[1]), int(value[0])
    return None


def _model_class_counts(cfg: OnnxModelConfig, sig: ModelSignature) -> list[int]:
    """How many classes the outputs may carry, most likely first ([] where the layout does not say).

    A YOLO prediction tensor (1, A, B) with an `auto` layout gives two readings (channels first or
    last); the smaller dimension is the per-detection one for any real model (N is in the thousands).
    """
    conv = cfg.convention
    outs = {o.name: o for o in sig.outputs}
    if conv in _YOLO_FAMILY:
        name = cfg.yolox.predictions if conv == "yolox" else cfg.yolo.predictions
        pred = outs.get(name)
        if pred is None or pred.rank != 3 or not pred.static:
            return []
        a, b = int(pred.shape[1] or 0), int(pred.shape[2] or 0)
        if conv == "yolox":
            return [b - 5]
        layout = cfg.yolo.predictions_layout
        widths = [a] if layout == "channels_first" else [b] if layout == "channels_last" else sorted({a, b})
        extra = 4 + int(cfg.yolo.has_objectness(conv))
        if conv == "yolo_seg":
            protos = outs.get(cfg.yolo.prototypes)
            if protos is None or protos.rank != 4 or protos.shape[1] is None:
                return []
            extra += int(protos.shape[1])
        return [k - extra for k in widths if k > extra]
    if conv == "semantic":
        logits = outs.get(cfg.semantic.logits)
        return [int(logits.shape[1])] if logits is not None and logits.rank == 4 and logits.shape[1] else []
    return []


def _class_names(cfg: OnnxModelConfig, sig: ModelSignature, convention: str) -> tuple[str, ...]:
    if cfg.class_names != "auto":
        return resolve_class_names(cfg.class_names)
    counts = _model_class_counts(cfg, sig)
    names = metadata_names(sig.metadata)
    if names and (not counts or len(names) in counts):
        return names
    if convention == "torchvision":
        return CLASS_NAME_PRESETS["coco91"]
    if convention == "detection" and not counts:
        return CLASS_NAME_PRESETS["coco80"]
    for nc in counts:
        for preset in ("coco80", "coco_panoptic"):
            if nc == len(CLASS_NAME_PRESETS[preset]):
                return CLASS_NAME_PRESETS[preset]
    raise SegmentationError(
        f"the model predicts {counts[0] if counts else 'an unknown number of'} classes and its metadata names "
        "none; list them in `class_names` in a model config (or a preset: coco80, coco91, coco_panoptic)"
    )


# ----------------------------------------------------------------------------------------------- input
def _fixed_input_size(cfg: OnnxModelConfig, sig: ModelSignature) -> tuple[int, int] | None:
    """(width, height): the configured size, else the static input shape, else the export metadata."""
    if cfg.preprocess.input_size:
        return int(cfg.preprocess.input_size[0]), int(cfg.preprocess.input_size[1])
    hw = static_input_hw(sig.inputs[0].shape, cfg.preprocess.layout)
    if hw is not None:
        return hw[1], hw[0]
    return _metadata_imgsz(sig.metadata)


_TITLES = {
    "yolox": "YOLOX", "yolov5": "YOLOv5", "yolov8": "YOLOv8/11 detection", "yolo_seg": "YOLO segmentation",
    "torchvision": "torchvision detection", "detection": "boxes/scores/classes detection",
    "semantic": "semantic logits",
}


def _describe(
    cfg: OnnxModelConfig, sig: ModelSignature, input_size: tuple[int, int] | None, reasons: list[str],
    detected: bool,
) -> str:
    p = cfg.preprocess
    size = f"{input_size[0]}x{input_size[1]}" if input_size else "the image's own size"
    value_range = "0-255" if p.scale == 1 else "0-1" if p.scale == 1.0 / 255.0 else f"x{p.scale:g}"
    how = f"detected ({'; '.join(reasons)})" if detected else "as configured"
    names = cfg.class_names
    classes = f"{len(names)} classes"
    for preset, values in CLASS_NAME_PRESETS.items():
        if tuple(names) == values:
            classes += f" ({preset})"
    pad = f"letterbox {p.pad_position} pad {p.pad_value}" if p.letterbox else "stretched"
    parts = [f"{_TITLES.get(cfg.convention, cfg.convention)} {how}", f"outputs {sig.describe_outputs()}",
             f"input {sig.inputs[0].name!r} {size} {p.color_order} {value_range}, {pad}", classes]
    if _masks_from_depth(cfg):
        parts.append("masks from depth")
    return "; ".join(parts)


def _masks_from_depth(cfg: OnnxModelConfig) -> bool:
    return cfg.convention in ("yolox", "yolov5", "yolov8", "detection") or (
        cfg.convention == "torchvision" and not cfg.detection.masks)
