"""Image resampling for the mapper's processing resolution."""

from __future__ import annotations

import cv2
import numpy as np


def downsample_depth(depth: np.ndarray, factor: int, min_valid: int = 2) -> np.ndarray:
    """Block mean of the valid (> 0) depths in factor x factor blocks; 0 where too few are valid.

    Averaging (instead of picking one pixel) lowers the sensor noise by ~sqrt(factor^2); blocks that
    straddle a depth edge are rejected when their spread is large, so no flying pixels are made.
    """
    if factor == 1:
        return depth
    h, w = depth.shape
    h2, w2 = h // factor, w // factor
    blocks = (depth[: h2 * factor, : w2 * factor].reshape(h2, factor, w2, factor).transpose(0, 2, 1, 3)
              .reshape(h2, w2, factor * factor))
    valid = blocks > 0
    n = valid.sum(axis=2)
    total = np.where(valid, blocks, 0).sum(axis=2)
    mean = total / np.maximum(n, 1)
    lo = np.where(valid, blocks, np.inf).min(axis=2)
    hi = np.where(valid, blocks, -np.inf).max(axis=2)
    ok = (n >= min(min_valid, factor * factor)) & (hi - lo <= 0.05 * mean + 0.01)
    return np.where(ok, mean, 0.0).astype(np.float32)


def downsample_labels(labels: np.ndarray, factor: int) -> np.ndarray:
    """Nearest (top-left of each block) sampling of a label image: labels must never be blended."""
    if factor == 1:
        return labels
    return np.ascontiguousarray(labels[::factor, ::factor])


def downsample_color(color: np.ndarray, factor: int) -> np.ndarray:
    if factor == 1:
        return color
    h, w = color.shape[:2]
    return cv2.resize(color, (w // factor, h // factor), interpolation=cv2.INTER_AREA)
