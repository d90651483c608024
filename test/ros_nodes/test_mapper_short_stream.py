"""A short or paused stream is mapped (issue 24, item 4): the gravity window (window x stride frames,
30 by default) never fills on an 8-frame recording; its frames must not wait for the node's shutdown.
The window decides on what it has after a pause, or at once when a service asks for the map."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest
from testsupport.ros import domain_id, play_recording, spin_until, stop_client_and_node

pytestmark = pytest.mark.ros



def _short_tum(folder, frames: int = 8):
    """An 8-frame TUM folder of the toy room (160x120), z up, the camera turning slowly."""
    from testsupport.frames import toy_room_tum

    toy_room_tum(folder, frames, 0.6 * np.pi)


def _run(tmp_path, *params: str, ask: bool) -> dict:
    """Play the short folder into a mapper node (default gravity window: 10 x 3 frames). ``ask``: call
    extract_entities as soon as the player is done; else wait (no service call) until mapper_status says
    the frames were integrated, then call it. The answer, the statuses and the node's log."""
    import json

    import rclpy
    from scene_recon_interfaces.srv import ExtractEntities
    from std_msgs.msg import String

    from ros_nodes.qos import STATUS

    domain = str(domain_id("spare2"))
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=domain)
    os.environ["ROS_DOMAIN_ID"] = domain
    py = sys.executable
    args = [py, "-m", "ros_nodes.mapper_node", "--ros-args", "-p", f"data_root:={tmp_path}",
            "-p", "use_segmentation:=false", "-p", "tf_reliable:=true", "-p", "in_order:=true",
            "-p", "status_period_s:=0.3"]
    for param in params:
        args += ["-p", param]
    mapper = subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    rclpy.init()
    node = rclpy.create_node("short_stream_checker")
    out: dict = {"statuses": []}
    try:
        node.create_subscription(String, "mapper_status", lambda m: out["statuses"].append(json.loads(m.data)),
                                 STATUS)
        extract = node.create_client(ExtractEntities, "extract_entities")
        assert extract.wait_for_service(timeout_sec=60), "mapper node did not come up"
        player = play_recording(py, tmp_path / "tum", env)
        assert player.returncode == 0, player.stdout + player.stderr
        t_end = time.monotonic()
        if not ask:
            st = out["statuses"]
            # (frames mapped while the gravity check reads are integrated at once: the window must have closed too)
            out["integrated"] = spin_until(node, lambda: bool(st) and st[-1]["frames_integrated"] > 0
                                           and st[-1]["queue"] == 0 and st[-1]["gravity_window"] == 0, 20)
        out["waited_s"] = time.monotonic() - t_end
        fut = extract.call_async(ExtractEntities.Request(include_meshes=False))
        rclpy.spin_until_future_complete(node, fut, timeout_sec=30)
        out["answer"] = fut.result()
    finally:
        out["log"] = stop_client_and_node(node, mapper)
    return out


#: both ways of reading the gravity window: its frames mapped as they come (the default), or held for the verdict
WINDOW_MODES = pytest.mark.parametrize("map_while_checking", ["true", "false"])


@WINDOW_MODES
def test_a_service_asking_for_the_map_decides_the_gravity_window(tmp_path, map_while_checking):
    """No pause decides here (gravity_pause_s 120 s): the first extract_entities after the 8 frames
    decides the window, maps its frames (held ones) and answers entities."""
    _short_tum(tmp_path / "tum")
    run = _run(tmp_path, "gravity_pause_s:=120.0", f"gravity_map_while_checking:={map_while_checking}", ask=True)
    res, log = run["answer"], run["log"]
    assert res is not None and res.success, log[-3000:]
    assert len(res.entities.entities) > 0, (res.message, log[-3000:])
    assert "extract_entities asked for the map: the gravity window's" in log, log[-3000:]
    assert "gravity check: the fixed frame's +z is up" in log


@WINDOW_MODES
def test_a_paused_short_stream_is_mapped_without_any_service_call(tmp_path, map_while_checking):
    """The window decides after the stream pauses (gravity_pause_s), with no service call: the node's
    status reports the frames integrated a moment after the player stopped, not at shutdown."""
    _short_tum(tmp_path / "tum")
    run = _run(tmp_path, "gravity_pause_s:=1.0", f"gravity_map_while_checking:={map_while_checking}", ask=False)
    assert run["integrated"], (run["statuses"][-1:], run["log"][-3000:])
    assert run["statuses"][-1]["frames_integrated"] >= 6 and run["statuses"][-1]["held_for_gravity"] == 0
    assert run["waited_s"] < 15
    assert run["answer"] is not None and len(run["answer"].entities.entities) > 0
    assert "asked for the map" not in run["log"]
    if map_while_checking == "true":  # mapped as they came; the pause closed the window (publishing resumed)
        assert "the stream paused before the window was full: the gravity window's" in run["log"], run["log"][-3000:]
