"""Simulated RGB-D camera: renderer + depth-noise model -> the project's `RGBDFrame`s.

`RGBDSensorSimulator` builds the ray-casting scene once and renders any number of frames from it;
`frame()` / `frames()` wrap the result as `panoptic_mapping.dataio.frame.RGBDFrame` with the
ground-truth label image in `extras['labels']`, exactly what the loaders yield for real data.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np

from recon_core.frame import CameraIntrinsics, RGBDFrame
from scene_recon.synthetic.depth_noise import DepthNoiseConfig, apply_depth_noise
from scene_recon.synthetic.items import RenderItem
from scene_recon.synthetic.renderer import RaycastRenderer, RenderConfig


@dataclass
class CameraConfig:
    """Pinhole camera (Kinect/PrimeSense-like 640x480 defaults, OpenCV pixel-centre convention)."""

    width: int = 640
    height: int = 480
    fx: float = 525.0
    fy: float = 525.0
    cx: float = 319.5
    cy: float = 239.5

    def intrinsics(self) -> CameraIntrinsics:
        return CameraIntrinsics(self.fx, self.fy, self.cx, self.cy, self.width, self.height)


@dataclass
class SensorConfig:
    """Everything that defines the simulated RGB-D sensor."""

    camera: CameraConfig = field(default_factory=CameraConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    depth_noise: DepthNoiseConfig = field(default_factory=DepthNoiseConfig)
    #: frame_id written into the produced RGBDFrames.
    frame_id: str = "camera_color_optical_frame"
    #: Also put the clean depth / camera-frame normals / true pose into `RGBDFrame.extras`
    #: ('depth_clean', 'normals', 'pose_true'); off by default to keep frames light.
    extras_clean_depth: bool = False
    extras_normals: bool = False
    extras_true_pose: bool = False


@dataclass
class SimulatedFrame:
    """One rendered view. Depth in metres (0 = invalid), labels int32 (0 = none)."""

    color: np.ndarray  # (H, W, 3) uint8 RGB
    depth: np.ndarray  # (H, W) float32, noisy sensor depth
    depth_clean: np.ndarray  # (H, W) float32, exact z-depth
    labels: np.ndarray  # (H, W) int32 item labels
    normals: np.ndarray  # (H, W, 3) float32 unit normals in the camera optical frame (0 = none)
    pose: np.ndarray  # (4, 4) float64 true camera-to-map pose


class RGBDSensorSimulator:
    """Renders noisy RGB-D frames of a fixed set of items from arbitrary poses.

    The Open3D ray-casting scene is built once in the constructor; `render` only casts rays,
    shades and adds noise (see `benchmark` in the tests / report for timings).
    """

    def __init__(
        self,
        items: Sequence[RenderItem],
        intrinsics: CameraIntrinsics | None = None,
        config: SensorConfig | None = None,
    ) -> None:
        self.config = config or SensorConfig()
        self.intrinsics = intrinsics or self.config.camera.intrinsics()
        self.renderer = RaycastRenderer(items, self.config.render)

    @property
    def items(self) -> list[RenderItem]:
        return self.renderer.items

    def render(self, pose: np.ndarray, rng: np.random.Generator | None = None) -> SimulatedFrame:
        """Render the view from `pose`; `rng` drives colour and depth noise (None: seed 0)."""
        rng = rng if rng is not None else np.random.default_rng(0)
        hits, color = self.renderer.render(pose, self.intrinsics, rng)
        depth = apply_depth_noise(
            hits.depth,
            self.config.depth_noise,
            rng,
            incidence_cos=hits.view_cos,
            focal_px=self.intrinsics.fx,
        )
        return SimulatedFrame(
            color=color,
            depth=depth,
            depth_clean=hits.depth,
            labels=hits.labels,
            normals=hits.normals,
            pose=hits.pose,
        )

    def to_rgbd_frame(
        self,
        sim: SimulatedFrame,
        index: int = 0,
        timestamp_ns: int = 0,
        reported_pose: np.ndarray | None = None,
    ) -> RGBDFrame:
        """Wrap a `SimulatedFrame` as an `RGBDFrame` (labels in extras['labels']).

        reported_pose: the pose to publish (e.g. from `add_pose_noise`); default the true pose.
        """
        extras: dict[str, np.ndarray] = {"labels": sim.labels}
        if self.config.extras_clean_depth:
            extras["depth_clean"] = sim.depth_clean
        if self.config.extras_normals:
            extras["normals"] = sim.normals
        if self.config.extras_true_pose:
            extras["pose_true"] = sim.pose
        return RGBDFrame(
            color=sim.color,
            depth=sim.depth,
            intrinsics=self.intrinsics,
            pose=sim.pose if reported_pose is None else np.asarray(reported_pose, dtype=np.float64),
            timestamp_ns=int(timestamp_ns),
            index=int(index),
            frame_id=self.config.frame_id,
            extras=extras,
        )

    def frame(
        self,
        pose: np.ndarray,
        rng: np.random.Generator | None = None,
        index: int = 0,
        timestamp_ns: int = 0,
        reported_pose: np.ndarray | None = None,
    ) -> RGBDFrame:
        """Render and wrap one frame."""
        return self.to_rgbd_frame(self.render(pose, rng), index, timestamp_ns, reported_pose)

    def frames(
        self,
        poses: np.ndarray,
        timestamps_ns: np.ndarray | Sequence[int] | None = None,
        seed: int = 0,
        reported_poses: np.ndarray | None = None,
        fps: float = 30.0,
    ) -> Iterator[RGBDFrame]:
        """Lazily render a sequence (e.g. a `CameraTrajectory`'s poses), deterministic per seed.

        Each frame gets its own child generator (`SeedSequence(seed).spawn`), so frame k looks the
        same whether or not earlier frames were rendered. Timestamps default to index / fps.
        """
        poses = np.asarray(poses, dtype=np.float64)
        n = poses.shape[0]
        if timestamps_ns is None:
            timestamps_ns = np.round(np.arange(n) / fps * 1e9).astype(np.int64)
        stamps = np.asarray(timestamps_ns, dtype=np.int64)
        if stamps.shape[0] != n or (reported_poses is not None and len(reported_poses) != n):
            raise ValueError("poses, timestamps and reported poses must have the same length")
        children = np.random.SeedSequence(seed).spawn(n)
        for i in range(n):
            rng = np.random.default_rng(children[i])
            reported = None if reported_poses is None else reported_poses[i]
            yield self.frame(poses[i], rng, index=i, timestamp_ns=int(stamps[i]), reported_pose=reported)
