"""Camera-topic subscriptions that match RELIABLE and BEST_EFFORT publishers alike.

Real drivers differ: some publish images RELIABLE, many (and `ros2 bag play` of a sensor-QoS
recording) BEST_EFFORT. A RELIABLE subscription never matches a BEST_EFFORT publisher; a
BEST_EFFORT subscription matches both but then receives a RELIABLE stream best-effort (a third of
640x480 frames lost across processes, REFERENCE.md). So, like `ros2 bag record`, the subscription
adapts to what is offered: RELIABLE while every publisher of the topic offers it, BEST_EFFORT as soon
as one does not; it looks at the publishers every `check_period_s` and recreates itself when that changes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.callback_groups import CallbackGroup
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from ros_nodes.qos import SENSOR_BEST_EFFORT, SENSOR_RELIABLE
from ros_nodes.runner import steady_timer


def offered_reliability(node: Node, topic: str) -> ReliabilityPolicy | None:
    """BEST_EFFORT when any publisher of `topic` offers only that, RELIABLE when all offer reliable,
    None when there is no publisher."""
    infos = node.get_publishers_info_by_topic(node.resolve_topic_name(topic))
    if not infos:
        return None
    if any(i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for i in infos):
        return ReliabilityPolicy.BEST_EFFORT
    return ReliabilityPolicy.RELIABLE


class SensorSubscription:
    """A subscription to a sensor topic whose reliability follows the topic's publishers."""

    def __init__(self, node: Node, msg_type: Any, topic: str, callback: Callable[[Any], None],
                 callback_group: CallbackGroup | None = None, check_period_s: float = 1.0, depth: int = 0) -> None:
        """`depth`: history depth (0: the sensor profiles' own)."""
        self._node, self._type, self._topic = node, msg_type, topic
        self._callback, self._group = callback, callback_group
        self._depth = depth
        self.reliability = ReliabilityPolicy.RELIABLE
        self._sub = node.create_subscription(msg_type, topic, callback, self._profile(), callback_group=callback_group)
        self.switches = 0
        steady_timer(node, check_period_s, self.check, callback_group)

    def _profile(self) -> QoSProfile:
        base = SENSOR_BEST_EFFORT if self.reliability == ReliabilityPolicy.BEST_EFFORT else SENSOR_RELIABLE
        if not self._depth:
            return base
        return QoSProfile(history=base.history, depth=self._depth, reliability=base.reliability)

    def check(self) -> None:
        """Recreate the subscription when the publishers' reliability changed."""
        offered = offered_reliability(self._node, self._topic)
        if offered is None or offered == self.reliability:
            return
        self._node.destroy_subscription(self._sub)
        self.reliability = offered
        self._sub = self._node.create_subscription(self._type, self._topic, self._callback, self._profile(),
                                                   callback_group=self._group)
        self.switches += 1
        self._node.get_logger().info(f"{self._node.resolve_topic_name(self._topic)}: publishers offer "
                                     f"{offered.name}; subscribed {offered.name}")
