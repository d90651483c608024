"""How one exported ONNX model is fed and decoded; one YAML file per model (`config/segmentation/`).

The project ships no weights (none can be downloaded here); users export their own model and
describe it with a file like `config/segmentation/yolo_seg.yaml`. Three output conventions are
understood (`convention`):

* `yolo_seg`  YOLOv8-seg style instance segmentation: output0 (1, 4+nc+nm, N) boxes cx,cy,w,h +
              class scores + mask coefficients, output1 (1, nm, mh, mw) mask prototypes;
* `detection` boxes/scores/classes only ((1, N, 4), (1, N), (1, N)): masks come from depth;
* `semantic`  per-pixel logits (1, C, h, w): argmax, stuff per class, things by connected components.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from panoptic_mapping.segmentation.config import PAPER_SCORE_THRESHOLD, PaintConfig, resolve_path
from recon_core.config import ConfigError, load_config

CONVENTIONS: tuple[str, ...] = ("yolo_seg", "detection", "semantic")
COLOR_ORDERS: tuple[str, ...] = ("RGB", "BGR")
LAYOUTS: tuple[str, ...] = ("NCHW", "NHWC")
BOX_FORMATS: tuple[str, ...] = ("xyxy", "xywh", "cxcywh")


@dataclass
class PreprocessConfig:
    """Image -> input tensor. Values follow the model's training pipeline; see its export notes."""

    #: Network input [width, height]; [] takes the model's static input shape.
    input_size: list[int] = field(default_factory=lambda: [640, 640])
    #: True: scale to fit keeping the aspect ratio and pad (YOLO letterbox); False: stretch.
    letterbox: bool = True
    #: Grey level of the letterbox padding (0-255, before normalisation; YOLO uses 114).
    pad_value: int = 114
    #: Channel order the model expects (images arrive as RGB).
    color_order: str = "RGB"
    #: x = (pixel * scale - mean) / std, per channel in the model's channel order.
    scale: float = 1.0 / 255.0
    mean: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    std: list[float] = field(default_factory=lambda: [1.0, 1.0, 1.0])
    #: Tensor layout of the image input.
    layout: str = "NCHW"

    def __post_init__(self) -> None:
        _one_of("preprocess.color_order", self.color_order, COLOR_ORDERS)
        _one_of("preprocess.layout", self.layout, LAYOUTS)
        if self.input_size and (len(self.input_size) != 2 or min(self.input_size) <= 0):
            raise ConfigError(f"preprocess.input_size must be [width, height] > 0 or [], got {self.input_size}")
        if len(self.mean) != 3 or len(self.std) != 3 or min(abs(s) for s in self.std) == 0:
            raise ConfigError("preprocess.mean and preprocess.std need 3 values each, std non-zero")
        if not 0 <= self.pad_value <= 255:
            raise ConfigError(f"preprocess.pad_value must be in 0..255, got {self.pad_value}")


@dataclass
class YoloSegConfig:
    """Outputs of a YOLO-family instance segmentation model."""

    #: Output tensor names; "" takes the model's outputs in order (predictions first, prototypes second).
    predictions: str = ""
    prototypes: str = ""
    #: Layout of the predictions: `channels_first` (1, 4+nc+nm, N) as YOLOv8 exports it,
    #: `channels_last` (1, N, 4+nc+nm), or `auto` (decided from the shape; channels_first on a tie).
    predictions_layout: str = "auto"
    #: YOLOv5-seg style objectness column after the box (score = objectness * class score).
    objectness: bool = False
    #: Mask = sigmoid(coefficients @ prototypes) > mask_threshold.
    mask_threshold: float = 0.5

    def __post_init__(self) -> None:
        _one_of("yolo.predictions_layout", self.predictions_layout, ("auto", "channels_first", "channels_last"))
        if not 0 < self.mask_threshold < 1:
            raise ConfigError(f"yolo.mask_threshold must be in (0, 1), got {self.mask_threshold}")


@dataclass
class DepthMaskConfig:
    """Instance masks of detection-only models, cut out of the depth image inside each box.

    The object's depth is the median valid depth of the box's central part (objects fill the centre
    of their box, background its corners); the mask is the connected component of pixels within a
    depth band around it that overlaps that central part most.
    """

    #: Side of the central part, as a fraction of the box side.
    center_fraction: float = 0.5
    #: Half-width of the depth band: max(abs_tolerance_m, rel_tolerance * median depth).
    abs_tolerance_m: float = 0.15
    rel_tolerance: float = 0.1
    #: What to do when the central part has no valid depth: `box` (whole box) or `drop`.
    no_depth: str = "drop"

    def __post_init__(self) -> None:
        _one_of("detection.depth_mask.no_depth", self.no_depth, ("box", "drop"))
        if not 0 < self.center_fraction <= 1:
            raise ConfigError(f"center_fraction must be in (0, 1], got {self.center_fraction}")


@dataclass
class DetectionConfig:
    """Outputs of a detection-only model."""

    #: Output tensor names; "" takes the model's outputs in order (boxes, scores, classes).
    boxes: str = ""
    scores: str = ""
    classes: str = ""
    #: xyxy (corners), xywh (corner + size) or cxcywh (centre + size).
    box_format: str = "xyxy"
    #: True: box coordinates are fractions of the network input size.
    normalized: bool = False
    #: Run class-wise NMS (harmless when the export already did).
    nms: bool = True
    depth_mask: DepthMaskConfig = field(default_factory=DepthMaskConfig)

    def __post_init__(self) -> None:
        _one_of("detection.box_format", self.box_format, BOX_FORMATS)


@dataclass
class SemanticConfig:
    """Outputs of a per-pixel semantic model."""

    #: Output tensor name; "" takes the first output.
    logits: str = ""
    #: True when the output is already a probability (softmax applied in the model).
    probabilities: bool = False
    #: Thing components smaller than this many pixels (in the original image) are dropped.
    min_instance_area_px: int = 64


@dataclass
class OnnxModelConfig:
    """One exported model: file, pre-processing, output convention and class mapping."""

    #: The .onnx file; a relative path is relative to the folder of the YAML file.
    model: str = ""
    convention: str = "yolo_seg"
    #: The model's classes in output order: `coco80`, `coco_panoptic` or an explicit list.
    class_names: str | list[str] = "coco80"
    #: Model class name -> project class name (`config/classes.yaml`); "" drops the class.
    #: Applied before the class table's COCO lists; classes that resolve to nothing are dropped.
    class_map: dict[str, str] = field(default_factory=dict)
    #: Detections (or semantic segments, by mean probability) below this score are dropped.
    score_threshold: float = PAPER_SCORE_THRESHOLD
    #: Class-wise non-maximum suppression IoU and the number of detections kept after it.
    nms_iou: float = 0.5
    max_detections: int = 100
    preprocess: PreprocessConfig = field(default_factory=PreprocessConfig)
    yolo: YoloSegConfig = field(default_factory=YoloSegConfig)
    detection: DetectionConfig = field(default_factory=DetectionConfig)
    semantic: SemanticConfig = field(default_factory=SemanticConfig)
    paint: PaintConfig = field(default_factory=PaintConfig)

    def __post_init__(self) -> None:
        _one_of("convention", self.convention, CONVENTIONS)
        for name in ("score_threshold", "nms_iou"):
            if not 0 <= getattr(self, name) <= 1:
                raise ConfigError(f"{name} must be in [0, 1], got {getattr(self, name)}")
        if self.max_detections <= 0:
            raise ConfigError(f"max_detections must be > 0, got {self.max_detections}")


def load_model_config(path: str | Path, overrides: dict[str, Any] | None = None) -> OnnxModelConfig:
    """Read a model YAML; the `model` path becomes absolute (relative to the YAML's folder)."""
    yaml_path = resolve_path(path)
    cfg = load_config(OnnxModelConfig, yaml_path, overrides)
    if cfg.model:
        cfg.model = str(resolve_path(cfg.model, base=yaml_path.parent))
    return cfg


def _one_of(name: str, value: str, options: tuple[str, ...]) -> None:
    if value not in options:
        raise ConfigError(f"{name}: unknown value {value!r}; valid values: {list(options)}")
