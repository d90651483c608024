"""The one interface every segmentation backend implements."""

from __future__ import annotations

import time
from abc import ABC, abstractmethod

import numpy as np

from panoptic_mapping.segmentation.types import PanopticSegmentation, SegmentationError
from recon_core.frame import RGBDFrame


class PanopticSegmenter(ABC):
    """Per-frame 2D panoptic segmentation of an RGB(-D) image.

    `segment` checks the input and times the backend (so every backend reports latency the same
    way); backends implement `_segment`. Backends that need more than the color image say so:
    detection-only ONNX models need `depth`, the oracle needs `frame.extras['labels']`.
    """

    #: Backend name as used in configs and the ROS parameter `backend`.
    name: str = ""

    def segment(
        self, color: np.ndarray, depth: np.ndarray | None = None, frame: RGBDFrame | None = None
    ) -> PanopticSegmentation:
        """Segment `color` ((H, W, 3) uint8 RGB); `depth` (H, W) float32 metres, 0 = invalid."""
        check_images(color, depth)
        t0 = time.perf_counter()
        result = self._segment(color, depth, frame)
        result.latency_ms = (time.perf_counter() - t0) * 1e3
        return result

    def segment_frame(self, frame: RGBDFrame) -> PanopticSegmentation:
        """Convenience: `segment(frame.color, frame.depth, frame)`."""
        return self.segment(frame.color, frame.depth, frame)

    @abstractmethod
    def _segment(
        self, color: np.ndarray, depth: np.ndarray | None, frame: RGBDFrame | None
    ) -> PanopticSegmentation: ...


def check_images(color: np.ndarray, depth: np.ndarray | None) -> None:
    """Raise SegmentationError unless color is (H, W, 3) uint8 and depth (if any) is (H, W)."""
    if not isinstance(color, np.ndarray) or color.ndim != 3 or color.shape[2] != 3 or color.dtype != np.uint8:
        shape = getattr(color, "shape", None)
        dtype = getattr(color, "dtype", type(color).__name__)
        raise SegmentationError(f"color must be an (H, W, 3) uint8 RGB array, got {dtype} with shape {shape}")
    if color.shape[0] == 0 or color.shape[1] == 0:
        raise SegmentationError(f"color image is empty ({color.shape[1]}x{color.shape[0]})")
    if depth is not None and depth.shape != color.shape[:2]:
        raise SegmentationError(
            f"depth {depth.shape[::-1]} and color {color.shape[1::-1]} differ in size; depth must be registered"
        )
