"""Result and intermediate types of 2D panoptic segmentation, shared by every backend.

A backend turns an image into *candidates* (a binary mask, a project class and a score each);
`panoptic.assemble` paints them into one non-overlapping label image, the `PanopticSegmentation`
that the mapper and the ROS service consume. Masks are kept as bounding-box crops (`MaskCrop`):
most instances are small, and a 640x480 full-size mask per instance would dominate the run time.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from recon_core.classes import ClassInfo
from recon_core.errors import SegmentationError


@dataclass(frozen=True)
class Segment:
    """One segment of a frame's panoptic segmentation (mirrors `scene_recon_interfaces/SegmentInfo`).

    `id` is the segment's value in the label image. `instance_id` numbers the thing instances of
    this frame only (0 for stuff): like a real network, ids carry no identity across frames, so the
    mapper must do data association itself.
    """

    id: int
    class_id: int
    class_name: str
    is_thing: bool
    instance_id: int
    score: float
    #: Tight box of the segment's pixels: (x, y, w, h) in pixels.
    box: tuple[int, int, int, int]
    #: Number of pixels of the segment in the label image.
    area: int = 0


@dataclass
class PanopticSegmentation:
    """The per-frame output of every backend.

    labels: (H, W) int32, 0 = no segment, otherwise a `Segment.id`.
    latency_ms: wall time the backend spent on this image (pre-processing to final labels).
    """

    labels: np.ndarray
    segments: list[Segment] = field(default_factory=list)
    latency_ms: float = 0.0

    def __post_init__(self) -> None:
        if self.labels.ndim != 2 or self.labels.dtype != np.int32:
            raise SegmentationError(
                f"labels must be a 2D int32 array, got {self.labels.dtype} with shape {self.labels.shape}"
            )

    @classmethod
    def empty(cls, height: int, width: int) -> PanopticSegmentation:
        return cls(np.zeros((height, width), np.int32), [])

    @property
    def shape(self) -> tuple[int, int]:
        h, w = self.labels.shape
        return int(h), int(w)

    def segment(self, segment_id: int) -> Segment:
        for s in self.segments:
            if s.id == segment_id:
                return s
        raise KeyError(f"no segment with id {segment_id}; ids: {[s.id for s in self.segments]}")

    def mask(self, segment_id: int) -> np.ndarray:
        """Full-size boolean mask of one segment."""
        return self.labels == segment_id

    @property
    def things(self) -> list[Segment]:
        return [s for s in self.segments if s.is_thing]

    @property
    def stuff(self) -> list[Segment]:
        return [s for s in self.segments if not s.is_thing]


@dataclass
class MaskCrop:
    """A binary mask stored as its crop: pixel (x + c, y + r) is set where `mask[r, c]`."""

    x: int
    y: int
    mask: np.ndarray  # (h, w) bool

    @property
    def height(self) -> int:
        return int(self.mask.shape[0])

    @property
    def width(self) -> int:
        return int(self.mask.shape[1])

    @property
    def area(self) -> int:
        return int(np.count_nonzero(self.mask))

    @property
    def slices(self) -> tuple[slice, slice]:
        return slice(self.y, self.y + self.height), slice(self.x, self.x + self.width)

    @classmethod
    def from_full(cls, mask: np.ndarray) -> MaskCrop | None:
        """Crop a full-size mask to its bounding box; None when it is empty."""
        rows = np.flatnonzero(mask.any(axis=1))
        if rows.size == 0:
            return None
        cols = np.flatnonzero(mask.any(axis=0))
        y0, y1, x0, x1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
        return cls(x0, y0, np.ascontiguousarray(mask[y0:y1, x0:x1], dtype=bool))

    def to_full(self, shape: tuple[int, int]) -> np.ndarray:
        out = np.zeros(shape, bool)
        out[self.slices] = self.mask
        return out

    def tight(self) -> MaskCrop | None:
        """The same pixels with the crop shrunk to their bounding box; None when empty."""
        inner = MaskCrop.from_full(self.mask)
        if inner is None:
            return None
        return MaskCrop(self.x + inner.x, self.y + inner.y, inner.mask)

    def padded(self, pad: int, shape: tuple[int, int]) -> MaskCrop:
        """The same pixels in a crop grown by `pad` on every side, clipped to an image of `shape`."""
        h, w = shape
        x0, y0 = max(self.x - pad, 0), max(self.y - pad, 0)
        x1, y1 = min(self.x + self.width + pad, w), min(self.y + self.height + pad, h)
        out = np.zeros((y1 - y0, x1 - x0), bool)
        out[self.y - y0 : self.y - y0 + self.height, self.x - x0 : self.x - x0 + self.width] = self.mask
        return MaskCrop(x0, y0, out)

    def union(self, other: MaskCrop) -> MaskCrop:
        x0, y0 = min(self.x, other.x), min(self.y, other.y)
        x1 = max(self.x + self.width, other.x + other.width)
        y1 = max(self.y + self.height, other.y + other.height)
        out = np.zeros((y1 - y0, x1 - x0), bool)
        for m in (self, other):
            out[m.y - y0 : m.y - y0 + m.height, m.x - x0 : m.x - x0 + m.width] |= m.mask
        return MaskCrop(x0, y0, out)

    def touches_border(self, shape: tuple[int, int]) -> bool:
        """True when a set pixel lies on the image border (the object is cut off by the frame)."""
        h, w = shape
        m = self.mask
        return bool(
            (self.y == 0 and m[0].any())
            or (self.x == 0 and m[:, 0].any())
            or (self.y + self.height == h and m[-1].any())
            or (self.x + self.width == w and m[:, -1].any())
        )


@dataclass
class SegmentCandidate:
    """A backend's raw output for one segment, before the panoptic painting resolves overlaps."""

    mask: MaskCrop
    class_info: ClassInfo
    score: float

    @property
    def is_thing(self) -> bool:
        return self.class_info.is_thing
