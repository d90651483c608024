"""Image -> network input tensor, and the geometry to map network outputs back to the image.

Coordinates are continuous with pixel i covering [i, i + 1) (the convention of cv2.resize), so an
input coordinate is u = x * scale_x + pad_x and maps back exactly with the inverse.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from panoptic_mapping.segmentation.model_config import PreprocessConfig
from panoptic_mapping.segmentation.types import SegmentationError


@dataclass(frozen=True)
class Letterbox:
    """Fit a (src_w x src_h) image into (dst_w x dst_h): scale, then pad (centred)."""

    src_w: int
    src_h: int
    dst_w: int
    dst_h: int
    scale_x: float
    scale_y: float
    pad_x: int
    pad_y: int

    @classmethod
    def fit(
        cls, src_w: int, src_h: int, dst_w: int, dst_h: int, keep_aspect: bool = True, center: bool = True
    ) -> Letterbox:
        """center=True: ultralytics LetterBox (size rounded, padding split evenly, the odd pixel
        right/bottom); center=False: YOLOX `preproc` (size floored, image at the top-left corner)."""
        if not keep_aspect:
            return cls(src_w, src_h, dst_w, dst_h, dst_w / src_w, dst_h / src_h, 0, 0)
        r = min(dst_w / src_w, dst_h / src_h)
        if center:
            new_w, new_h = min(round(src_w * r), dst_w), min(round(src_h * r), dst_h)
            pad_x, pad_y = (dst_w - new_w) // 2, (dst_h - new_h) // 2
        else:
            new_w, new_h = max(min(math.floor(src_w * r), dst_w), 1), max(min(math.floor(src_h * r), dst_h), 1)
            pad_x = pad_y = 0
        return cls(src_w, src_h, dst_w, dst_h, new_w / src_w, new_h / src_h, pad_x, pad_y)

    @classmethod
    def for_config(cls, src_w: int, src_h: int, dst_w: int, dst_h: int, cfg: PreprocessConfig) -> Letterbox:
        """The letterbox a (resolved) pre-processing config describes."""
        return cls.fit(src_w, src_h, dst_w, dst_h, keep_aspect=cfg.letterbox, center=cfg.pad_position != "top_left")

    @property
    def content_size(self) -> tuple[int, int]:
        """(width, height) of the resized image inside the input."""
        return round(self.src_w * self.scale_x), round(self.src_h * self.scale_y)

    def apply(self, image: np.ndarray, pad_value: int) -> np.ndarray:
        """Resize (bilinear) and pad an (H, W, C) image to the network input size."""
        new_w, new_h = self.content_size
        if (new_w, new_h) != (self.src_w, self.src_h):
            image = cv2.resize(image, (new_w, new_h), interpolation=cv2.INTER_LINEAR)
        right, bottom = self.dst_w - new_w - self.pad_x, self.dst_h - new_h - self.pad_y
        if self.pad_x or self.pad_y or right or bottom:
            image = cv2.copyMakeBorder(image, self.pad_y, bottom, self.pad_x, right, cv2.BORDER_CONSTANT,
                                       value=(pad_value,) * 4)
        return image

    def boxes_to_source(self, xyxy: np.ndarray) -> np.ndarray:
        """(N, 4) x0, y0, x1, y1 in input coordinates -> source image coordinates, clipped to it."""
        out = np.empty_like(np.asarray(xyxy, np.float64))
        out[:, [0, 2]] = (xyxy[:, [0, 2]] - self.pad_x) / self.scale_x
        out[:, [1, 3]] = (xyxy[:, [1, 3]] - self.pad_y) / self.scale_y
        out[:, [0, 2]] = out[:, [0, 2]].clip(0, self.src_w)
        out[:, [1, 3]] = out[:, [1, 3]].clip(0, self.src_h)
        return out

    def content_in_grid(self, grid_w: int, grid_h: int) -> tuple[int, int, int, int]:
        """The resized image's region (x0, y0, x1, y1) in a (grid_w x grid_h) map covering the input,
        e.g. a semantic logit map at 1/4 resolution."""
        fx, fy = grid_w / self.dst_w, grid_h / self.dst_h
        new_w, new_h = self.content_size
        x0, y0 = round(self.pad_x * fx), round(self.pad_y * fy)
        x1, y1 = round((self.pad_x + new_w) * fx), round((self.pad_y + new_h) * fy)
        return x0, y0, max(x1, x0 + 1), max(y1, y0 + 1)


def box_pixels(xyxy: np.ndarray, width: int, height: int) -> np.ndarray:
    """Continuous boxes -> integer pixel ranges [c0, c1) x [r0, r1) of the pixels whose centre lies
    inside (so a box from 100.0 to 200.0 covers exactly columns 100..199)."""
    xyxy = np.asarray(xyxy, np.float64).reshape(-1, 4)
    out = np.ceil(xyxy - 0.5).astype(np.int64)
    out[:, [0, 2]] = out[:, [0, 2]].clip(0, width)
    out[:, [1, 3]] = out[:, [1, 3]].clip(0, height)
    return out


def input_size(cfg: PreprocessConfig, model_shape: list[object] | tuple[object, ...]) -> tuple[int, int]:
    """(width, height) of the network input: from the config, else the model's static input shape."""
    if cfg.input_size:
        return int(cfg.input_size[0]), int(cfg.input_size[1])
    hw = static_input_hw(model_shape, cfg.layout)
    if hw is None:
        raise SegmentationError(
            f"the model's input shape {list(model_shape)} is dynamic; set preprocess.input_size: [width, height] "
            "in its config"
        )
    return hw[1], hw[0]


def static_input_hw(model_shape: list[object] | tuple[object, ...], layout: str = "NCHW") -> tuple[int, int] | None:
    """(height, width) of an image input (N, 3, H, W), (3, H, W) or NHWC when both are fixed, else None."""
    dims = list(model_shape)
    if len(dims) == 3:  # no batch dimension (torchvision detection exports)
        dims = [1, *dims]
    hw = dims[2:4] if layout == "NCHW" else dims[1:3]
    if len(hw) != 2 or not all(isinstance(d, int) and not isinstance(d, bool) and d > 0 for d in hw):
        return None
    return int(hw[0]), int(hw[1])  # type: ignore[call-overload]  # checked to be positive ints above


def make_input(color_rgb: np.ndarray, cfg: PreprocessConfig, box: Letterbox) -> np.ndarray:
    """(H, W, 3) uint8 RGB -> (1, 3, h, w) or (1, h, w, 3) float32 tensor. `auto` values of `cfg`
    take the YOLOv5/v8 defaults; resolve the config for its convention first (`resolved`)."""
    cfg = cfg.resolved(None)
    assert cfg.scale is not None and cfg.mean is not None and cfg.std is not None and cfg.pad_value is not None
    img = color_rgb[:, :, ::-1] if cfg.color_order == "BGR" else color_rgb
    img = box.apply(np.ascontiguousarray(img), cfg.pad_value)
    x = img.astype(np.float32)
    if cfg.scale != 1:
        x *= np.float32(cfg.scale)
    if any(cfg.mean):
        x -= np.asarray(cfg.mean, np.float32)
    if any(s != 1 for s in cfg.std):
        x /= np.asarray(cfg.std, np.float32)
    if cfg.layout == "NCHW":
        x = x.transpose(2, 0, 1)
    return np.ascontiguousarray(x[None])


def logit(p: float) -> float:
    """Inverse sigmoid: a probability threshold as a threshold on raw logits."""
    return math.log(p / (1.0 - p))
