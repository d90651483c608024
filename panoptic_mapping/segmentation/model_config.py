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
from recon_core.config import ConfigError, Settings, load_config, setting

CONVENTIONS: tuple[str, ...] = ("yolo_seg", "detection", "semantic")
COLOR_ORDERS: tuple[str, ...] = ("RGB", "BGR")
LAYOUTS: tuple[str, ...] = ("NCHW", "NHWC")
BOX_FORMATS: tuple[str, ...] = ("xyxy", "xywh", "cxcywh")


@dataclass
class PreprocessConfig(Settings):
    """Image -> input tensor. Values follow the model's training pipeline; see its export notes."""

    #: Network input [width, height]; [] takes the model's static input shape.
    input_size: list[int] = field(default_factory=lambda: [640, 640])
    #: True: scale to fit keeping the aspect ratio and pad (YOLO letterbox); False: stretch.
    letterbox: bool = True
    #: Grey level of the letterbox padding (0-255, before normalisation; YOLO uses 114).
    pad_value: int = setting(114, min=0, max=255)
    #: Channel order the model expects (images arrive as RGB).
    color_order: str = setting("RGB", choices=COLOR_ORDERS)
    #: x = (pixel * scale - mean) / std, per channel in the model's channel order.
    scale: float = 1.0 / 255.0
    mean: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    std: list[float] = field(default_factory=lambda: [1.0, 1.0, 1.0])
    #: Tensor layout of the image input.
    layout: str = setting("NCHW", choices=LAYOUTS)

    def __post_init__(self) -> None:
        """Ranges are checked by `Settings`; these conditions relate several values of a field."""
        super().__post_init__()
        if self.input_size and (len(self.input_size) != 2 or min(self.input_size) <= 0):
            raise ConfigError(f"preprocess.input_size must be [width, height] > 0 or [], got {self.input_size}")
        if len(self.mean) != 3 or len(self.std) != 3 or min(abs(s) for s in self.std) == 0:
            raise ConfigError("preprocess.mean and preprocess.std need 3 values each, std non-zero")


@dataclass
class YoloSegConfig(Settings):
    """Outputs of a YOLO-family instance segmentation model."""

    #: Output tensor names; "" takes the model's outputs in order (predictions first, prototypes second).
    predictions: str = ""
    prototypes: str = ""
    #: Layout of the predictions: `channels_first` (1, 4+nc+nm, N) as YOLOv8 exports it,
    #: `channels_last` (1, N, 4+nc+nm), or `auto` (decided from the shape; channels_first on a tie).
    predictions_layout: str = setting("auto", choices=("auto", "channels_first", "channels_last"))
    #: YOLOv5-seg style objectness column after the box (score = objectness * class score).
    objectness: bool = False
    #: Mask = sigmoid(coefficients @ prototypes) > mask_threshold.
    mask_threshold: float = setting(0.5, min=0.0, max=1.0, min_exclusive=True, max_exclusive=True)



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
    """Outputs of a detection-only model."""

    #: Output tensor names; "" takes the model's outputs in order (boxes, scores, classes).
    boxes: str = ""
    scores: str = ""
    classes: str = ""
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


@dataclass
class OnnxModelConfig(Settings):
    """One exported model: file, pre-processing, output convention and class mapping."""

    #: The .onnx file; a relative path is relative to the folder of the YAML file.
    model: str = ""
    convention: str = setting("yolo_seg", choices=CONVENTIONS)
    #: The model's classes in output order: `coco80`, `coco_panoptic` or an explicit list.
    class_names: str | list[str] = "coco80"
    #: Model class name -> project class name (`config/classes.yaml`); "" drops the class.
    #: Applied before the class table's COCO lists; classes that resolve to nothing are dropped.
    class_map: dict[str, str] = field(default_factory=dict)
    #: Detections (or semantic segments, by mean probability) below this score are dropped.
    score_threshold: float = setting(PAPER_SCORE_THRESHOLD, min=0.0, max=1.0)
    #: Class-wise non-maximum suppression IoU and the number of detections kept after it.
    nms_iou: float = setting(0.5, min=0.0, max=1.0)
    max_detections: int = setting(100, min=0, min_exclusive=True)
    preprocess: PreprocessConfig = field(default_factory=PreprocessConfig)
    yolo: YoloSegConfig = field(default_factory=YoloSegConfig)
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
