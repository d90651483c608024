"""`none` backend: geometry-only mapping, no semantics at all."""

from __future__ import annotations

import numpy as np

from panoptic_mapping.segmentation.base import PanopticSegmenter
from panoptic_mapping.segmentation.types import PanopticSegmentation
from recon_core.frame import RGBDFrame


class NoneSegmenter(PanopticSegmenter):
    """Returns no segments (all labels 0): the mapper then relies on depth segmentation alone."""

    name = "none"

    def _segment(
        self, color: np.ndarray, depth: np.ndarray | None, frame: RGBDFrame | None
    ) -> PanopticSegmentation:
        return PanopticSegmentation.empty(color.shape[0], color.shape[1])
