"""Per-frame 2D panoptic segmentation (stage 1), ROS-free, behind one interface.

    seg = make_segmenter(load_segmentation_config(overrides={"backend": "oracle",
                                                             "oracle.ground_truth": "out/demo/scene_groundtruth"}))
    result = seg.segment(frame.color, frame.depth, frame)   # PanopticSegmentation

Backends: `onnx` (an exported model the user brings, three output conventions), `oracle` (ground
truth of generated scenes through a network-like noise model), `none` (no segments).
"""

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
from panoptic_mapping.segmentation.onnx_backend import OnnxSegmenter, OnnxTiming
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
