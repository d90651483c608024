"""`ros_nodes.runner.spin_until_stopped` outlives an entity destroyed while the wait set was being built.

A multi-threaded executor builds its wait set on the spinning thread while callbacks run on others; a
callback that destroys an entity (the camera subscription `SensorSubscription.check` recreates when the
publishers' reliability changes) can make that build raise rclpy's `InvalidHandle`. In CI that ended a
mapper node 2 s after a best-effort camera appeared (`test_sensor_qos.py` then saw no frame integrated).
The race itself is timing-dependent, so the executor's spin is made to raise it once here."""

from __future__ import annotations

import os
import threading

import pytest
from testsupport.ros import domain_id


@pytest.mark.parametrize("threads", [1, 3])
def test_spinning_goes_on_after_an_invalid_handle(monkeypatch, threads):
    import rclpy
    from rclpy.exceptions import InvalidHandle
    from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor

    from ros_nodes.runner import spin_until_stopped

    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    monkeypatch.setenv("ROS_DOMAIN_ID", os.environ.get("ROS_DOMAIN_ID") or str(domain_id("spare1")))
    executor_class = MultiThreadedExecutor if threads > 1 else SingleThreadedExecutor
    original = executor_class.spin_once
    raised = []

    def spin_once_raising_once(self, timeout_sec=None):
        if not raised:
            raised.append(True)
            raise InvalidHandle("cannot use Destroyable because destruction was requested")
        return original(self, timeout_sec=timeout_sec)

    monkeypatch.setattr(executor_class, "spin_once", spin_once_raising_once)
    rclpy.init()
    try:
        node = rclpy.create_node("runner_spin_test")
        stop = threading.Event()
        ticks: list[int] = []

        def tick() -> None:
            ticks.append(1)
            if len(ticks) >= 3:
                stop.set()

        node.create_timer(0.02, tick)
        watchdog = threading.Timer(20.0, stop.set)  # never hang the suite
        watchdog.start()
        try:
            spin_until_stopped(node, stop, threads)
        finally:
            watchdog.cancel()
        assert raised, "the executor's spin never ran"
        assert len(ticks) >= 3  # the node kept spinning after the InvalidHandle
        node.destroy_node()
    finally:
        rclpy.shutdown()
