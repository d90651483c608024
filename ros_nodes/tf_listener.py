"""A TF listener on the core's TransformBuffer (tf2_ros is not on PyPI; this works everywhere)."""

from __future__ import annotations

import threading

import numpy as np
from rclpy.callback_groups import CallbackGroup
from rclpy.node import Node
from tf2_msgs.msg import TFMessage

from panoptic_mapping.dataio.transforms import TransformBuffer, TransformLookupError
from ros_nodes.conversions import stamp_to_ns
from ros_nodes.qos import TF_LISTEN, TF_LISTEN_RELIABLE, TF_STATIC


class TFListener:
    """Feeds /tf and /tf_static into a TransformBuffer with a bounded history per dynamic edge."""

    def __init__(self, node: Node, max_extrapolation_s: float = 0.05, max_gap_s: float = 1.0,
                 max_samples_per_edge: int = 2000, callback_group: CallbackGroup | None = None,
                 reliable: bool = False):
        """`reliable`: subscribe /tf reliable (matches reliable publishers only; see qos.TF_LISTEN_RELIABLE)."""
        self.buffer = TransformBuffer(int(max_extrapolation_s * 1e9), int(max_gap_s * 1e9), max_samples_per_edge)
        self._lock = threading.Lock()  # callbacks may run on another executor thread than lookups
        node.create_subscription(TFMessage, "/tf", lambda m: self._on_tf(m, False),
                                 TF_LISTEN_RELIABLE if reliable else TF_LISTEN,
                                 callback_group=callback_group)
        node.create_subscription(TFMessage, "/tf_static", lambda m: self._on_tf(m, True), TF_STATIC,
                                 callback_group=callback_group)

    def lookup(self, target: str, source: str, stamp_ns: int) -> np.ndarray:
        """T_target_source at `stamp_ns` (raises TransformLookupError)."""
        with self._lock:
            return self.buffer.lookup(target, source, stamp_ns)

    def time_range(self, target: str, source: str) -> tuple[int, int] | None:
        """(first, last) stamp (ns) where every dynamic edge between the two frames has TF; None when they are
        joined by static edges only, or not joined at all (a lookup then says why). A stamp after `last` is
        one whose TF has not arrived yet: looked up now, the newest pose would be held forward."""
        with self._lock:
            try:
                return self.buffer.time_range(source, target)
            except TransformLookupError:
                return None

    def _on_tf(self, msg: TFMessage, static: bool) -> None:
        with self._lock:
            self._add(msg, static)

    def _add(self, msg: TFMessage, static: bool) -> None:
        for tr in msg.transforms:
            t, q = tr.transform.translation, tr.transform.rotation
            self.buffer.add(tr.header.frame_id, tr.child_frame_id, stamp_to_ns(tr.header.stamp),
                            (t.x, t.y, t.z), (q.x, q.y, q.z, q.w), static=static)
