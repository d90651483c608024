"""RGB-D simulator end to end: RGBDFrames with labels, noise on/off, determinism, overview."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from recon_core.frame import RGBDFrame
from scene_recon.synthetic import (
    DepthNoiseConfig,
    OverviewConfig,
    RGBDSensorSimulator,
    SensorConfig,
    generate_trajectory,
    render_overview,
)
from scene_recon.synthetic.overview import _overview_camera, _peel_cast
from scene_recon.synthetic.trajectory import Footprint


@pytest.fixture(scope="module")
def sim(scene_items, intrinsics):
    return RGBDSensorSimulator(scene_items, intrinsics, SensorConfig(extras_clean_depth=True))


@pytest.fixture(scope="module")
def poses(scene_items, room):
    obstacles = [Footprint.from_mesh(it.mesh) for it in scene_items if it.label >= 10]
    centres = np.array([it.mesh.bounds.mean(axis=0) for it in scene_items if it.label >= 10])
    return generate_trajectory(room, centres, obstacles, num_frames=6, fps=30.0, seed=0).poses


def test_render_outputs(sim, view_pose):
    out = sim.render(view_pose, np.random.default_rng(0))
    assert out.color.shape == (120, 160, 3) and out.color.dtype == np.uint8
    assert out.depth.dtype == np.float32 and out.depth_clean.dtype == np.float32
    assert out.labels.dtype == np.int32 and out.normals.shape == (120, 160, 3)
    both = (out.depth > 0) & (out.depth_clean > 0)
    assert both.mean() > 0.8  # dropouts are a minority
    err = np.abs(out.depth[both] - out.depth_clean[both])
    # Disparity steps at fx = 130 px are coarse (~8 cm at 2.5 m), hence the loose bound.
    assert np.median(err) < 0.04 and err.max() < 0.3
    assert (out.depth[out.depth_clean == 0] == 0).all()


def test_noise_free_sensor_is_exact(scene_items, intrinsics, view_pose):
    cfg = SensorConfig(depth_noise=DepthNoiseConfig(noise_free=True))
    out = RGBDSensorSimulator(scene_items, intrinsics, cfg).render(view_pose, np.random.default_rng(0))
    np.testing.assert_array_equal(out.depth, out.depth_clean)


def test_frames_are_rgbd_frames_with_labels(sim, poses):
    frames = list(sim.frames(poses, seed=7))
    assert len(frames) == len(poses)
    for i, frame in enumerate(frames):
        assert isinstance(frame, RGBDFrame)
        assert frame.index == i and frame.frame_id == sim.config.frame_id
        assert frame.extras["labels"].shape == frame.depth.shape and frame.extras["labels"].dtype == np.int32
        assert "depth_clean" in frame.extras
        np.testing.assert_array_equal(frame.pose, poses[i])
        assert frame.intrinsics == sim.intrinsics
    assert frames[1].timestamp_ns - frames[0].timestamp_ns == pytest.approx(1e9 / 30, abs=1)
    again = list(sim.frames(poses, seed=7))
    for a, b in zip(frames, again, strict=True):
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_array_equal(a.color, b.color)
    other = next(iter(sim.frames(poses[:1], seed=8)))
    assert not np.array_equal(other.depth, frames[0].depth)


def test_reported_poses_and_length_checks(sim, poses):
    reported = poses.copy()
    reported[:, 0, 3] += 0.05
    frames = list(sim.frames(poses[:2], seed=0, reported_poses=reported[:2]))
    np.testing.assert_array_equal(frames[1].pose, reported[1])
    with pytest.raises(ValueError):
        next(iter(sim.frames(poses, timestamps_ns=[0, 1])))


def test_sensor_config_loads_from_yaml(tmp_path):
    from recon_core.config import dump_config, load_config

    path = tmp_path / "sensor.yaml"
    dump_config(SensorConfig(), path)
    cfg = load_config(SensorConfig, path, overrides={"depth_noise.noise_free": True, "camera.width": 320})
    assert cfg.depth_noise.noise_free and cfg.camera.width == 320
    assert dataclasses.replace(cfg.render.shading).light_direction == SensorConfig().render.shading.light_direction


def test_overview_sees_into_the_room(scene_items, room, poses, tmp_path):
    cfg = OverviewConfig(width=320, height=240)
    from scene_recon.synthetic import RaycastRenderer

    renderer = RaycastRenderer(scene_items)
    pose, intr = _overview_camera(scene_items, room, cfg)
    hits = _peel_cast(renderer, pose, intr, room, cfg)
    seen = set(np.unique(hits.labels).tolist())
    assert {1, 10, 11, 12} <= seen  # floor and every object visible from above
    assert 2 not in seen  # the ceiling is peeled away
    image = render_overview(scene_items, poses, tmp_path / "overview.png", room=room, config=cfg, renderer=renderer)
    assert image.shape == (240, 320, 3) and image.dtype == np.uint8
    back = cv2.imread(str(tmp_path / "overview.png"))
    assert back.shape == (240, 320, 3)
    no_path = render_overview(scene_items, None, room=room, config=cfg, renderer=renderer)
    assert (np.abs(image.astype(int) - no_path).sum(axis=2) > 60).sum() > 50  # the path is drawn
