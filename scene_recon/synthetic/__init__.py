"""Synthetic RGB-D data: camera trajectories, ray-cast rendering, sensor noise, overview pictures.

ROS-free and vectorized. Typical use::

    traj = generate_trajectory(room, object_centres, footprints, num_frames=300, fps=30, seed=0)
    sim = RGBDSensorSimulator(items, config=SensorConfig())
    for frame in sim.frames(traj.poses, traj.timestamps_ns, seed=0):
        ...  # panoptic_mapping.dataio.frame.RGBDFrame, labels in frame.extras["labels"]
    render_overview(items, traj.poses, "overview.png", room=room)
"""

from scene_recon.synthetic.depth_noise import DepthNoiseConfig, apply_depth_noise, axial_sigma
from scene_recon.synthetic.geometry import backproject, camera_rotation, look_at_pose, pixel_rays, pose_angles
from scene_recon.synthetic.items import Appearance, RenderItem, label_colors
from scene_recon.synthetic.overview import OverviewConfig, render_overview
from scene_recon.synthetic.renderer import RaycastRenderer, RayHits, RenderConfig, ShadingConfig
from scene_recon.synthetic.sensor import CameraConfig, RGBDSensorSimulator, SensorConfig, SimulatedFrame
from scene_recon.synthetic.trajectory import (
    CameraTrajectory,
    Footprint,
    PoseNoiseConfig,
    RoomBounds,
    TrajectoryConfig,
    add_pose_noise,
    generate_trajectory,
)

__all__ = [
    "Appearance",
    "CameraConfig",
    "CameraTrajectory",
    "DepthNoiseConfig",
    "Footprint",
    "OverviewConfig",
    "PoseNoiseConfig",
    "RGBDSensorSimulator",
    "RayHits",
    "RaycastRenderer",
    "RenderConfig",
    "RenderItem",
    "RoomBounds",
    "SensorConfig",
    "ShadingConfig",
    "SimulatedFrame",
    "TrajectoryConfig",
    "add_pose_noise",
    "apply_depth_noise",
    "axial_sigma",
    "backproject",
    "camera_rotation",
    "generate_trajectory",
    "label_colors",
    "look_at_pose",
    "pixel_rays",
    "pose_angles",
    "render_overview",
]
