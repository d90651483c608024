"""DDS domains for tests: each ROS test gets its own id, all inside 0-101.

Ids above 101 (except 215-232) map to UDP ports that can clash with the kernel's ephemeral range,
and two tests sharing a domain can discover each other's leftover participants.
"""

from __future__ import annotations

import os

_TESTS = ("dds_exchange", "player", "segmentation", "mapper", "contact_graph", "spare1", "spare2", "spare3")


def domain_id(test: str) -> int:
    """A domain id unique to `test` within this run (and varied by pid between runs)."""
    slot = _TESTS.index(test)
    return 20 + (os.getpid() % 10) * 8 + slot  # 20 .. 99


def spin_until(node, predicate, timeout: float) -> bool:
    """Spin `node` until `predicate()` holds (True) or `timeout` seconds pass (False)."""
    import time

    import rclpy

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
        if predicate():
            return True
    return False


def call_service(node, client, request, timeout: float = 30.0):
    """Call a service from `node` and wait for the answer: (response, seconds it took)."""
    import time

    import rclpy

    t0 = time.perf_counter()
    future = client.call_async(request)
    rclpy.spin_until_future_complete(node, future, timeout_sec=timeout)
    assert future.done(), "service call timed out"
    return future.result(), time.perf_counter() - t0
