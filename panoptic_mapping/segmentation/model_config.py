"""How one exported ONNX model is fed and decoded; one YAML file per model (`config/segmentation/`).

The project ships no weights (none can be downloaded here); users export their own model. With
`convention: auto` (the default) the output convention, the pre-processing and the class list are
read off the ONNX graph (`autodetect.py`), so a model file alone is enough; a YAML file like
`config/segmentation/yolox.yaml` only pins what the detection gets wrong. Conventions
(`convention`), named after the exporters whose layout they read:

* `yolox`       Megvii YOLOX `tools/export_onnx.py`: (1, N, 5+nc) raw grid predictions over strides
                8/16/32 (N = grid cells, one per location), BGR 0-255 input, top-left letterbox;
* `yolov5`      ultralytics/yolov5 `export.py`: (1, N, 5+nc) decoded cx, cy, w, h (input pixels),
                objectness, class scores (N = 3 anchors x grid cells), RGB 0-1, centred letterbox;
* `yolov8`      ultralytics (YOLOv8/YOLO11) detection: (1, 4+nc, N), no objectness;
* `yolo_seg`    YOLOv8-seg style instance segmentation: output0 (1, 4+nc+nm, N) boxes cx,cy,w,h +
                class scores + mask coefficients, output1 (1, nm, mh, mw) mask prototypes;
* `torchvision` torchvision Mask R-CNN / Faster R-CNN exports: boxes (N, 4) xyxy input pixels, labels
                (N,) COCO category ids (91 with background 0), scores (N,), optional masks (N, 1, H, W);
* `detection`   generic boxes/scores/classes ((1, N, 4), (1, N), (1, N));
* `semantic`    per-pixel logits (1, C, h, w): argmax, stuff per class, things by connected components.

Detection-only conventions (`yolox`, `yolov5`, `yolov8`, `torchvision` without masks, `detection`)
cut their instance masks out of the depth image (`detection.depth_mask`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from panoptic_mapping.segmentation.config import PaintConfig, resolve_path
from recon_core.config import ConfigError, Settings, load_config, setting

#: `auto` is resolved from the ONNX graph when the model is loaded; the others are fixed layouts.
CONVENTIONS: tuple[str, ...] = (
    "auto", "yolox", "yolov5", "yolov8", "yolo_seg", "torchvision", "detection", "semantic",
)
#: Conventions whose instance masks come from the depth image (torchvision only without a masks output).
DETECTION_ONLY: tuple[str, ...] = ("yolox", "yolov5", "yolov8", "detection")
COLOR_ORDERS: tuple[str, ...] = ("auto", "RGB", "BGR")
PAD_POSITIONS: tuple[str, ...] = ("auto", "center", "top_left")
LAYOUTS: tuple[str, ...] = ("NCHW", "NHWC")
BOX_FORMATS: tuple[str, ...] = ("xyxy", "xywh", "cxcywh")
#: Default detection threshold of real detectors (typical values 0.35-0.5; the synthetic world's
#: oracle keeps the paper's 0.7, `config.PAPER_SCORE_THRESHOLD`).
DEFAULT_SCORE_THRESHOLD = 0.4
#: ImageNet normalisation (semantic models trained with torchvision/mmseg-style pipelines).
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


@dataclass(frozen=True)
class PreprocessPreset:
    """What an exporter's own demo does to an image before the network (see the module docstring)."""

    color_order: str
    scale: float
    mean: tuple[float, float, float]
    std: tuple[float, float, float]
    pad_position: str
    pad_value: int


_YOLO_PRESET = PreprocessPreset("RGB", 1.0 / 255.0, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), "center", 114)
#: Pre-processing per convention; `auto` keys of `PreprocessConfig` take these values. `None`
#: (a config used before its convention is known) takes the YOLOv5/v8 values.
PREPROCESS_PRESETS: dict[str | None, PreprocessPreset] = {
    # YOLOX: cv2 image as read (BGR), 0-255, resized image at the top-left of a 114-grey canvas
    # (yolox/data/data_augment.py `preproc`).
    "yolox": PreprocessPreset("BGR", 1.0, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), "top_left", 114),
    # ultralytics LetterBox(center=True), 114 grey, RGB / 255.
    "yolov5": _YOLO_PRESET,
    "yolov8": _YOLO_PRESET,
    "yolo_seg": _YOLO_PRESET,
    "detection": _YOLO_PRESET,
    # torchvision detection models normalise and resize inside the graph: RGB in [0, 1]; a static
    # input is filled from the top-left with zeros like torchvision's own batching does.
    "torchvision": PreprocessPreset("RGB", 1.0 / 255.0, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), "top_left", 0),
    "semantic": PreprocessPreset("RGB", 1.0 / 255.0, IMAGENET_MEAN, IMAGENET_STD, "center", 0),
    None: _YOLO_PRESET,
}


@dataclass
class PreprocessConfig(Settings):
    """Image -> input tensor. `auto`/null values take the convention's exporter defaults
    (`PREPROCESS_PRESETS`); set them only for a model trained with another pipeline."""

    #: Network input [width, height]; [] takes the model's static input shape, else the export size
    #: in its metadata, else 640x640 (torchvision: the image's own size, the model resizes inside).
    input_size: list[int] = field(default_factory=list)
    #: True: scale to fit keeping the aspect ratio and pad (YOLO letterbox); False: stretch.
    letterbox: bool = True
    #: Where the padding goes: `center` (ultralytics) or `top_left` (image at the top-left corner,
    #: padding right and bottom: YOLOX, torchvision); `auto`: the convention's.
    pad_position: str = setting("auto", choices=PAD_POSITIONS)
    #: Grey level of the letterbox padding (0-255, before normalisation; YOLO uses 114); null: auto.
    pad_value: int | None = None
    #: Channel order the model expects (images arrive as RGB); `auto`: the convention's.
    color_order: str = setting("auto", choices=COLOR_ORDERS)
    #: x = (pixel * scale - mean) / std, per channel in the model's channel order; null: auto.
    scale: float | None = None
    mean: list[float] | None = None
    std: list[float] | None = None
    #: Tensor layout of the image input.
    layout: str = setting("NCHW", choices=LAYOUTS)

    def __post_init__(self) -> None:
        """Ranges are checked by `Settings`; these conditions relate several values of a field."""
        super().__post_init__()
        if self.input_size and (len(self.input_size) != 2 or min(self.input_size) <= 0):
            raise ConfigError(f"preprocess.input_size must be [width, height] > 0 or [], got {self.input_size}")
        if self.pad_value is not None and not 0 <= self.pad_value <= 255:
            raise ConfigError(
                f"preprocess.pad_value must be in [0, 255] (or null: the convention's), got {self.pad_value}")
        if self.mean is not None and len(self.mean) != 3:
            raise ConfigError("preprocess.mean needs 3 values (or null: the convention's)")
        if self.std is not None and (len(self.std) != 3 or min(abs(s) for s in self.std) == 0):
            raise ConfigError("preprocess.std needs 3 non-zero values (or null: the convention's)")

    def resolved(self, convention: str | None) -> PreprocessConfig:
        """A copy with every `auto`/null value replaced by the convention's exporter default."""
        p = PREPROCESS_PRESETS.get(convention, PREPROCESS_PRESETS[None])
        return PreprocessConfig(
            input_size=list(self.input_size),
            letterbox=self.letterbox,
            pad_position=p.pad_position if self.pad_position == "auto" else self.pad_position,
            pad_value=p.pad_value if self.pad_value is None else self.pad_value,
            color_order=p.color_order if self.color_order == "auto" else self.color_order,
            scale=p.scale if self.scale is None else self.scale,
            mean=list(p.mean if self.mean is None else self.mean),
            std=list(p.std if self.std is None else self.std),
            layout=self.layout,
        )


@dataclass
class YoloSegConfig(Settings):
    """Outputs of the ultralytics-style YOLO models: `yolo_seg`, `yolov8` and `yolov5`."""

    #: Output tensor names; "" takes them from the graph (the rank-3 output is the predictions,
    #: the rank-4 one the prototypes), else the outputs in order.
    predictions: str = ""
    prototypes: str = ""
    #: Layout of the predictions: `channels_first` (1, 4+nc+nm, N) as YOLOv8 exports it,
    #: `channels_last` (1, N, 4+nc+nm) as YOLOv5 does, or `auto` (decided from the shape).
    predictions_layout: str = setting("auto", choices=("auto", "channels_first", "channels_last"))
    #: Objectness column after the box (score = objectness * class score); null: by convention
    #: (true for `yolov5`, false for `yolov8` and `yolo_seg`; YOLOv5-seg exports need true).
    objectness: bool | None = None
    #: Mask = sigmoid(coefficients @ prototypes) > mask_threshold.
    mask_threshold: float = setting(0.5, min=0.0, max=1.0, min_exclusive=True, max_exclusive=True)

    def has_objectness(self, convention: str) -> bool:
        return (convention == "yolov5") if self.objectness is None else self.objectness


@dataclass
class YoloxConfig(Settings):
    """Output of a Megvii YOLOX export: (1, N, 5 + nc) per grid cell, strides in order.

    The official `tools/export_onnx.py` leaves `decode_in_inference` off, so the box columns are raw
    grid predictions decoded here as `yolox/utils/demo_utils.py: demo_postprocess` does:
    cx, cy = (p + cell) * stride, w, h = exp(p) * stride. The head applies the sigmoid to objectness
    and class scores in inference, so they arrive as probabilities and score = objectness * class.
    """

    #: Output tensor name; "" takes the first output.
    predictions: str = ""
    #: false: raw grid (the official export); true: exported with --decode_in_inference (boxes
    #: already in input pixels); auto: per call from the values of the confident rows (raw grid
    #: offsets and log-sizes stay within a few units, decoded boxes are pixel coordinates).
    decoded: str = setting("auto", choices=("auto", "true", "false"))
    #: Feature strides in output order (YOLOX-P6 variants: [8, 16, 32, 64]).
    strides: list[int] = setting([8, 16, 32], min=1)
    #: true when objectness and class scores are logits (a head exported without its sigmoid).
    apply_sigmoid: bool = False


@dataclass
class DepthMaskConfig(Settings):
    """Instance masks of detection-only models, cut out of the depth image inside each box.

    The object's depth is the median valid depth of the box's central part (objects fill the centre
    of their box, background its corners); the mask is the connected component of pixels within a
    depth band around it that overlaps that central part most.
    """

    #: Side of the central part, as a fraction of the box side.
    center_fraction: float = setting(0.5, min=0.0, max=1.0, min_exclusive=True)
    #: Half-width of the depth band: max(abs_tolerance_m, rel_tolerance * median depth).
    abs_tolerance_m: float = 0.15
    rel_tolerance: float = 0.1
    #: What to do when the central part has no valid depth: `box` (whole box) or `drop`.
    no_depth: str = setting("drop", choices=("box", "drop"))


@dataclass
class DetectionConfig(Settings):
    """Outputs of a box detector (`detection`, `torchvision`); `depth_mask` serves every
    detection-only convention (`yolox`, `yolov5`, `yolov8` too)."""

    #: Output tensor names; "" takes them from the graph (torchvision: boxes, labels, scores,
    #: masks), else the outputs in order (boxes, scores, classes).
    boxes: str = ""
    scores: str = ""
    classes: str = ""
    #: Per-detection mask probabilities (N, 1, H, W) over the input (torchvision Mask R-CNN);
    #: "" with no such output: masks come from depth.
    masks: str = ""
    mask_threshold: float = setting(0.5, min=0.0, max=1.0, min_exclusive=True, max_exclusive=True)
    #: xyxy (corners), xywh (corner + size) or cxcywh (centre + size).
    box_format: str = setting("xyxy", choices=BOX_FORMATS)
    #: True: box coordinates are fractions of the network input size.
    normalized: bool = False
    #: Run class-wise NMS (harmless when the export already did).
    nms: bool = True
    depth_mask: DepthMaskConfig = field(default_factory=DepthMaskConfig)


@dataclass
class SemanticConfig(Settings):
    """Outputs of a per-pixel semantic model."""

    #: Output tensor name; "" takes the first output.
    logits: str = ""
    #: True when the output is already a probability (softmax applied in the model).
    probabilities: bool = False
    #: Thing components smaller than this many pixels (in the original image) are dropped.
    min_instance_area_px: int = 64


#: Model classes dropped even with a `fallback_class`: people and animals move, so they are no
#: part of a static scene model (a person integrated over a few keyframes is a ghost object).
DEFAULT_IGNORE_CLASSES: tuple[str, ...] = (
    "person", "bird", "cat", "dog", "horse", "sheep", "cow", "elephant", "bear", "zebra", "giraffe",
)


@dataclass
class OnnxModelConfig(Settings):
    """One exported model: file, pre-processing, output convention and class mapping."""

    #: The .onnx file; a relative path is relative to the folder of the YAML file.
    model: str = ""
    #: `auto`: read off the graph when the model is loaded (see the module docstring).
    convention: str = setting("auto", choices=CONVENTIONS)
    #: The model's classes in output order: `auto` (the names in the export's metadata, else the
    #: COCO list that fits the class count), `coco80`, `coco91` (torchvision category ids),
    #: `coco_panoptic` or an explicit list.
    class_names: str | list[str] = "auto"
    #: Model class name -> project class name (`config/classes.yaml`); "" drops the class.
    #: Applied before the class table's COCO lists.
    class_map: dict[str, str] = field(default_factory=dict)
    #: Project class for model classes that map to nothing else (a COCO sink, bowl or laptop);
    #: "" drops them. Ignored when the class table has no such class.
    fallback_class: str = "object"
    #: Model classes never mapped to the fallback class (dropped unless `class_map` names them).
    ignore_classes: list[str] = field(default_factory=lambda: list(DEFAULT_IGNORE_CLASSES))
    #: Detections (or semantic segments, by mean probability) below this score are dropped. Real
    #: detectors: 0.35-0.5; the paper's 0.7 suits the oracle of the synthetic world.
    score_threshold: float = setting(DEFAULT_SCORE_THRESHOLD, min=0.0, max=1.0)
    #: Class-wise non-maximum suppression IoU and the number of detections kept after it.
    nms_iou: float = setting(0.5, min=0.0, max=1.0)
    max_detections: int = setting(100, min=0, min_exclusive=True)
    preprocess: PreprocessConfig = field(default_factory=PreprocessConfig)
    yolo: YoloSegConfig = field(default_factory=YoloSegConfig)
    yolox: YoloxConfig = field(default_factory=YoloxConfig)
    detection: DetectionConfig = field(default_factory=DetectionConfig)
    semantic: SemanticConfig = field(default_factory=SemanticConfig)
    paint: PaintConfig = field(default_factory=PaintConfig)


def load_model_config(path: str | Path, overrides: dict[str, Any] | None = None) -> OnnxModelConfig:
    """Read a model YAML; the `model` path becomes absolute (relative to the YAML's folder)."""
    yaml_path = resolve_path(path)
    cfg = load_config(OnnxModelConfig, yaml_path, overrides)
    if cfg.model:
        cfg.model = str(resolve_path(cfg.model, base=yaml_path.parent))
    return cfg
