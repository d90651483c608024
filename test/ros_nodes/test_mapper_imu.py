"""The mapper node's IMU gravity check over DDS: accelerometer readings in the IMU's own frame, rotated
into the map frame by TF, tell that the map frame is tilted; the verdict lands in the saved map."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from testsupport.ros import domain_id, spin_until

pytestmark = pytest.mark.ros


def test_mapper_node_checks_the_map_frames_up_with_an_imu(tmp_path):
    import rclpy
    from scene_recon_interfaces.srv import SaveMap
    from sensor_msgs.msg import Imu
    from tf2_msgs.msg import TFMessage

    from ros_nodes.conversions import make_header, make_transform_stamped
    from ros_nodes.qos import SENSOR_BEST_EFFORT, TF_STATIC

    tilt = np.radians(8.0)  # the map frame's +z is 8 deg off up (about x)
    up_in_map = np.array([0.0, -np.sin(tilt), np.cos(tilt)])
    imu_in_map = np.eye(4)  # the IMU is mounted turned 90 deg about z on a base at (1, 2, 0.3)
    imu_in_map[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    imu_in_map[:3, 3] = [1.0, 2.0, 0.3]
    reading = imu_in_map[:3, :3].T @ (9.80665 * up_in_map)  # what the IMU reads, in its own frame
    domain = str(domain_id("spare2"))
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=domain)
    os.environ["ROS_DOMAIN_ID"] = domain
    proc = subprocess.Popen([sys.executable, "-m", "ros_nodes.mapper_node", "--ros-args",
                             "-p", f"data_root:={tmp_path}", "-p", "imu_topic:=/imu", "-p", "imu_samples:=60",
                             "-p", "gravity_check:=false", "-p", "use_segmentation:=false"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    rclpy.init()
    node = rclpy.create_node("imu_driver")
    saved = None
    try:
        tf_pub = node.create_publisher(TFMessage, "/tf_static", TF_STATIC)
        imu_pub = node.create_publisher(Imu, "/imu", SENSOR_BEST_EFFORT)
        save = node.create_client(SaveMap, "save_map")
        assert save.wait_for_service(timeout_sec=60), "mapper node did not come up"
        tf_pub.publish(TFMessage(transforms=[make_transform_stamped(imu_in_map, "map", "imu_link", 0)]))
        assert spin_until(node, lambda: imu_pub.get_subscription_count() > 0, 30), "no IMU subscription"
        # best effort: what is sent before the mapper's reader has matched this writer in turn is lost for good
        # (a loaded CI run kept fewer than 60 of 120): a grace period, and four times the readings the check needs
        spin_until(node, lambda: False, 1.0)
        rng = np.random.default_rng(0)
        for i in range(240):  # 100 Hz, with the platform's own small accelerations and noise
            msg = Imu(header=make_header(10**9 + i * 10**7, "imu_link"))
            a = reading + rng.normal(0, 0.2, 3)
            msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = (float(v) for v in a)
            imu_pub.publish(msg)
            spin_until(node, lambda: False, 0.01)
        spin_until(node, lambda: False, 1.0)
        fut = save.call_async(SaveMap.Request(path="imu_check"))
        rclpy.spin_until_future_complete(node, fut, timeout_sec=30)
        saved = fut.result()
    finally:
        node.destroy_node()
        rclpy.shutdown()
        proc.terminate()
        log = proc.communicate(timeout=20)[0]
    assert saved is not None and saved.success, log[-3000:]
    imu = json.loads((tmp_path / "imu_check" / "map.json").read_text())["gravity"]["imu"]
    assert imu["ok"] and not imu["provisional"] and imu["samples"] >= 60, (imu, log[-2000:])
    assert abs(imu["angle_from_z_deg"] - 8.0) < 1.0
    assert np.degrees(np.arccos(np.clip(np.dot(imu["up_in_input"], up_in_map), -1, 1))) < 1.0
    assert "deg from its +z by the IMU" in imu["note"] and "deg from its +z by the IMU" in log
