"""Per-frame 2D panoptic segmentation (stage 1), ROS-free, behind one interface.

    seg = make_segmenter(load_segmentation_config(overrides={"backend": "oracle",
                                                             "oracle.ground_truth": "out/demo/scene_groundtruth"}))
    result = seg.segment(frame.color, frame.depth, frame)   # PanopticSegmentation

Backends: `onnx` (an exported model the user brings: YOLOX, YOLOv5, YOLOv8/11, YOLOv8-seg,
torchvision Mask/Faster R-CNN or semantic logits, the convention read off the graph), `oracle`
(ground truth of generated scenes through a network-like noise model), `none` (no segments).

    seg = make_segmenter(load_segmentation_config(overrides={"backend": "onnx", "onnx.model": "yolox_s.onnx"}))
"""

from panoptic_mapping.segmentation.autodetect import ModelSignature, ResolvedModel, resolve_model
from panoptic_mapping.segmentation.base import PanopticSegmenter
from panoptic_mapping.segmentation.config import (
    BACKENDS,
    OnnxConfig,
    OracleConfig,
    OracleNoiseConfig,
    PaintConfig,
    SegmentationConfig,
    load_segmentation_config,
)
from panoptic_mapping.segmentation.factory import make_segmenter
from panoptic_mapping.segmentation.model_config import OnnxModelConfig, load_model_config
from panoptic_mapping.segmentation.none_backend import NoneSegmenter
from panoptic_mapping.segmentation.onnx_backend import OnnxSegmenter, OnnxTiming, select_providers
from panoptic_mapping.segmentation.oracle import EntityClass, OracleSegmenter
from panoptic_mapping.segmentation.panoptic import assemble
from panoptic_mapping.segmentation.types import (
    MaskCrop,
    PanopticSegmentation,
    Segment,
    SegmentationError,
    SegmentCandidate,
)

__all__ = [
    "BACKENDS",
    "EntityClass",
    "MaskCrop",
    "ModelSignature",
    "NoneSegmenter",
    "OnnxConfig",
    "OnnxModelConfig",
    "OnnxSegmenter",
    "OnnxTiming",
    "OracleConfig",
    "OracleNoiseConfig",
    "OracleSegmenter",
    "PaintConfig",
    "PanopticSegmentation",
    "PanopticSegmenter",
    "ResolvedModel",
    "Segment",
    "SegmentCandidate",
    "SegmentationConfig",
    "SegmentationError",
    "assemble",
    "load_model_config",
    "load_segmentation_config",
    "make_segmenter",
    "resolve_model",
    "select_providers",
]
