"""Bring colour and depth of different sizes onto one pixel grid: the depth image's.

Depth is never resampled (interpolating depth invents surfaces between foreground and
background); the colour image (and a label image of the colour's size) is resampled into the
depth image's grid instead, and the frame carries the depth camera's intrinsics:

* both intrinsics known (ScanNet's `intrinsic_color.txt` / `intrinsic_depth.txt`, a bag with a
  camera info per stream): every depth pixel takes the colour of the colour pixel on the same
  viewing ray (the two cameras are assumed to share their optical centre, as registered streams do);
* one intrinsics known and both images with the same aspect ratio (a decimated depth stream,
  colour and depth at two resolutions of one camera): the colour is resized, the intrinsics scaled;
* otherwise the frame is refused with a message that says what is missing.
"""

from __future__ import annotations

import cv2
import numpy as np

from recon_core.errors import DatasetError
from recon_core.frame import CameraIntrinsics

Intrinsics4 = tuple[float, float, float, float]


def scale_intrinsics(k: Intrinsics4, sx: float, sy: float) -> Intrinsics4:
    """Intrinsics of an image resized by (sx, sy) (pixel-centre convention, like cv2.resize)."""
    fx, fy, cx, cy = k
    return fx * sx, fy * sy, (cx + 0.5) * sx - 0.5, (cy + 0.5) * sy - 0.5


def _centre_error(k: Intrinsics4, w: int, h: int) -> float:
    return abs(k[2] - (w - 1) / 2) / w + abs(k[3] - (h - 1) / 2) / h


def register_to_depth(
    color: np.ndarray,
    depth: np.ndarray,
    k_color: Intrinsics4 | None,
    k_depth: Intrinsics4 | None,
    labels: np.ndarray | None = None,
    k_describes: str = "color",
) -> tuple[np.ndarray, CameraIntrinsics, np.ndarray | None, bool]:
    """(colour, intrinsics, labels, resampled) on the depth image's grid.

    `k_color` / `k_depth`: intrinsics of each image at its own size (None: unknown). With only one
    given and `k_describes="auto"`, the image whose centre is nearer the principal point is taken to
    be the one it describes. `labels` (same size as `color`) is resampled by nearest neighbour.
    """
    hd, wd = depth.shape[:2]
    hc, wc = color.shape[:2]
    if (hc, wc) == (hd, wd):
        k = k_depth or k_color
        if k is None:
            raise DatasetError("no camera intrinsics for the frame")
        return color, CameraIntrinsics(*k, width=wd, height=hd), labels, False
    if k_depth is None or k_color is None:
        k_one = k_color or k_depth
        if k_one is None:
            raise DatasetError("no camera intrinsics for the frame")
        rel = abs(wc / hc - wd / hd) / (wd / hd)
        if rel > 0.01:
            raise DatasetError(
                f"color {wc}x{hc} and depth {wd}x{hd} differ in size and aspect ratio, and only one camera "
                "matrix is known: give the depth camera's intrinsics too (a camera info beside the depth topic, "
                "intrinsic_depth.txt) or record depth registered to color (e.g. aligned_depth_to_color)"
            )
        describes = k_describes
        if describes == "auto":
            describes = "color" if _centre_error(k_one, wc, hc) <= _centre_error(k_one, wd, hd) else "depth"
        if k_depth is None and describes == "color":
            k_color, k_depth = k_one, scale_intrinsics(k_one, wd / wc, hd / hc)
        else:
            k_depth, k_color = k_one, scale_intrinsics(k_one, wc / wd, hc / hd)
    assert k_color is not None and k_depth is not None
    out_labels = None
    if labels is not None:
        out_labels = _warp(labels.astype(np.int32), k_color, k_depth, wd, hd, cv2.INTER_NEAREST, 0)
    src, k_src = color, k_color
    shrink = min(k_depth[0] / k_color[0], k_depth[1] / k_color[1])
    if shrink < 0.75:  # area-average first: a plain warp would alias the downscaled colour
        w2, h2 = max(1, round(wc * shrink)), max(1, round(hc * shrink))
        src = cv2.resize(color, (w2, h2), interpolation=cv2.INTER_AREA)
        k_src = scale_intrinsics(k_color, w2 / wc, h2 / hc)
    out = _warp(src, k_src, k_depth, wd, hd, cv2.INTER_LINEAR, 0)
    return out, CameraIntrinsics(*k_depth, width=wd, height=hd), out_labels, True


def _warp(img: np.ndarray, k_src: Intrinsics4, k_dst: Intrinsics4, w: int, h: int, interp: int,
          border: int) -> np.ndarray:
    """Resample `img` (seen with `k_src`) into a (h, w) image seen with `k_dst` from the same centre."""
    ax, ay = k_src[0] / k_dst[0], k_src[1] / k_dst[1]
    m = np.array([[ax, 0.0, k_src[2] - ax * k_dst[2]], [0.0, ay, k_src[3] - ay * k_dst[3]]], np.float64)
    if img.dtype == np.int32 and interp == cv2.INTER_NEAREST:
        # cv2.warpAffine has no int32 path for all builds: go through float64, exact for labels < 2^53
        out = cv2.warpAffine(img.astype(np.float64), m, (w, h), flags=interp | cv2.WARP_INVERSE_MAP,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=border)
        return out.astype(np.int32)
    return cv2.warpAffine(img, m, (w, h), flags=interp | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT,
                          borderValue=border)
