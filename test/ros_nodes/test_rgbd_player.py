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


def test_player_publishes_bag_frames(tmp_path):
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
         "-p", "rate:=3.0", "-p", "wait_for_subscribers:=1",
         "-p", "labels_topic_in:=/ground_truth/panoptic_labels"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and min(len(v) for v in got.values()) < N:
            rclpy.spin_once(node, timeout_sec=0.05)
        out, _ = player.communicate(timeout=30)
    finally:
        if player.poll() is None:
            player.kill()
        node.destroy_node()
        rclpy.shutdown()
    assert player.returncode == 0, out
    assert f"played {N} frames" in out
    assert [len(got[k]) for k in ("color", "depth", "labels", "info", "tf")] == [N] * 5
    for i in range(N):
        np.testing.assert_array_equal(image_to_rgb(got["color"][i]), colors[i])
        depth, _n_bad = image_to_depth(got["depth"][i])
        np.testing.assert_allclose(depth, depths[i], atol=1e-6)
        np.testing.assert_array_equal(image_to_labels(got["labels"][i]), labels[i])
        assert camera_info_to_intrinsics(got["info"][i]) == intr
        tf = got["tf"][i].transforms[0]
        assert (tf.header.frame_id, tf.child_frame_id) == ("map", "camera_color_optical_frame")
        np.testing.assert_allclose(transform_to_matrix(tf.transform), poses[i], atol=1e-12)
        assert stamp_to_ns(got["color"][i].header.stamp) == 2 * 10**9 + i * 33_333_333
