"""Back-pressure (issue 24, item 3): the player paces a recording by the mapper's progress
(`mapper_progress`), so a mapper that falls behind is never outrun. Here the "mapper" is this test
process: it takes one frame per 0.25 s (at 30 Hz recorded) and publishes its progress as the mapper
node does; the player must stay at most pace_max_lag frames ahead, and every frame arrives. A mapper that
says it has received nothing yet (starting on loaded cores) is not outrun either: unpaced, a player 8x faster
than recorded sent a whole bag before such a mapper took its first frame, and the readers' history lost 25
of 90 frames (CI, test_ros_run_under_load)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import numpy as np
import pytest
from testsupport.ros import domain_id

pytestmark = pytest.mark.ros
N, W, H = 12, 40, 30
LAG_MAX = 3


def _write_bag(path) -> None:
    from panoptic_mapping.dataio import CameraIntrinsics
    from panoptic_mapping.dataio.bag_writer import RGBDBagWriter
    from panoptic_mapping.dataio.transforms import make_transform

    rng = np.random.default_rng(0)
    intr = CameraIntrinsics(40, 41, 19.5, 14.5, W, H)
    with RGBDBagWriter(path) as w:
        for i in range(N):
            w.write_frame(2 * 10**9 + i * 33_333_333, rng.integers(0, 256, (H, W, 3), dtype=np.uint8),
                          np.full((H, W), 1.5, np.float32), intr, make_transform([0.1 * i, 0, 1.5], [0, 0, 0, 1]))


def _play_against_a_slow_mapper(tmp_path, silent_s: float) -> tuple[int, int, int, str]:
    """Play a bag against this process as a mapper that maps a frame per 0.25 s and, for `silent_s` after the
    first frame arrived, says it has received nothing (as a starting mapper does). Returns (frames received,
    frames done, most frames ever received and not done, the player's output)."""
    import rclpy
    from sensor_msgs.msg import Image
    from std_msgs.msg import String

    from ros_nodes.conversions import stamp_to_ns
    from ros_nodes.qos import PROGRESS_TOPIC, SENSOR_RECORDING, STATUS

    _write_bag(tmp_path / "rec")
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain_id("player")))
    os.environ["ROS_DOMAIN_ID"] = env["ROS_DOMAIN_ID"]
    rclpy.init()
    node = rclpy.create_node("slow_mapper")
    received: list[int] = []
    node.create_subscription(Image, "/camera/color/image_raw",
                             lambda m: received.append(stamp_to_ns(m.header.stamp)), SENSOR_RECORDING)
    from sensor_msgs.msg import CameraInfo
    from tf2_msgs.msg import TFMessage

    from ros_nodes.qos import TF_DYNAMIC

    # every stream has a subscriber (the player waits for them, wait_for_subscribers)
    node.create_subscription(Image, "/camera/depth/image_rect_raw", lambda m: None, SENSOR_RECORDING)
    node.create_subscription(CameraInfo, "/camera/color/camera_info", lambda m: None, SENSOR_RECORDING)
    node.create_subscription(TFMessage, "/tf", lambda m: None, TF_DYNAMIC)
    progress = node.create_publisher(String, PROGRESS_TOPIC, STATUS)
    player = subprocess.Popen(
        [sys.executable, "-m", "ros_nodes.rgbd_player", "--ros-args", "-p", f"source:={tmp_path / 'rec'}",
         "-p", "rate:=1.0", "-p", "wait_for_subscribers:=1", "-p", f"pace_max_lag:={LAG_MAX}"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    done = 0
    most_ahead = 0
    first_at: float | None = None
    try:
        deadline = time.monotonic() + 90
        next_step = time.monotonic()
        while time.monotonic() < deadline and done < N:
            rclpy.spin_once(node, timeout_sec=0.02)
            most_ahead = max(most_ahead, len(received) - done)
            if received and first_at is None:
                first_at = time.monotonic()
            if first_at is not None and time.monotonic() - first_at < silent_s:
                progress.publish(String(data=json.dumps({"oldest_waiting_ns": None, "newest_received_ns": None,
                                                         "backlog": 0})))
                continue
            if received and time.monotonic() >= next_step and done < len(received):
                done += 1  # one frame mapped
                next_step = time.monotonic() + 0.25
            waiting = received[done:]
            progress.publish(String(data=json.dumps({
                "oldest_waiting_ns": waiting[0] if waiting else None,
                "newest_received_ns": received[-1] if received else None, "backlog": len(waiting)})))
        out, _ = player.communicate(timeout=60)
    finally:
        if player.poll() is None:
            player.kill()
        node.destroy_node()
        rclpy.shutdown()
    assert player.returncode == 0, out
    return len(received), done, most_ahead, out


@pytest.mark.parametrize("silent_s", [0.0, 1.0], ids=["mapper-ready", "mapper-silent-at-start"])
def test_the_player_waits_for_a_slow_mapper(tmp_path, silent_s):
    received, done, most_ahead, out = _play_against_a_slow_mapper(tmp_path, silent_s)
    assert received == N == done, (received, out)
    # unpaced, all 12 frames come within 0.4 s; paced, the player is never more than LAG_MAX ahead
    assert most_ahead <= LAG_MAX, (most_ahead, out)
    assert "waited" in out and "for the mapper" in out, out
