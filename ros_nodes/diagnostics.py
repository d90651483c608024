"""`/diagnostics` for every node: one `diagnostic_msgs/DiagnosticArray` about once a second.

The standard topic (what `diagnostic_aggregator`, `rqt_robot_monitor` and `ros2 topic echo /diagnostics`
read): each node publishes one `DiagnosticStatus` named ``<node name>: <role>``, its level (OK / WARN /
ERROR) decided from the node's own state, a one-line message saying why, and key/values of what the node
tracks. The keys every node uses for the same thing (`KEY_*` below) are documented in
docs/PLANNER_CONTRACT.md.

A node gives `NodeDiagnostics` a function returning its current `Health`; the numbers come from the
node's own counters (the same ones as its status topic and log line). The two small windows here,
`RateWindow` (events per second) and `LatencyWindow` (median of the recent durations), and
`RecentIncrease` (has a monotonic counter grown lately, e.g. frames dropped) are what a node needs on
top of its counters for rates, latencies and "is it happening now" rather than "did it ever happen".
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.callback_groups import CallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ros_nodes.runner import steady_timer

#: The standard topic (absolute: a namespaced node still reports to the one aggregator).
TOPIC = "/diagnostics"
#: Reliable, volatile, a short history: what diagnostic_updater offers and the aggregator subscribes with.
#: A status is superseded a second later, so a late subscriber needs no history.
QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                 durability=DurabilityPolicy.VOLATILE)
PERIOD_S = 1.0

OK, WARN, ERROR = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR", DiagnosticStatus.STALE: "STALE"}

# Keys shared by the nodes (one name for one quantity, whichever node reports it).
KEY_INPUT_RATE = "input_rate_hz"  # inputs per second over the last RATE_WINDOW_S
KEY_LATENCY = "processing_latency_ms"  # median of the recent processing steps
KEY_RECEIVED = "received"  # inputs received since start
KEY_PROCESSED = "processed"  # inputs fully processed since start
KEY_DROPPED = "dropped"  # inputs dropped (could not keep up) since start
KEY_SKIPPED = "skipped"  # inputs skipped (unusable) since start
KEY_QUEUE = "queue_depth"  # inputs waiting to be processed now
KEY_LAST_ERROR = "last_error"  # text of the newest error ("" if none)

#: Rates are counted over this many seconds.
RATE_WINDOW_S = 5.0
#: A counter that grew within this many seconds counts as "happening now" (WARN while frames are dropped).
RECENT_S = 10.0


class RateWindow:
    """Events per second over the last `window_s` seconds (thread safe)."""

    def __init__(self, window_s: float = RATE_WINDOW_S) -> None:
        self.window_s = window_s
        self._times: collections.deque[float] = collections.deque()
        self._lock = threading.Lock()

    def tick(self, now: float | None = None) -> None:
        with self._lock:
            self._times.append(time.monotonic() if now is None else now)
            self._trim(self._times[-1])

    def rate_hz(self, now: float | None = None) -> float:
        with self._lock:
            now = time.monotonic() if now is None else now
            self._trim(now)
            return len(self._times) / self.window_s

    def _trim(self, now: float) -> None:
        while self._times and self._times[0] < now - self.window_s:
            self._times.popleft()


class LatencyWindow:
    """The median of the last `size` durations (thread safe)."""

    def __init__(self, size: int = 50) -> None:
        self._values: collections.deque[float] = collections.deque(maxlen=size)
        self._lock = threading.Lock()

    def add(self, ms: float) -> None:
        with self._lock:
            self._values.append(float(ms))

    def median_ms(self) -> float:
        with self._lock:
            values = sorted(self._values)
        if not values:
            return 0.0
        n = len(values)
        return values[n // 2] if n % 2 else 0.5 * (values[n // 2 - 1] + values[n // 2])


class RecentIncrease:
    """Whether monotonic counters grew within the last `window_s` seconds (by name)."""

    def __init__(self, window_s: float = RECENT_S) -> None:
        self.window_s = window_s
        self._last: dict[str, tuple[float, float]] = {}  # name -> (value, when it last grew)

    def grew(self, name: str, value: float, now: float | None = None) -> bool:
        now = time.monotonic() if now is None else now
        prev = self._last.get(name)
        if prev is None:
            # first look: a counter already above zero grew "now" (a node that started dropping at once)
            self._last[name] = (value, now if value > 0 else -float("inf"))
        elif value > prev[0]:
            self._last[name] = (value, now)
        elif value < prev[0]:  # reset (a reset map): remember the new base
            self._last[name] = (value, prev[1])
        return now - self._last[name][1] <= self.window_s


@dataclass
class Health:
    """One node's state: level, why, and what it tracks (key -> value; floats rounded on the wire)."""

    level: bytes = OK
    message: str = "ok"
    values: dict[str, Any] = field(default_factory=dict)
    hardware_id: str = ""

    def escalate(self, level: bytes, reason: str) -> None:
        """Raise the level to `level` (never lowers it); the reasons of the highest level make the message."""
        if level > self.level:
            self.level, self.message = level, reason
        elif level == self.level and level != OK:
            self.message = f"{self.message}; {reason}"


def _text(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:.3f}".rstrip("0").rstrip(".") if value == value else "nan"
    return str(value)


def status_msg(name: str, health: Health) -> DiagnosticStatus:
    return DiagnosticStatus(level=health.level, name=name, message=health.message, hardware_id=health.hardware_id,
                            values=[KeyValue(key=str(k), value=_text(v)) for k, v in health.values.items()])


class NodeDiagnostics:
    """Publishes `report()` on /diagnostics every `period_s` (a steady timer: it keeps going while a
    played bag's /clock is paused or over). The status name is ``<node name>: <role>``."""

    def __init__(self, node: Node, role: str, report: Callable[[], Health], period_s: float = PERIOD_S,
                 callback_group: CallbackGroup | None = None) -> None:
        self._node, self._report = node, report
        self.name = f"{node.get_name()}: {role}"
        self._pub = node.create_publisher(DiagnosticArray, TOPIC, QOS)
        self.published = 0
        steady_timer(node, period_s, self.publish, callback_group)

    def publish(self) -> None:
        try:
            health = self._report()
        except Exception as exc:  # a report must never take the node down; say so instead
            health = Health(ERROR, f"diagnostics failed: {type(exc).__name__}: {exc}",
                            {KEY_LAST_ERROR: f"{type(exc).__name__}: {exc}"})
        msg = DiagnosticArray(status=[status_msg(self.name, health)])
        msg.header.stamp = self._node.get_clock().now().to_msg()
        self._pub.publish(msg)
        self.published += 1


__all__ = ["ERROR", "KEY_DROPPED", "KEY_INPUT_RATE", "KEY_LAST_ERROR", "KEY_LATENCY", "KEY_PROCESSED", "KEY_QUEUE",
           "KEY_RECEIVED", "KEY_SKIPPED", "LEVEL_NAMES", "OK", "PERIOD_S", "QOS", "TOPIC", "WARN", "Health",
           "LatencyWindow", "NodeDiagnostics", "RateWindow", "RecentIncrease", "status_msg"]
