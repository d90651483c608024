"""A played recording's poses may come late: reliable /tf resends a sample lost beside big images only at
the writer's next heartbeat (3 s in Fast DDS). The mapper (tf_reliable) waits for them instead of
skipping the frames: every frame is integrated with its own pose, none is counted `no_tf`."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from testsupport.ros import domain_id, spin_until

pytestmark = pytest.mark.ros

K = (60.0, 60.0, 31.5, 23.5)
LATE_S = 1.5  # each pose is sent this long after its images


@pytest.mark.parametrize("executor", ["events", "multi_threaded"])
def test_mapper_waits_for_poses_that_come_late_over_reliable_tf(tmp_path, executor):
    import rclpy
    from sensor_msgs.msg import CameraInfo, Image
    from std_msgs.msg import String
    from tf2_msgs.msg import TFMessage

    from recon_core.frame import CameraIntrinsics
    from ros_nodes.conversions import (
        depth_to_image,
        intrinsics_to_camera_info,
        make_transform_stamped,
        rgb_to_image,
    )
    from ros_nodes.qos import SENSOR_RECORDING, STATUS, TF_DYNAMIC

    domain = str(domain_id("spare3"))
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=domain)
    os.environ["ROS_DOMAIN_ID"] = domain
    mapper = subprocess.Popen([sys.executable, "-m", "ros_nodes.mapper_node", "--ros-args",
                               "-p", f"data_root:={tmp_path}", "-p", "use_segmentation:=false",
                               "-p", "gravity_check:=false", "-p", "tf_reliable:=true", "-p", "in_order:=true",
                               "-p", "status_period_s:=0.5", "-p", f"executor:={executor}"],
                              env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    rclpy.init()
    node = rclpy.create_node("late_tf_camera")
    statuses: list[dict] = []
    try:
        node.create_subscription(String, "mapper_status", lambda m: statuses.append(json.loads(m.data)), STATUS)
        pubs = {t: node.create_publisher(Image, t, SENSOR_RECORDING)
                for t in ("/camera/color/image_raw", "/camera/depth/image_rect_raw")}
        info_pub = node.create_publisher(CameraInfo, "/camera/color/camera_info", SENSOR_RECORDING)
        tf_pub = node.create_publisher(TFMessage, "/tf", TF_DYNAMIC)
        everyone = [*pubs.values(), info_pub, tf_pub]
        assert spin_until(node, lambda: all(p.get_subscription_count() > 0 for p in everyone) and bool(statuses),
                          60), "mapper node did not come up"
        spin_until(node, lambda: False, 1.0)
        intr = CameraIntrinsics(*K, 64, 48)
        color = np.full((48, 64, 3), 120, np.uint8)
        depth = np.full((48, 64), 1.5, np.float32)
        stamps = [10**9 + i * 200_000_000 for i in range(3)]
        for stamp in stamps:
            info_pub.publish(intrinsics_to_camera_info(intr, stamp, "cam"))
            pubs["/camera/color/image_raw"].publish(rgb_to_image(color, stamp, "cam"))
            pubs["/camera/depth/image_rect_raw"].publish(depth_to_image(depth, stamp, "cam"))
            spin_until(node, lambda: False, 0.2)
        spin_until(node, lambda: False, LATE_S)  # the poses come well after the 0.5 s a live frame waits
        for i, stamp in enumerate(stamps):
            pose = np.eye(4)
            pose[0, 3] = 0.1 * i
            tf_pub.publish(TFMessage(transforms=[make_transform_stamped(pose, "map", "cam", stamp)]))
        assert spin_until(node, lambda: statuses[-1]["frames_integrated"] == 3, 30), statuses[-1]
    finally:
        node.destroy_node()
        rclpy.shutdown()
        mapper.terminate()
        log = mapper.communicate(timeout=30)[0]
    counters = statuses[-1]["counters"]
    assert counters.get("no_tf", 0) == 0 and counters.get("no_camera_info", 0) == 0, (counters, log[-2000:])
    assert counters.get("tf_extrapolated", 0) == 0, counters
