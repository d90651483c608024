"""DDS domains for tests: the caller's ROS_DOMAIN_ID when one was set, else an id of the test's own.

A caller that sets ROS_DOMAIN_ID (two engineers, two CI jobs on one machine) gets every ROS test on
that domain, so two such runs never talk to each other; the tests then run one after the other on it
and each waits for its own nodes by name, not for "some other participant". With none set, each
test gets an id of its own (varied by pid between runs), all inside 0-101: ids above 101 (except
215-232) map to UDP ports that can clash with the kernel's ephemeral range.
"""

from __future__ import annotations

import os

_TESTS = ("dds_exchange", "player", "segmentation", "mapper", "contact_graph", "spare1", "spare2", "spare3", "e2e")
#: Set by test/conftest.py before it gives ROS_DOMAIN_ID a default: the caller's own value, or "".
CALLER_DOMAIN_VARIABLE = "SCENE_RECON_TEST_CALLER_DOMAIN"


def caller_domain() -> int | None:
    """The ROS_DOMAIN_ID the test run was started with, if any."""
    value = os.environ.get(CALLER_DOMAIN_VARIABLE, "").strip()
    return int(value) if value else None


def domain_id(test: str) -> int:
    """The caller's domain id; else one unique to `test` within this run (and varied by pid between runs)."""
    caller = caller_domain()
    if caller is not None:
        return caller
    slot = _TESTS.index(test)
    return 10 + (os.getpid() % 10) * len(_TESTS) + slot  # 10 .. 99


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


def stop_client_and_node(node, proc, timeout: float = 15.0) -> str:
    """End a test: destroy the client `node`, shut rclpy down, SIGTERM the node process `proc`
    (SIGKILL after `timeout` s) and return what it printed."""
    import subprocess

    import rclpy

    node.destroy_node()
    rclpy.shutdown()
    proc.terminate()
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return str(out)


def call_service(node, client, request, timeout: float = 30.0):
    """Call a service from `node` and wait for the answer: (response, seconds it took)."""
    import time

    import rclpy

    t0 = time.perf_counter()
    future = client.call_async(request)
    rclpy.spin_until_future_complete(node, future, timeout_sec=timeout)
    assert future.done(), "service call timed out"
    return future.result(), time.perf_counter() - t0


def subscribe_diagnostics(node) -> dict[str, list[dict]]:
    """Subscribe `node` to /diagnostics; returns status name -> the statuses received, oldest first, each
    as {"level": "OK"|"WARN"|"ERROR"|"STALE", "message", "hardware_id", "values": {key: text}}."""
    from diagnostic_msgs.msg import DiagnosticArray

    from ros_nodes.diagnostics import LEVEL_NAMES, QOS, TOPIC

    got: dict[str, list[dict]] = {}

    def on_array(msg) -> None:
        for s in msg.status:
            got.setdefault(s.name, []).append({"level": LEVEL_NAMES[s.level], "message": s.message,
                                               "hardware_id": s.hardware_id,
                                               "values": {kv.key: kv.value for kv in s.values}})

    node.create_subscription(DiagnosticArray, TOPIC, on_array, QOS)
    return got


def play_recording(python: str, source, env: dict, *params: str, timeout: float = 120.0):
    """Play `source` once through the rgbd_player node at rate 1.0 (waiting for a subscriber) and return
    the finished process; `params`: extra ``name:=value`` parameters."""
    import subprocess

    args = [python, "-m", "ros_nodes.rgbd_player", "--ros-args", "-p", f"source:={source}", "-p", "rate:=1.0",
            "-p", "wait_for_subscribers:=1"]
    for param in params:
        args += ["-p", param]
    return subprocess.run(args, env=env, capture_output=True, text=True, timeout=timeout)
