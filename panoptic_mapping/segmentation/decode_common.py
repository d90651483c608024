"""What every output decoder needs to know about one call (shared by the conventions)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from panoptic_mapping.segmentation.class_map import ModelClassMap
from panoptic_mapping.segmentation.letterbox import Letterbox
from panoptic_mapping.segmentation.model_config import OnnxModelConfig
from panoptic_mapping.segmentation.types import SegmentationError


@dataclass
class DecodeContext:
    """The geometry and class mapping of one `OnnxSegmenter.segment` call."""

    config: OnnxModelConfig
    class_map: ModelClassMap
    letterbox: Letterbox
    depth: np.ndarray | None = None
    #: Warnings already given by this segmenter (each is logged once, not on every frame).
    warned: set[str] = field(default_factory=set)

    def warn_once(self, key: str, message: str) -> None:
        if key not in self.warned:
            self.warned.add(key)
            logging.getLogger("panoptic_mapping.segmentation").warning(message)

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) of the source image."""
        return self.letterbox.src_w, self.letterbox.src_h


def squeeze_batch(array: np.ndarray, ndim: int, what: str) -> np.ndarray:
    """Drop a leading batch dimension of 1 so the array has `ndim` dimensions."""
    a = np.asarray(array)
    while a.ndim > ndim and a.shape[0] == 1:
        a = a[0]
    if a.ndim != ndim:
        raise SegmentationError(f"{what}: expected {ndim} dimensions (plus a batch of 1), got shape {array.shape}")
    return a


def cxcywh_to_xyxy(b: np.ndarray) -> np.ndarray:
    half = b[:, 2:4] / 2.0
    return np.concatenate([b[:, 0:2] - half, b[:, 0:2] + half], axis=1)
