"""Camera drivers publish RELIABLE or BEST_EFFORT: the mapper integrates a BEST_EFFORT stream too (a
RELIABLE subscription would never match it). The RELIABLE case is the player's (test_ros_graph_e2e)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from testsupport.ros import domain_id, spin_until

pytestmark = pytest.mark.ros
REPO_ROOT = Path(__file__).resolve().parents[2]


def test_mapper_integrates_a_best_effort_camera(tmp_path):
    import rclpy
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo, Image
    from std_msgs.msg import String
    from tf2_msgs.msg import TFMessage

    from panoptic_mapping.dataio import CameraIntrinsics
    from ros_nodes.conversions import depth_to_image, intrinsics_to_camera_info, make_transform_stamped, rgb_to_image
    from ros_nodes.qos import STATUS, TF_DYNAMIC

    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain_id("spare1")),
               PYTHONPATH=os.pathsep.join([str(REPO_ROOT), os.environ.get("PYTHONPATH", "")]))
    os.environ["ROS_DOMAIN_ID"] = env["ROS_DOMAIN_ID"]
    log = tmp_path / "mapper.log"
    mapper = subprocess.Popen([sys.executable, "-m", "ros_nodes.mapper_node", "--ros-args", "-p",
                               "use_segmentation:=false", "-p", "status_period_s:=0.5", "-p", f"data_root:={tmp_path}"],
                              env=env, stdout=log.open("w"), stderr=subprocess.STDOUT)
    rclpy.init()
    node = rclpy.create_node("best_effort_camera")
    try:
        best_effort = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
        pub_color = node.create_publisher(Image, "/camera/color/image_raw", best_effort)
        pub_depth = node.create_publisher(Image, "/camera/depth/image_rect_raw", best_effort)
        pub_info = node.create_publisher(CameraInfo, "/camera/color/camera_info", best_effort)
        pub_tf = node.create_publisher(TFMessage, "/tf", TF_DYNAMIC)
        statuses: list[dict] = []
        node.create_subscription(String, "mapper_status", lambda m: statuses.append(json.loads(m.data)), STATUS)
        intr = CameraIntrinsics(60, 60, 31.5, 23.5, 64, 48)
        color = np.full((48, 64, 3), 128, np.uint8)
        depth = np.full((48, 64), 1.5, np.float32)
        pose = np.eye(4)
        k, deadline = 0, time.monotonic() + 60
        while time.monotonic() < deadline and not (statuses and statuses[-1]["frames_integrated"] >= 10):
            stamp = 10**9 + k * 100_000_000
            pose[0, 3] = 0.001 * k
            pub_tf.publish(TFMessage(transforms=[make_transform_stamped(pose, "map", "cam", stamp)]))
            pub_info.publish(intrinsics_to_camera_info(intr, stamp, "cam"))
            pub_color.publish(rgb_to_image(color, stamp, "cam"))
            pub_depth.publish(depth_to_image(depth, stamp, "cam"))
            k += 1
            spin_until(node, lambda: False, 0.1)  # ~10 Hz
        assert statuses and statuses[-1]["frames_integrated"] >= 10, (statuses[-1:], log.read_text()[-3000:])
    finally:
        node.destroy_node()
        rclpy.shutdown()
        mapper.send_signal(signal.SIGTERM)
        try:
            rc = mapper.wait(timeout=60)
        except subprocess.TimeoutExpired:
            mapper.kill()
            rc = mapper.wait()
    text = log.read_text()
    assert rc == 0 and "Traceback" not in text, text[-3000:]
    assert "/camera/color/image_raw: publishers offer BEST_EFFORT; subscribed BEST_EFFORT" in text, text[-3000:]
