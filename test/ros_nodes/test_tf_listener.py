"""The TF listener over DDS: `time_range` tells whether TF has arrived up to a stamp, so a frame that came before
the pose of its instant waits for it instead of taking the previous pose held forward (which the lookup's
50 ms extrapolation tolerance would give: a played bag's map then depended on callback order)."""

from __future__ import annotations

import os

import numpy as np
import pytest
from testsupport.ros import domain_id, spin_until

from panoptic_mapping.dataio.transforms import make_transform

pytestmark = pytest.mark.ros
T0 = 5 * 10**9
PERIOD = 33_333_333  # 30 fps


def test_time_range_says_when_tf_has_arrived_up_to_a_stamp():
    import rclpy
    from tf2_msgs.msg import TFMessage

    from ros_nodes.conversions import make_transform_stamped
    from ros_nodes.qos import TF_DYNAMIC
    from ros_nodes.tf_listener import TFListener

    os.environ["ROS_DOMAIN_ID"] = str(domain_id("spare1"))
    rclpy.init()
    pub_node, sub_node = rclpy.create_node("tf_talker"), rclpy.create_node("tf_listener_under_test")
    try:
        listener = TFListener(sub_node)
        pub = pub_node.create_publisher(TFMessage, "/tf", TF_DYNAMIC)
        poses = [make_transform([0.1 * i, 0.0, 1.5], [0.0, 0.0, np.sin(0.05 * i), np.cos(0.05 * i)]) for i in range(3)]

        def send(i: int) -> None:
            pub.publish(TFMessage(transforms=[make_transform_stamped(poses[i], "map", "cam", T0 + i * PERIOD)]))

        assert listener.time_range("map", "cam") is None  # nothing known yet: the lookup says what is missing
        assert spin_until(sub_node, lambda: pub.get_subscription_count() > 0, 10)
        send(0)
        assert spin_until(sub_node, lambda: listener.time_range("map", "cam") is not None, 10)
        assert listener.time_range("map", "cam") == (T0, T0)  # the next frame's TF has not arrived
        # what waiting avoids: the next frame's pose looked up now is the previous sample held forward
        np.testing.assert_allclose(listener.lookup("map", "cam", T0 + PERIOD), poses[0])
        send(1)
        send(2)
        assert spin_until(sub_node, lambda: listener.time_range("map", "cam") == (T0, T0 + 2 * PERIOD), 10)
        np.testing.assert_allclose(listener.lookup("map", "cam", T0 + PERIOD), poses[1], atol=1e-12)
        # static edges only: no time range (nothing to wait for)
        listener.buffer.add("cam", "lens", 0, (0.0, 0.0, 0.01), (0.0, 0.0, 0.0, 1.0), static=True)
        assert listener.time_range("cam", "lens") is None
    finally:
        pub_node.destroy_node()
        sub_node.destroy_node()
        rclpy.shutdown()
