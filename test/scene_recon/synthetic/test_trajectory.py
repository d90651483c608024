"""Camera trajectory: inside the room, outside furniture, smooth, level, deterministic."""

from __future__ import annotations

import numpy as np
import pytest

from scene_recon.synthetic import (
    Footprint,
    PoseNoiseConfig,
    RoomBounds,
    TrajectoryConfig,
    add_pose_noise,
    camera_rotation,
    generate_trajectory,
    pose_angles,
)
from scene_recon.synthetic.trajectory import catmull_rom

ROOM = RoomBounds(0.0, 6.0, 0.0, 5.0, 2.6)
OBSTACLES = [
    Footprint.from_bounds(2.4, 2.0, 3.6, 3.0),  # table in the middle
    Footprint((0.6, 4.2), (0.5, 0.3), yaw=0.3),  # cabinet in a corner
    Footprint.from_bounds(4.8, 0.0, 6.0, 1.0),  # shelf against a wall
]
POIS = np.array([[3.0, 2.5, 0.75], [0.6, 4.2, 0.9], [5.4, 0.5, 1.0], [1.0, 1.0, 0.3], [5.5, 4.5, 0.5]])
FPS = 30.0


@pytest.fixture(scope="module")
def traj():
    return generate_trajectory(ROOM, POIS, OBSTACLES, num_frames=450, fps=FPS, seed=3)


def _rotation_angles(poses: np.ndarray) -> np.ndarray:
    rel = np.einsum("fji,fjk->fik", poses[:-1, :3, :3], poses[1:, :3, :3])
    return np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1))


def test_shapes_and_valid_rotations(traj):
    assert len(traj) == 450 and traj.poses.shape == (450, 4, 4) and traj.targets.shape == (450, 3)
    r = traj.poses[:, :3, :3]
    np.testing.assert_allclose(r @ r.transpose(0, 2, 1), np.broadcast_to(np.eye(3), r.shape), atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-9)
    np.testing.assert_allclose(traj.poses[:, 3], [[0, 0, 0, 1]] * 450)
    assert traj.timestamps_ns[0] == 0 and np.all(np.diff(traj.timestamps_ns) == pytest.approx(1e9 / FPS, abs=1))


def test_stays_in_room_and_out_of_obstacles(traj):
    cfg = TrajectoryConfig()
    xy = traj.positions[:, :2]
    slack = 0.1  # wobble and grid discretisation may eat a little of the margin
    assert ROOM.contains(xy, cfg.wall_margin_m - slack).all()
    for obstacle in OBSTACLES:
        assert not obstacle.contains(xy, cfg.obstacle_margin_m - slack).any()
    z = traj.positions[:, 2]
    assert (z >= cfg.min_height_m).all() and (z <= cfg.max_height_m).all()


def test_smooth_motion(traj):
    cfg = TrajectoryConfig()
    step = np.linalg.norm(np.diff(traj.positions, axis=0), axis=1)
    assert step.max() <= cfg.max_speed_mps * (1 + cfg.speed_variation) / FPS + 0.01
    assert step.mean() > 0.05 / FPS  # it does move
    angles = np.degrees(_rotation_angles(traj.poses))
    bound = np.hypot(cfg.max_yaw_rate_deg_s, cfg.max_pitch_rate_deg_s) / FPS + 0.5  # + roll jitter
    assert angles.max() <= bound
    # Second differences are small too (no jerks): acceleration bounded.
    accel = np.linalg.norm(np.diff(traj.positions, 2, axis=0), axis=1) * FPS**2
    assert accel.max() < 3.0


def test_level_and_pitched_down(traj):
    _, pitch, roll = pose_angles(traj.poses)
    assert np.abs(np.degrees(roll)).max() <= 3 * TrajectoryConfig().roll_jitter_deg + 1e-6
    assert np.degrees(np.abs(roll)).mean() < 1.5
    assert np.degrees(pitch).max() <= 0.0 + 1e-6 and np.degrees(pitch).mean() < -5.0
    # The image y axis points (mostly) down: gravity aware.
    assert (traj.poses[:, 2, 1] < -0.5).all()


def test_looks_at_points_of_interest(traj):
    forward = traj.poses[:, :3, 2]
    to_poi = POIS[None, :, :] - traj.positions[:, None, :]
    cos = np.einsum("fi,fpi->fp", forward, to_poi) / np.linalg.norm(to_poi, axis=2)
    # Most of the time (fixations, not turns) a point of interest is within 25 deg of the optical axis.
    assert (cos.max(axis=1) > np.cos(np.radians(25))).mean() > 0.7
    # Over the whole sequence several different objects are looked at.
    assert len(np.unique(np.argmax(cos, axis=1))) >= 3


def test_deterministic_and_seed_dependent(traj):
    again = generate_trajectory(ROOM, POIS, OBSTACLES, num_frames=450, fps=FPS, seed=3)
    np.testing.assert_array_equal(again.poses, traj.poses)
    other = generate_trajectory(ROOM, POIS, OBSTACLES, num_frames=450, fps=FPS, seed=4)
    assert np.abs(other.positions - traj.positions).max() > 0.3


def test_configurable_length_and_no_pois():
    short = generate_trajectory(ROOM, None, [], num_frames=1, fps=FPS, seed=0)
    assert short.poses.shape == (1, 4, 4)
    t = generate_trajectory(ROOM, np.zeros((0, 3)), [], num_frames=60, fps=15.0, seed=0)
    assert len(t) == 60 and np.all(np.isfinite(t.poses))
    assert t.timestamps_ns[-1] == pytest.approx(59 / 15.0 * 1e9, abs=1)


def test_small_cluttered_room_still_works():
    room = RoomBounds(0, 3.0, 0, 2.5, 2.4)
    obstacles = [Footprint.from_bounds(1.2, 0.9, 1.8, 1.6)]
    t = generate_trajectory(room, [[1.5, 1.25, 0.8]], obstacles, num_frames=90, fps=FPS, seed=1)
    assert room.contains(t.positions[:, :2], 0.2).all()
    assert not obstacles[0].contains(t.positions[:, :2], 0.05).any()


def test_no_free_space_raises():
    room = RoomBounds(0, 1.0, 0, 1.0)
    with pytest.raises(ValueError, match="free"):
        generate_trajectory(room, None, [Footprint.from_bounds(-1, -1, 2, 2)], num_frames=10, seed=0)


def test_pose_noise_is_separate_and_bounded(traj):
    noisy = add_pose_noise(traj.poses, PoseNoiseConfig(), np.random.default_rng(0), FPS)
    assert noisy.shape == traj.poses.shape and not np.shares_memory(noisy, traj.poses)
    err = np.linalg.norm(noisy[:, :3, 3] - traj.positions, axis=1)
    assert err.max() < 0.2 and err[-1] > err[0]  # drift accumulates
    assert err[0] < 0.02
    r = noisy[:, :3, :3]
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-9)
    again = add_pose_noise(traj.poses, PoseNoiseConfig(), np.random.default_rng(0), FPS)
    np.testing.assert_array_equal(noisy, again)
    zero = PoseNoiseConfig(0.0, 0.0, 0.0, 0.0, 0.0)
    np.testing.assert_allclose(add_pose_noise(traj.poses, zero, np.random.default_rng(0), FPS), traj.poses, atol=1e-12)


def test_camera_rotation_convention():
    r = camera_rotation(np.array(0.0), np.array(0.0))
    np.testing.assert_allclose(r[:, 2], [1, 0, 0], atol=1e-12)  # looks along +x
    np.testing.assert_allclose(r[:, 0], [0, -1, 0], atol=1e-12)  # image x to the right
    np.testing.assert_allclose(r[:, 1], [0, 0, -1], atol=1e-12)  # image y down
    yaw, pitch, roll = np.array([0.3, -2.0]), np.array([-0.4, 0.1]), np.array([0.02, -0.05])
    pose = np.tile(np.eye(4), (2, 1, 1))
    pose[:, :3, :3] = camera_rotation(yaw, pitch, roll)
    np.testing.assert_allclose(np.stack(pose_angles(pose)), np.stack([yaw, pitch, roll]), atol=1e-12)


def test_catmull_rom_interpolates():
    pts = np.array([[0.0, 0], [1, 0], [1, 1], [0, 1]])
    np.testing.assert_allclose(catmull_rom(pts, np.arange(4.0), closed=True), pts, atol=1e-12)
    np.testing.assert_allclose(catmull_rom(pts, np.arange(4.0)), pts, atol=1e-12)


def test_loop_grows_with_recording_length():
    def extent(frames: int) -> float:
        t = generate_trajectory(ROOM, POIS, [], num_frames=frames, fps=FPS, seed=2)
        return float(np.ptp(t.positions[:, 0]) + np.ptp(t.positions[:, 1]))

    assert extent(1800) > extent(150) + 0.5


def test_trajectory_config_from_yaml(tmp_path):
    from recon_core.config import dump_config, load_config

    path = tmp_path / "traj.yaml"
    dump_config(TrajectoryConfig(), path)
    cfg = load_config(TrajectoryConfig, path, overrides={"pose_noise.jitter_translation_m": 0.01, "laps": 2.0})
    assert cfg.pose_noise.jitter_translation_m == 0.01 and cfg.laps == 2.0
