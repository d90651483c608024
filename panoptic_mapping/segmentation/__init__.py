"""Per-frame 2D panoptic segmentation (stage 1), ROS-free, behind one interface.

    seg = make_segmenter(load_segmentation_config(overrides={"backend": "oracle",
                                                             "oracle.ground_truth": "out/demo/scene_groundtruth"}))
    result = seg.segment(frame.color, frame.depth, frame)   # PanopticSegmentation

Backends: `onnx` (an exported model the user brings, three output conventions), `oracle` (ground
truth of generated scenes through a network-like noise model), `none` (no segments).
"""

from .base import PanopticSegmenter
from .config import (
    BACKENDS,
    OnnxConfig,
    OracleConfig,
    OracleNoiseConfig,
    PaintConfig,
    SegmentationConfig,
    load_segmentation_config,
)
from .factory import make_segmenter
from .model_config import OnnxModelConfig, load_model_config
from .none_backend import NoneSegmenter
from .onnx_backend import OnnxSegmenter, OnnxTiming
from .oracle import EntityClass, OracleSegmenter
from .panoptic import assemble
from .types import MaskCrop, PanopticSegmentation, Segment, SegmentationError, SegmentCandidate

__all__ = [
    "BACKENDS",
    "EntityClass",
    "MaskCrop",
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
    "Segment",
    "SegmentCandidate",
    "SegmentationConfig",
    "SegmentationError",
    "assemble",
    "load_model_config",
    "load_segmentation_config",
    "make_segmenter",
]
