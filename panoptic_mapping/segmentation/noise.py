"""Mask-level noise operations of the oracle backend (each one imitates a typical network error).

All work on `MaskCrop`s, so their cost follows the object's size, not the image's.
"""

from __future__ import annotations

import cv2
import numpy as np

from panoptic_mapping.segmentation.types import MaskCrop


def _disk(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def erode_or_dilate(mask: MaskCrop, radius: int, dilate: bool, shape: tuple[int, int]) -> MaskCrop | None:
    """Grow or shrink the outline by `radius` pixels (boundary uncertainty of a network).

    Erosion does not eat in from the image border: the object goes on outside the frame.
    """
    if radius <= 0:
        return mask
    padded = mask.padded(radius, shape)
    m = padded.mask.astype(np.uint8)
    if dilate:
        out = cv2.dilate(m, _disk(radius), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    else:
        out = cv2.erode(m, _disk(radius), borderType=cv2.BORDER_REPLICATE)
    return MaskCrop(padded.x, padded.y, out.astype(bool)).tight()


def split_along_line(mask: MaskCrop, angle: float) -> tuple[MaskCrop, MaskCrop] | None:
    """Two parts of the mask on either side of the line through its centroid at `angle` (radians)."""
    ys, xs = np.nonzero(mask.mask)
    if xs.size < 2:
        return None
    cx, cy = xs.mean(), ys.mean()
    cols = np.arange(mask.width) - cx
    rows = np.arange(mask.height) - cy
    side = (cols[None, :] * np.cos(angle) + rows[:, None] * np.sin(angle)) > 0
    a = MaskCrop(mask.x, mask.y, mask.mask & side).tight()
    b = MaskCrop(mask.x, mask.y, mask.mask & ~side).tight()
    if a is None or b is None:
        return None
    return a, b


def bleed_onto_background(
    mask: MaskCrop, depth: np.ndarray, radius: int, depth_gap_m: float
) -> MaskCrop:
    """Spill the mask, within `radius` of it, onto pixels much farther away than the object itself
    (the floor seen through a chair's legs labelled "chair")."""
    if radius <= 0:
        return mask
    shape = depth.shape[:2]
    own = depth[mask.slices][mask.mask]
    own = own[own > 0]
    if own.size == 0:
        return mask
    far_from = float(np.median(own)) + depth_gap_m
    padded = mask.padded(radius, shape)
    grown = cv2.dilate(padded.mask.astype(np.uint8), _disk(radius)).astype(bool)
    far = depth[padded.slices] > far_from
    return MaskCrop(padded.x, padded.y, padded.mask | (grown & far))


def random_blob(rng: np.random.Generator, shape: tuple[int, int], axes_px: tuple[float, float]) -> MaskCrop:
    """A random filled ellipse (a spurious detection); may reach past the image border."""
    h, w = shape
    a, b = rng.uniform(axes_px[0], axes_px[1], size=2)
    angle = float(rng.uniform(0.0, 180.0))
    cx, cy = float(rng.uniform(0, w)), float(rng.uniform(0, h))
    r = int(np.ceil(max(a, b)))
    canvas = np.zeros((2 * r + 1, 2 * r + 1), np.uint8)
    cv2.ellipse(canvas, (r, r), (max(round(a), 1), max(round(b), 1)), angle, 0, 360, 1, thickness=-1)
    return MaskCrop(round(cx) - r, round(cy) - r, canvas.astype(bool))


def touching_pairs(labels: np.ndarray) -> np.ndarray:
    """(K, 2) pairs (a < b) of non-zero labels that are 4-neighbours somewhere in the image."""
    m = int(labels.max()) + 1
    codes = []
    for a, b in ((labels[:, :-1], labels[:, 1:]), (labels[:-1, :], labels[1:, :])):
        diff = (a != b) & (a != 0) & (b != 0)
        lo, hi = np.minimum(a[diff], b[diff]).astype(np.int64), np.maximum(a[diff], b[diff]).astype(np.int64)
        codes.append(lo * m + hi)
    uniq = np.unique(np.concatenate(codes))
    return np.stack([uniq // m, uniq % m], axis=1)
