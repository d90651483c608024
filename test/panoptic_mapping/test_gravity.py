"""Gravity from depth: up of a tilted world frame recovered from rendered rooms, degenerate views
fall back to +z with a reason, alignment files, and `scene-recon map --gravity` on a tilted TUM folder."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from panoptic_mapping.gravity import (
    GravityConfig,
    GravityEstimator,
    alignment_from_estimate,
    angle_deg,
    load_alignment,
    rotation_to_z,
)
from recon_core.errors import InputError
from scene_recon.synthetic.geometry import look_at_pose
from scene_recon.synthetic.sensor import RGBDSensorSimulator
from scene_recon.synthetic.toy_scene import make_toy_scene

Z = np.array([0.0, 0.0, 1.0])
#: The issue's example: a world frame tilted 63 deg about x and 20 deg about y (TUM-like).
TILT = np.eye(4)
TILT[:3, :3] = Rotation.from_euler("xy", [63, 20], degrees=True).as_matrix()
TILT[:3, 3] = [0.3, -1.0, 2.0]
#: Views of the toy room (6 m x 5 m, 2.6 m high) from a hand-held height, pitched 15-45 deg down.
VIEWS = [((-1.5, -1.0, 1.4), (1.0, 1.0, 0.5)), ((1.0, -1.5, 1.5), (-1.0, 1.0, 0.6)),
         ((2.0, 1.0, 1.3), (-2.0, -1.0, 0.8)), ((-2.0, 1.5, 1.6), (2.0, -1.0, 0.4)),
         ((0.0, 0.0, 1.5), (2.5, 0.0, 1.0)), ((0.5, 1.5, 1.2), (-1.0, -2.0, 0.7))]


@pytest.fixture(scope="module")
def sim() -> RGBDSensorSimulator:
    return RGBDSensorSimulator(make_toy_scene(8, 0).items)


def _views(sim, views, seed: int = 0, roll: float = 0.0) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    out = []
    for eye, target in views:
        pose = look_at_pose(np.array(eye, float), np.array(target, float), roll=np.radians(roll))
        out.append((sim.render(pose, rng).depth, pose))  # noisy sensor depth
    return out


def _estimate(sim, frames, world: np.ndarray, cfg: GravityConfig | None = None):
    est = GravityEstimator(cfg)
    for depth, pose in frames:
        est.add_frame(depth, sim.intrinsics, world @ pose)
    return est.estimate()


@pytest.mark.parametrize("tilt", [(63, 20), (0, 0), (-30, 75), (10, 0)])
def test_up_of_a_tilted_room_is_recovered_within_2_deg(sim, tilt):
    world = np.eye(4)
    world[:3, :3] = Rotation.from_euler("xy", tilt, degrees=True).as_matrix()
    true_up = world[:3, :3] @ Z
    g = _estimate(sim, _views(sim, VIEWS), world)
    assert g.ok and g.method == "floor", g
    assert angle_deg(g.up, true_up) < 2.0
    assert g.angle_deg == pytest.approx(angle_deg(true_up, Z), abs=2.0)
    assert g.support > 0.9  # floor, walls and box sides: a Manhattan room
    transform, note = alignment_from_estimate(g, GravityConfig())
    if tilt == (0, 0):  # a z-up input: estimated within noise of +z and left exactly as it is
        assert g.angle_deg < 1.0 and np.array_equal(transform, np.eye(4)) and "not rotated" in note
    else:
        assert angle_deg(transform[:3, :3] @ true_up, Z) < 2.0 and "map rotated" in note


def test_the_default_tilt_maps_the_floor_to_horizontal(sim):
    g = _estimate(sim, _views(sim, VIEWS, seed=3), TILT)
    transform, _ = alignment_from_estimate(g, GravityConfig())
    # the aligned world is the original z-up one up to a yaw (smallest rotation): its z axis is z
    back = transform[:3, :3] @ TILT[:3, :3]
    assert angle_deg(back @ Z, Z) < 2.0
    assert g.angle_deg == pytest.approx(angle_deg(TILT[:3, :3] @ Z, Z), abs=2.0)


def test_one_wall_filling_the_view_gives_no_estimate_and_keeps_z(sim):
    # 1 m in front of the x = 3 wall, level: nothing but that wall in view (no floor, no second wall)
    views = [((2.0, -0.5 + 0.3 * k, 1.3), (4.0, -0.5 + 0.3 * k, 1.3)) for k in range(4)]
    frames = _views(sim, views)
    for world in (np.eye(4), TILT):
        g = _estimate(sim, frames, world)
        assert not g.ok and "fewer than two wall directions" in g.reason
        assert len(g.modes) == 1 and g.modes[0][1] == pytest.approx(1.0)
        transform, note = alignment_from_estimate(g, GravityConfig())
        assert np.array_equal(transform, np.eye(4)) and "no estimate" in note and "+z is taken as up" in note


def _pitched(pitch_deg: float, eye=(0.0, 0.0, 1.4), yaws=(0.0, 0.3, 0.6, 0.9, 1.2, 1.5)):
    """Views from `eye` pitched `pitch_deg` down, at these yaws (rad)."""
    e = np.array(eye)
    p = np.radians(pitch_deg)
    return [(tuple(e), tuple(e + np.array([np.cos(y) * np.cos(p), np.sin(y) * np.cos(p), -np.sin(p)])))
            for y in yaws]


@pytest.mark.parametrize("pitch", [70, 78])
def test_cameras_looking_steeply_down_at_the_floor(sim, pitch):
    # image up is ~70 deg from up: beyond max_tilt_deg, but the cameras do not roll (image x horizontal)
    g = _estimate(sim, _views(sim, _pitched(pitch)), TILT)
    assert g.ok and g.method == "floor" and angle_deg(g.camera_up, TILT[:3, :3] @ Z) > 60
    assert angle_deg(g.up, TILT[:3, :3] @ Z) < 2.0
    # rolled cameras give no such licence: rolled 40 deg about the optical axis, image x is 12-13 deg
    # off horizontal (steep pitch makes roll mostly a yaw): accepted by the default max_roll_deg (20),
    # refused by 5 deg: no estimate, +z kept
    frames = _views(sim, _pitched(pitch), roll=40.0)
    assert _estimate(sim, frames, TILT).ok
    rolled = _estimate(sim, frames, TILT, GravityConfig(max_roll_deg=5.0))
    assert not rolled.ok and "without roll" in rolled.reason


def test_a_lone_wall_ahead_of_a_camera_pitched_down_is_no_ceiling(sim):
    # 0.5 m from the x = 3 wall, looking 45 deg down at it: only that wall in view
    views = _pitched(45, eye=(2.5, 0.0, 2.0), yaws=[-0.1, 0.0, 0.1])
    frames = _views(sim, views)
    assert all(d[d > 0].max() < 1.6 for d, _ in frames)  # nothing but the near wall
    g = _estimate(sim, frames, TILT)
    assert not g.ok and len(g.modes) == 1


def test_two_walls_without_floor_still_give_up(sim):
    # looking level into the corner (3, 2.5) from 1.4 m: floor and ceiling are out of the view cone
    views = [((1.9, 1.4, 1.3), (3.0 + dx, 2.5 - dx, 1.3)) for dx in (-0.3, 0.0, 0.3)]
    world = np.eye(4)
    world[:3, :3] = Rotation.from_euler("zx", [30, -40], degrees=True).as_matrix()
    g = _estimate(sim, _views(sim, views), world)
    assert g.ok and g.method == "walls"
    assert angle_deg(g.up, world[:3, :3] @ Z) < 2.0


def test_empty_depth_gives_no_estimate():
    from recon_core.frame import CameraIntrinsics

    est = GravityEstimator()
    est.add_frame(np.zeros((48, 64), np.float32), CameraIntrinsics(50, 50, 31.5, 23.5, 64, 48), np.eye(4))
    g = est.estimate()
    assert not g.ok and g.reason


def test_rotation_to_z_and_alignment_files(tmp_path):
    for up in ([0, 0, 1], [0, 0, -1], [1, 2, 3], [0.2, -0.9, 0.1]):
        r = rotation_to_z(np.array(up, float))
        assert np.allclose(r @ (np.array(up) / np.linalg.norm(up)), Z) and np.allclose(r.T @ r, np.eye(3))
        assert np.linalg.det(r) == pytest.approx(1.0)
    f = tmp_path / "align.txt"
    np.savetxt(f, TILT)
    assert np.allclose(load_alignment(f), TILT)
    np.savetxt(f, TILT[:3, :3])
    assert np.allclose(load_alignment(f)[:3, :3], TILT[:3, :3])
    bad = TILT.copy()
    bad[:3, 0] *= 2
    np.savetxt(f, bad)
    with pytest.raises(InputError, match="not a proper rotation"):
        load_alignment(f)
    f.write_text("1 2 3\n")
    with pytest.raises(InputError, match="4x4"):
        load_alignment(f)
    with pytest.raises(InputError, match="cannot read"):
        load_alignment(tmp_path / "missing.txt")


# ---------------------------------------------------------------------------------------- the CLI
K_SMALL = (131.25, 131.25, 79.5, 59.5)


@pytest.fixture(scope="module")
def tilted_tum(tmp_path_factory):
    """A TUM folder of the toy room (160x120) whose world frame is TILT: up is 65 deg from its +z."""
    from testsupport.frames import tum

    from recon_core.frame import CameraIntrinsics

    room = make_toy_scene(6, 1)
    small = RGBDSensorSimulator(room.items, CameraIntrinsics(*K_SMALL, 160, 120))
    folder = tmp_path_factory.mktemp("tilted") / "tum"
    depths, poses = [], []
    for k in range(16):
        yaw = 2 * np.pi * k / 16
        pose = look_at_pose(np.array([0.0, 0.0, 1.4]), np.array([2 * np.cos(yaw), 2 * np.sin(yaw), 0.5]))
        depths.append(np.round(small.render(pose, np.random.default_rng(k)).depth * 5000).astype(np.uint16))
        poses.append(TILT @ pose)
    tum(folder, 16, np.full((120, 160, 3), 128, np.uint8), depths, poses)
    return folder


def _map(folder, out, *extra):
    from scene_recon.cli import main

    argv = ["map", str(folder), "--out", str(out), "--segmenter", "none", "--intrinsics",
            ",".join(str(v) for v in K_SMALL), "--json", *extra]
    return main(argv)


def _floor_share(out) -> float:
    """Share of the map's vertices in its most populated 4 cm height slice: a horizontal floor."""
    import trimesh

    z = trimesh.load(out / "meshes" / "0.ply", force="mesh", process=False).vertices[:, 2]
    counts, _ = np.histogram(z, bins=np.arange(z.min(), z.max() + 0.04, 0.04))
    return float(counts.max() / len(z))


def test_map_gravity_auto_rotates_a_tilted_recording_into_z_up(tilted_tum, tmp_path, capsys):
    assert _map(tilted_tum, tmp_path / "auto", "--gravity", "auto") == 0
    summary = json.loads(capsys.readouterr().out)
    meta = json.loads((tmp_path / "auto" / "map.json").read_text())
    t = np.array(meta["gravity_alignment"])
    assert angle_deg(t[:3, :3] @ TILT[:3, :3] @ Z, Z) < 2.0  # the true up became +z
    g = summary["gravity"]
    assert g["mode"] == "auto" and g["applied"] and g["estimate"]["method"] == "floor"
    assert g["rotation_deg"] == pytest.approx(angle_deg(TILT[:3, :3] @ Z, Z), abs=2.0)
    assert meta["gravity"] == g
    auto_share = _floor_share(tmp_path / "auto")
    # trusting the tilted input (z) leaves the floor 65 deg off horizontal
    assert _map(tilted_tum, tmp_path / "z", "--gravity", "z") == 0
    z = json.loads(capsys.readouterr().out)["gravity"]
    assert z["mode"] == "z" and not z["applied"]
    # trusted but checked: the 65 deg is said (it passed silently on real 7-Scenes frames, 117 deg off)
    assert z["estimate"]["angle_from_z_deg"] == pytest.approx(angle_deg(TILT[:3, :3] @ Z, Z), abs=2.0)
    assert "but its up is estimated" in z["note"]
    assert auto_share > 0.3 and _floor_share(tmp_path / "z") < 0.05
    # a transform file: the same as the truth
    f = tmp_path / "align.txt"
    np.savetxt(f, np.linalg.inv(TILT))
    assert _map(tilted_tum, tmp_path / "file", "--gravity", str(f)) == 0
    g = json.loads(capsys.readouterr().out)["gravity"]
    assert g["mode"] == "file" and g["applied"]
    assert _floor_share(tmp_path / "file") == pytest.approx(auto_share, abs=0.05)


def test_run_forwards_gravity_to_map():
    import argparse

    from scene_recon.commands.run_cmd import _map_argv

    ns = argparse.Namespace(source="in", model=None, model_config=None, classes=None, max_depth=None, min_depth=None,
                            gravity="z")
    from pathlib import Path

    argv = _map_argv(ns, "none", Path("out"))
    assert argv[argv.index("--gravity") + 1] == "z"


def test_mapper_keeps_its_alignment_through_save_and_load(tmp_path):
    from panoptic_mapping.mapper import PanopticMapper

    m = PanopticMapper()
    m.set_alignment(np.linalg.inv(TILT), {"mode": "file", "note": "test"})
    pose = TILT @ look_at_pose(np.array([1.0, 0.0, 1.5]), np.array([2.0, 0.0, 1.0]))
    assert np.allclose(m.local_pose(pose)[:3, 3], [1.0, 0.0, 1.5])  # back in the z-up room
    m.recentre(np.array([1.0, 0.0, 0.0]))
    assert np.allclose(m.local_pose(pose)[:3, 3], [0.0, 0.0, 1.5])  # alignment first, then the offset
    m.save(tmp_path)
    loaded = PanopticMapper.load(tmp_path)
    assert np.allclose(loaded.alignment, np.linalg.inv(TILT)) and loaded.gravity == {"mode": "file", "note": "test"}
    m.frames_integrated = 1
    with pytest.raises(ValueError, match="before the first frame"):
        m.set_alignment(np.eye(4))


# ---------------------------------------------------------------------------------------- refinement
def _drifting_tum(folder, drift_deg: float):
    """The toy room as a TUM folder (160x120) in the TILT world whose first 3 poses are off by
    ``drift_deg`` about x (a tracker settling at the start): the window sees a tilted floor."""
    from testsupport.frames import tum

    from recon_core.frame import CameraIntrinsics

    room = make_toy_scene(6, 1)
    small = RGBDSensorSimulator(room.items, CameraIntrinsics(*K_SMALL, 160, 120))
    err = np.eye(4)
    err[:3, :3] = Rotation.from_euler("x", drift_deg, degrees=True).as_matrix()
    depths, poses = [], []
    for k in range(24):
        yaw = 2 * np.pi * k / 12
        pose = look_at_pose(np.array([0.0, 0.0, 1.4]), np.array([2 * np.cos(yaw), 2 * np.sin(yaw), 0.5]))
        depths.append(np.round(small.render(pose, np.random.default_rng(k)).depth * 5000).astype(np.uint16))
        poses.append(TILT @ err @ pose if k < 3 else TILT @ pose)
    tum(folder, 24, np.full((120, 160, 3), 128, np.uint8), depths, poses)
    return folder


def _refined_map(folder, out, refine_every_n: int = 2):
    from panoptic_mapping.dataio import DataInputConfig
    from panoptic_mapping.pipeline import map_recording, write_map_outputs

    data = DataInputConfig(intrinsics=list(K_SMALL))
    data.gravity.window_frames, data.gravity.stride, data.gravity.refine_every_n = 3, 1, refine_every_n
    mapper, run = map_recording(folder, None, data_config=data, progress=False)
    write_map_outputs(out, mapper, run)
    return mapper.gravity


def test_gravity_is_refined_as_the_map_grows_and_a_wrong_start_is_reported(tmp_path, caplog):
    """The estimate of the first frames is kept (the map cannot turn under way); frames mapped after
    the window refine it: a start 6 deg off is reported, with the alignment to map again with."""
    import logging

    folder = _drifting_tum(tmp_path / "drift", 6.0)
    with caplog.at_level(logging.WARNING):
        g = _refined_map(folder, tmp_path / "out")
    applied = np.array(g["input_up"])
    true_up = TILT[:3, :3] @ Z
    assert angle_deg(applied, true_up) > 4.0  # the window saw the drifted poses only
    r = g["refined"]
    assert r["ok"] and r["frames_added"] == 11 and r["frames"] == 14  # 3 of the window + every 2nd of 21
    assert r["residual_deg"] > 2.0 and r["suggest_file"]
    assert angle_deg(np.array(r["up_in_input"]), true_up) < 2.0
    assert "map again with --gravity OUT/gravity_refined.txt" in caplog.text
    suggestion = np.loadtxt(tmp_path / "out" / "gravity_refined.txt")
    assert angle_deg(suggestion[:3, :3] @ true_up, Z) < 2.0
    assert json.loads((tmp_path / "out" / "map.json").read_text())["gravity"]["refined"] == r
    # mapped again with it: the whole recording agrees with the up applied, no file
    from panoptic_mapping.dataio import DataInputConfig
    from panoptic_mapping.pipeline import map_recording

    data = DataInputConfig(intrinsics=list(K_SMALL))
    data.gravity.mode = str(tmp_path / "out" / "gravity_refined.txt")
    mapper, _run = map_recording(folder, None, data_config=data, progress=False)
    assert angle_deg(np.array(mapper.gravity["input_up"]), true_up) < 2.0
    assert "refined" not in mapper.gravity  # a file or z is trusted: nothing to refine


def test_a_consistent_recording_refines_to_the_same_up_and_writes_no_file(tmp_path):
    folder = _drifting_tum(tmp_path / "steady", 0.0)
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "gravity_refined.txt").write_text("stale\n")  # from an earlier run
    g = _refined_map(folder, tmp_path / "out")
    assert g["refined"]["ok"] and g["refined"]["residual_deg"] < 1.0 and not g["refined"]["suggest_file"]
    assert not (tmp_path / "out" / "gravity_refined.txt").exists()
    assert "refined" not in _refined_map(folder, tmp_path / "off", refine_every_n=0)


def test_gravity_monitor_checks_a_stream_it_cannot_rotate(sim):
    """The ROS mapper node trusts its TF map frame: its first frames tell whether that frame is z up."""
    from panoptic_mapping.gravity import GravityMonitor

    frames = _views(sim, VIEWS)
    cfg = GravityConfig(window_frames=3, stride=2)
    for world, tilted in ((TILT, True), (np.eye(4), False)):
        mon = GravityMonitor(cfg)
        results = [mon.feed(depth, sim.intrinsics, world @ pose) for depth, pose in frames]
        assert [r is not None for r in results] == [False] * 4 + [True, False]  # frames 1, 3, 5: done at 5
        assert mon.done and mon.result is not None and mon.result.frames == 3
        assert angle_deg(mon.result.up, world[:3, :3] @ Z) < 2.0
        rec = mon.record()
        assert rec["mode"] == "tf" and not rec["applied"] and rec["estimate"]["ok"]
        assert bool(mon.warning) == tilted and ("the fixed frame's up is" in rec["note"]) == tilted
    assert GravityMonitor(cfg).feed(frames[0][0], sim.intrinsics, None) is None  # no pose: nothing


def test_gravity_monitor_reports_a_provisional_estimate_before_its_window_is_full(sim):
    """A short bag (or frames lost under load) must not leave a saved map without its gravity check."""
    from panoptic_mapping.gravity import GravityMonitor

    frames = _views(sim, VIEWS)
    mon = GravityMonitor(GravityConfig(window_frames=10, stride=1))
    empty = mon.record()
    assert empty["mode"] == "tf" and "estimate" not in empty and "no posed frame" in empty["note"]
    for depth, pose in frames[:2]:
        assert mon.feed(depth, sim.intrinsics, TILT @ pose) is None
    rec = mon.record()
    assert rec["provisional"] and rec["estimate"]["ok"] and rec["estimate"]["frames"] == 2
    assert "the fixed frame's up is" in rec["note"] and "provisional: 2 of 10" in rec["note"]
    assert not mon.done  # the check goes on collecting
    for depth, pose in frames[2:]:
        mon.feed(depth, sim.intrinsics, TILT @ pose)
    assert mon.estimator is not None and mon.estimator.frames == len(frames)


def _rot_x(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])


def test_accelerometer_check_finds_a_tilted_frames_up_and_refuses_what_is_not_gravity():
    from panoptic_mapping.gravity import STANDARD_GRAVITY, AccelerometerCheck

    rng = np.random.default_rng(0)
    cfg = GravityConfig(imu_samples=200)
    true_up = _rot_x(12.0) @ Z  # the fixed frame's +z is 12 deg off up
    # a robot driving: gravity plus its own accelerations (zero mean) plus sensor noise, one NaN sample
    readings = STANDARD_GRAVITY * true_up + rng.normal(0, 0.3, (200, 3))
    readings[7] = np.nan
    check = AccelerometerCheck(cfg)
    assert check.add(readings[:150]) is None and not check.done
    early = check.record()
    assert early["provisional"] and early["ok"] and early["samples"] == 149
    est = check.add(np.r_[readings[150:], readings[:1]])
    assert est is not None and est.ok and est.method == "imu" and check.done
    assert angle_deg(est.up, true_up) < 0.5 and abs(est.angle_deg - 12.0) < 0.5
    rec = check.record()
    assert not rec["provisional"] and rec["dropped_non_finite"] == 1 and "deg from its +z by the IMU" in rec["note"]
    assert "the fixed frame's up is" in rec["note"]
    # an IMU in g, not m/s^2: refused with the reason, never a made-up up
    in_g = AccelerometerCheck(cfg).add(readings[np.isfinite(readings[:, 0])][:200] / STANDARD_GRAVITY)
    assert in_g is None  # (one reading short: 199 finite)
    units = AccelerometerCheck(GravityConfig(imu_samples=100)).add(np.tile(true_up, (100, 1)))
    assert units is not None and not units.ok and "not about 9.81" in units.reason
    # shaking: readings scattered widely around their mean
    shaky = STANDARD_GRAVITY * Z + rng.normal(0, 6.0, (300, 3))
    shake = AccelerometerCheck(GravityConfig(imu_samples=300, imu_max_g_error=5.0)).add(shaky)
    assert shake is not None and not shake.ok and "shaking" in shake.reason
    nothing = AccelerometerCheck(cfg).record()
    assert not nothing["ok"] and "no finite" in nothing["note"]
