"""The one frame type every loader yields and every stage consumes."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from recon_core.errors import DatasetError


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics of the (depth-registered) color camera, in pixels."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        values = np.array([self.fx, self.fy, self.cx, self.cy], dtype=np.float64)
        if not np.all(np.isfinite(values)) or self.fx <= 0 or self.fy <= 0:
            raise DatasetError(f"invalid camera intrinsics {self}: focal lengths must be finite and > 0")
        if self.width <= 0 or self.height <= 0:
            raise DatasetError(f"invalid image size {self.width}x{self.height} in camera intrinsics")

    @property
    def matrix(self) -> np.ndarray:
        """3x3 camera matrix K (float64)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @classmethod
    def from_matrix(cls, k: np.ndarray, width: int, height: int) -> CameraIntrinsics:
        k = np.asarray(k, dtype=np.float64).reshape(3, 3)
        return cls(float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]), int(width), int(height))

    def scaled(self, factor: float) -> CameraIntrinsics:
        """Intrinsics of the image resized by `factor` (pixel-centre convention)."""
        return CameraIntrinsics(
            self.fx * factor,
            self.fy * factor,
            (self.cx + 0.5) * factor - 0.5,
            (self.cy + 0.5) * factor - 0.5,
            round(self.width * factor),
            round(self.height * factor),
        )


@dataclass
class RGBDFrame:
    """One synchronised RGB-D frame.

    Conventions (all loaders, all stages):
    * `color`: (H, W, 3) uint8, RGB order.
    * `depth`: (H, W) float32 metres, registered to `color`; 0 marks an invalid pixel (NaN, inf and
      negative readings are turned into 0 by the loaders and counted in `invalid_depth_pixels`).
    * `pose`: (4, 4) float64 camera-to-map transform of the optical frame (x right, y down,
      z forward), map frame gravity aligned (z up); None when no pose is known for this frame.
    * `timestamp_ns`: sensor time of the depth image, integer nanoseconds.
    """

    color: np.ndarray
    depth: np.ndarray
    intrinsics: CameraIntrinsics
    pose: np.ndarray | None
    timestamp_ns: int
    index: int = 0
    frame_id: str = ""
    invalid_depth_pixels: int = 0
    extras: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        h, w = self.depth.shape[:2]
        if self.color.shape[:2] != (h, w):
            raise DatasetError(
                f"color {self.color.shape[1]}x{self.color.shape[0]} and depth {w}x{h} differ in size; "
                "depth must be registered to color (e.g. aligned_depth_to_color)"
            )
        if (self.intrinsics.width, self.intrinsics.height) != (w, h):
            raise DatasetError(
                f"camera info says {self.intrinsics.width}x{self.intrinsics.height} but images are {w}x{h}"
            )
        if self.pose is not None:
            pose = np.asarray(self.pose, dtype=np.float64)
            if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
                raise DatasetError(f"frame {self.index}: camera pose must be a finite 4x4 matrix")
            self.pose = pose

    @property
    def timestamp(self) -> float:
        """Timestamp in seconds (float64)."""
        return self.timestamp_ns * 1e-9


def sanitize_depth(depth: np.ndarray) -> tuple[np.ndarray, int]:
    """Return float32 metres with every NaN, inf or negative reading set to 0, and their count."""
    depth = np.asarray(depth, dtype=np.float32)
    bad = ~np.isfinite(depth) | (depth < 0)
    n_bad = int(np.count_nonzero(bad))
    if n_bad:
        depth = np.where(bad, np.float32(0.0), depth)
    return depth, n_bad
