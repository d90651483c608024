"""A node process whose exit hangs after SIGINT ends itself and says where (`ros_nodes.runner.start_exit_watchdog`).

Once in CI a segmentation service was still running 30 s after SIGINT and was killed by the runner with no
trace of where it hung. Here a callback-like thread blocks forever (a non-daemon thread: Python's exit joins
it, as it joins an executor's pool threads): the watchdog must dump every thread's stack into the output and
end the process, with exit code 0 when the node's own shutdown had run and 1 when it had not."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest
from testsupport.ros import domain_id

_STUCK_NODE = """
import sys, threading, time
import rclpy
from ros_nodes.runner import init_ros, shutdown_node, start_exit_watchdog

stop = init_ros([])
start_exit_watchdog(stop, deadline_s=1.0)
node = rclpy.create_node("exit_watchdog_test")
release = threading.Event()

def stuck_in_the_middleware():
    release.wait()

threading.Thread(target=stuck_in_the_middleware).start()
print("ready", flush=True)
stop.wait()
if sys.argv[1] == "saved":
    shutdown_node(node)
    print("shutdown done", flush=True)
else:
    time.sleep(60)
"""


@pytest.mark.parametrize(("state", "code"), [("saved", 0), ("not-saved", 1)])
def test_a_hung_exit_ends_with_the_threads_stacks(tmp_path, state, code):
    script = tmp_path / "stuck_node.py"
    script.write_text(_STUCK_NODE)
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_DOMAIN_ID=os.environ.get("ROS_DOMAIN_ID") or str(domain_id("spare1")))
    proc = subprocess.Popen([sys.executable, str(script), state], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, env=env)
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # (the DDS profile's log line comes first)
            if line.strip() == "ready":
                break
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == code, out
    assert time.monotonic() - t0 < 15
    assert "exit watchdog: the node is still running" in out
    assert "stuck_in_the_middleware" in out  # the stuck thread's stack names its function
    assert ("shutdown done" in out) == (state == "saved")
