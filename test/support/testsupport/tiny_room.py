"""A tiny rendered room (floor, table, cup, chair as boxes) and posed RGB-D frames of it, for mapper tests."""

from __future__ import annotations

import numpy as np
import trimesh

from panoptic_mapping.config import MapperConfig
from panoptic_mapping.dataio import CameraIntrinsics, RGBDFrame
from scene_recon.synthetic.geometry import look_at_pose
from scene_recon.synthetic.items import RenderItem
from scene_recon.synthetic.renderer import RaycastRenderer

INTR = CameraIntrinsics(160.0, 160.0, 79.5, 59.5, 160, 120)
#: Label-image values of the room's objects.
IDS = {"floor": 1, "table": 2, "cup": 3, "chair": 4}
#: Camera positions that see the table, cup and chair from several sides.
EYES = [(0.0, -0.5, 1.4), (0.1, 0.0, 1.5), (0.0, 0.5, 1.4), (0.3, -0.3, 1.6), (0.3, 0.4, 1.3)]


def box(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    m = trimesh.creation.box(extents=hi - lo)
    m.apply_translation((lo + hi) / 2)
    return m


def room_meshes() -> dict[str, trimesh.Trimesh]:
    return {
        "floor": box([-3, -3, -0.05], [3, 3, 0]),
        "table": box([1.2, -0.4, 0], [2.0, 0.4, 0.7]),
        "cup": box([1.55, -0.05, 0.7], [1.65, 0.05, 0.82]),
        "chair": box([1.3, 0.8, 0], [1.7, 1.2, 0.5]),
    }


def room_renderer(meshes: dict[str, trimesh.Trimesh] | None = None) -> RaycastRenderer:
    meshes = meshes or room_meshes()
    return RaycastRenderer([RenderItem(m, IDS[k], name=k) for k, m in meshes.items()])


def render_frame(renderer, eye, target=(1.6, 0.2, 0.4), index=0) -> tuple[RGBDFrame, np.ndarray]:
    """(frame, label image) seen from `eye` looking at `target`."""
    pose = look_at_pose(np.array(eye, float), np.array(target, float))
    hits, rgb = renderer.render(pose, INTR)
    frame = RGBDFrame(rgb, hits.depth.astype(np.float32), INTR, pose, index * 100_000_000, index=index)
    return frame, hits.labels.astype(np.int32)


def tiny_mapper_config(min_segment_points: int, min_segment_pixels: int) -> MapperConfig:
    """The full mapper for these 160x120 frames: every frame integrated with its masks (no keyframe gate, no
    still-camera skip) and segment floors scaled to the frames' few pixels (300 points are for 640x480)."""
    cfg = MapperConfig(mode="full", downsample=1)
    cfg.keyframes.enabled = False
    cfg.static.enabled = False
    cfg.fusion.min_segment_points = min_segment_points
    cfg.depth_segmentation.min_segment_pixels = min_segment_pixels
    return cfg
