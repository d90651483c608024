"""The player node publishes a real bag over DDS; a subscriber in this process checks every frame."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from testsupport.ros import domain_id

from panoptic_mapping.dataio import CameraIntrinsics
from panoptic_mapping.dataio.bag_writer import RGBDBagWriter
from panoptic_mapping.dataio.transforms import make_transform

pytestmark = pytest.mark.ros
N, W, H = 12, 40, 30


def _write_bag(path: Path):
    rng = np.random.default_rng(0)
    colors = rng.integers(0, 256, (N, H, W, 3), dtype=np.uint8)
    depths = (rng.integers(400, 5000, (N, H, W)) / 1000.0).astype(np.float32)
    labels = rng.integers(0, 9, (N, H, W)).astype(np.int32)
    poses = [make_transform([0.1 * i, 0, 1.5], [0, 0, np.sin(0.05 * i), np.cos(0.05 * i)]) for i in range(N)]
    intr = CameraIntrinsics(40, 41, 19.5, 14.5, W, H)
    with RGBDBagWriter(path) as w:
        for i in range(N):
            w.write_frame(2 * 10**9 + i * 33_333_333, colors[i], depths[i], intr, poses[i], labels[i])
    return colors, depths, labels, poses, intr


def _wait_for_exit(node, player) -> str:
    """The player's output once it exited, then what arrived meanwhile (a loaded machine delivered the
    last /clock sample after the caller had stopped spinning)."""
    import rclpy

    out, _ = player.communicate(timeout=30)
    drain = time.monotonic() + 1.0
    while time.monotonic() < drain:
        rclpy.spin_once(node, timeout_sec=0.01)
    return out


@pytest.mark.parametrize("stride", [1, 2])
def test_player_publishes_bag_frames(tmp_path, stride):
    """Every frame of the bag in order with its pose, intrinsics and labels; with `stride` (a preset's
    data.stride through `ros-run --preset`) every stride-th one only."""
    import rclpy
    from sensor_msgs.msg import CameraInfo, Image
    from tf2_msgs.msg import TFMessage

    from ros_nodes.conversions import (
        camera_info_to_intrinsics,
        image_to_depth,
        image_to_labels,
        image_to_rgb,
        stamp_to_ns,
        transform_to_matrix,
    )
    from ros_nodes.qos import SENSOR_RELIABLE, TF_DYNAMIC

    colors, depths, labels, poses, intr = _write_bag(tmp_path / "rec")
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain_id("player")))
    os.environ["ROS_DOMAIN_ID"] = env["ROS_DOMAIN_ID"]
    rclpy.init()
    node = rclpy.create_node("player_checker")
    got: dict[str, list] = {"color": [], "depth": [], "labels": [], "info": [], "tf": []}
    node.create_subscription(Image, "/camera/color/image_raw", got["color"].append, SENSOR_RELIABLE)
    node.create_subscription(Image, "/camera/depth/image_rect_raw", got["depth"].append, SENSOR_RELIABLE)
    node.create_subscription(Image, "/ground_truth/panoptic_labels", got["labels"].append, SENSOR_RELIABLE)
    node.create_subscription(CameraInfo, "/camera/color/camera_info", got["info"].append, SENSOR_RELIABLE)
    node.create_subscription(TFMessage, "/tf", got["tf"].append, TF_DYNAMIC)
    player = subprocess.Popen(
        [sys.executable, "-m", "ros_nodes.rgbd_player", "--ros-args", "-p", f"source:={tmp_path / 'rec'}",
         "-p", "rate:=3.0", "-p", "wait_for_subscribers:=1", "-p", f"stride:={stride}",
         "-p", "labels_topic_in:=/ground_truth/panoptic_labels"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 60
        played = list(range(0, N, stride))
        while time.monotonic() < deadline and min(len(v) for v in got.values()) < len(played):
            rclpy.spin_once(node, timeout_sec=0.05)
        out = _wait_for_exit(node, player)
    finally:
        if player.poll() is None:
            player.kill()
        node.destroy_node()
        rclpy.shutdown()
    assert player.returncode == 0, out
    assert f"played {len(played)} frames" in out
    assert [len(got[k]) for k in ("color", "depth", "labels", "info", "tf")] == [len(played)] * 5
    for k, i in enumerate(played):
        np.testing.assert_array_equal(image_to_rgb(got["color"][k]), colors[i])
        depth, _n_bad = image_to_depth(got["depth"][k])
        np.testing.assert_allclose(depth, depths[i], atol=1e-6)
        np.testing.assert_array_equal(image_to_labels(got["labels"][k]), labels[i])
        assert camera_info_to_intrinsics(got["info"][k]) == intr
        tf = got["tf"][k].transforms[0]
        assert (tf.header.frame_id, tf.child_frame_id) == ("map", "camera_color_optical_frame")
        np.testing.assert_allclose(transform_to_matrix(tf.transform), poses[i], atol=1e-12)
        assert stamp_to_ns(got["color"][k].header.stamp) == 2 * 10**9 + i * 33_333_333


def test_player_clock_start_offset_rate_and_pause(tmp_path):
    """/clock carries the recording's time, `start_offset_s` skips the first frames, `rate` scales the timing
    and `~/set_paused` holds frames and clock until resumed."""
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import CameraInfo, Image
    from std_srvs.srv import SetBool
    from testsupport.ros import call_service
    from tf2_msgs.msg import TFMessage

    from ros_nodes.conversions import stamp_to_ns
    from ros_nodes.qos import SENSOR_RELIABLE

    _write_bag(tmp_path / "rec")
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain_id("player")))
    os.environ["ROS_DOMAIN_ID"] = env["ROS_DOMAIN_ID"]
    rclpy.init()
    node = rclpy.create_node("player_clock_checker")
    frames: list[tuple[float, int]] = []  # (arrival, stamp)
    clocks: list[tuple[float, int]] = []
    node.create_subscription(Image, "/camera/color/image_raw",
                             lambda m: frames.append((time.monotonic(), stamp_to_ns(m.header.stamp))), SENSOR_RELIABLE)
    node.create_subscription(Clock, "/clock", lambda m: clocks.append((time.monotonic(), stamp_to_ns(m.clock))),
                             QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    # the player starts once every stream has a subscriber (wait_for_subscribers)
    node.create_subscription(Image, "/camera/depth/image_rect_raw", lambda m: None, SENSOR_RELIABLE)
    node.create_subscription(CameraInfo, "/camera/color/camera_info", lambda m: None, SENSOR_RELIABLE)
    node.create_subscription(TFMessage, "/tf", lambda m: None, SENSOR_RELIABLE)
    pause = node.create_client(SetBool, "rgbd_player/set_paused")
    player = subprocess.Popen(
        [sys.executable, "-m", "ros_nodes.rgbd_player", "--ros-args", "-p", f"source:={tmp_path / 'rec'}",
         "-p", "rate:=0.5", "-p", "start_offset_s:=0.1", "-p", "publish_clock:=true", "-p", "wait_for_subscribers:=1"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    t0 = 2 * 10**9
    try:
        assert pause.wait_for_service(timeout_sec=60)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and len(frames) < 2:
            rclpy.spin_once(node, timeout_sec=0.01)
        res, _ = call_service(node, pause, SetBool.Request(data=True))
        assert res.success and "paused" in res.message
        paused_at = time.monotonic()
        n_frames, n_clock = len(frames), max(c for _, c in clocks)
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.01)
        assert len(frames) <= n_frames + 1  # (one may have been on its way)
        held = [c for t, c in clocks if t > paused_at + 0.2]
        assert all(c <= frames[-1][1] for c in held), "the clock ran on while paused"
        res, _ = call_service(node, pause, SetBool.Request(data=False))
        assert res.success and "playing" in res.message
        resumed_at = time.monotonic()
        while time.monotonic() < deadline and len(frames) < N - 4:
            rclpy.spin_once(node, timeout_sec=0.01)
        out = _wait_for_exit(node, player)
    finally:
        if player.poll() is None:
            player.kill()
        node.destroy_node()
        rclpy.shutdown()
    assert player.returncode == 0, out
    # start offset 0.1 s: the frames at 0, 33, 67 and 100 - 1e-7 ms are skipped
    assert [s for _, s in frames] == [t0 + i * 33_333_333 for i in range(4, N)], [s - t0 for _, s in frames]
    # rate 0.5: 67 ms of wall time per frame, the pause not counted (a lower bound: a loaded machine is slower)
    played = (frames[n_frames - 1][0] - frames[0][0]) + (frames[-1][0] - resumed_at)
    assert played >= 0.8 * (len(frames) - 2) * 2 * 0.0333, played
    stamps = [c for _, c in clocks]
    assert stamps == sorted(stamps) and stamps[-1] == frames[-1][1] and stamps[0] >= frames[0][1]
    assert n_clock >= frames[n_frames - 1][1]
