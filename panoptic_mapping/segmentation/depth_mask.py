"""Instance masks for detection-only models, cut out of the depth image inside each box."""

from __future__ import annotations

import cv2
import numpy as np

from panoptic_mapping.segmentation.model_config import DepthMaskConfig
from panoptic_mapping.segmentation.types import MaskCrop

#: Connectivity of the depth-band components (8: thin diagonal parts stay attached).
_CONNECTIVITY = 8


def depth_mask_in_box(depth: np.ndarray, pixels: np.ndarray, cfg: DepthMaskConfig) -> MaskCrop | None:
    """Mask of the object in box pixels [c0, c1) x [r0, r1); None when the box has no usable depth.

    The object's depth is the median valid depth of the box's central part; the mask is the
    connected component of pixels within the depth band around it that overlaps the central part
    most, so the table behind a cup or the wall behind a chair (outside the band) stay out, and so
    does a same-depth object elsewhere in the box (another component).
    """
    c0, r0, c1, r1 = (int(v) for v in pixels)
    if c1 <= c0 or r1 <= r0:
        return None
    crop = depth[r0:r1, c0:c1]
    h, w = crop.shape
    ch, cw = max(round(h * cfg.center_fraction), 1), max(round(w * cfg.center_fraction), 1)
    y0, x0 = (h - ch) // 2, (w - cw) // 2
    center = crop[y0 : y0 + ch, x0 : x0 + cw]
    valid = center[center > 0]
    if valid.size == 0:
        return MaskCrop(c0, r0, np.ones((h, w), bool)) if cfg.no_depth == "box" else None
    med = float(np.median(valid))
    tol = max(cfg.abs_tolerance_m, cfg.rel_tolerance * med)
    band = (crop > 0) & (np.abs(crop - med) <= tol)
    n, comp = cv2.connectedComponents(band.astype(np.uint8), connectivity=_CONNECTIVITY)
    if n <= 1:
        return None
    votes = np.bincount(comp[y0 : y0 + ch, x0 : x0 + cw].ravel(), minlength=n)
    votes[0] = 0
    best = int(np.argmax(votes))
    if votes[best] == 0:
        return None
    return MaskCrop(c0, r0, comp == best)
