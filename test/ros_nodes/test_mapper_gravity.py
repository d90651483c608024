"""The mapper node on a recording whose TF map frame is not z up (a visual SLAM's first-camera frame):
the map is built in a gravity-aligned child frame that /tf_static announces, and the entities, the saved
map and its gravity record are in that frame; whether the first frames are mapped while the gravity check
reads them (the default: the map restarts in the aligned frame at the verdict) or wait for its verdict.
A z-up frame is mapped from its first frame on, with nothing restarted."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from testsupport.ros import domain_id, play_recording, spin_until

pytestmark = pytest.mark.ros

#: The TF map frame: tilted 63 deg about x and 20 deg about y (up is 65 deg from its +z), shifted.
TILT = np.eye(4)
TILT[:3, :3] = Rotation.from_euler("xy", [63, 20], degrees=True).as_matrix()
TILT[:3, 3] = [0.3, -1.0, 2.0]
Z = np.array([0.0, 0.0, 1.0])


def _tilted_tum(folder, frames: int = 16, transform: np.ndarray | None = TILT):
    """A TUM folder of the toy room (160x120, intrinsics in camera-intrinsics.txt) with poses in TILT."""
    from testsupport.frames import toy_room_tum

    toy_room_tum(folder, frames, 2 * np.pi, transform)


def _angle(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def _map_over_dds(tmp_path, save_as: str, *params: str) -> dict:
    """Play the tilted TUM folder (tmp_path/tum) into a mapper node started with ``params``, wait until
    every frame was taken, save the map as ``save_as``; what the test needs from the run."""
    import rclpy
    from scene_recon_interfaces.msg import PanopticEntityArray
    from scene_recon_interfaces.srv import SaveMap
    from std_msgs.msg import String
    from tf2_msgs.msg import TFMessage

    from ros_nodes.conversions import transform_to_matrix
    from ros_nodes.qos import ENTITIES, STATUS, TF_STATIC

    domain = str(domain_id("spare3"))
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=domain)
    os.environ["ROS_DOMAIN_ID"] = domain
    py = sys.executable
    args = [py, "-m", "ros_nodes.mapper_node", "--ros-args", "-p", f"data_root:={tmp_path}",
            "-p", "use_segmentation:=false", "-p", "tf_reliable:=true", "-p", "in_order:=true",
            "-p", "gravity_window_frames:=6", "-p", "gravity_stride:=2",
            "-p", "publish_period_s:=0.5", "-p", "status_period_s:=0.5"]
    for param in params:
        args += ["-p", param]
    mapper = subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    rclpy.init()
    node = rclpy.create_node("gravity_checker")
    out: dict = {"statics": {}, "entities": [], "statuses": [], "saved": None}
    try:
        node.create_subscription(TFMessage, "/tf_static", lambda m: out["statics"].update(
            {(t.header.frame_id, t.child_frame_id): transform_to_matrix(t.transform) for t in m.transforms}),
            TF_STATIC)
        node.create_subscription(PanopticEntityArray, "panoptic_entities", out["entities"].append, ENTITIES)
        node.create_subscription(String, "mapper_status", lambda m: out["statuses"].append(json.loads(m.data)),
                                 STATUS)
        save = node.create_client(SaveMap, "save_map")
        assert save.wait_for_service(timeout_sec=60), "mapper node did not come up"
        player = play_recording(py, tmp_path / "tum", env)
        assert player.returncode == 0, player.stdout + player.stderr
        statuses = out["statuses"]
        assert spin_until(node, lambda: bool(statuses) and statuses[-1]["frames_integrated"] >= 14
                          and statuses[-1]["queue"] == 0 and not statuses[-1]["unpublished_changes"], 60), statuses[-1:]
        spin_until(node, lambda: bool(out["entities"]), 10)
        fut = save.call_async(SaveMap.Request(path=save_as))
        rclpy.spin_until_future_complete(node, fut, timeout_sec=60)
        out["saved"] = fut.result()
    finally:
        node.destroy_node()
        rclpy.shutdown()
        mapper.terminate()
        out["log"] = mapper.communicate(timeout=30)[0]
    assert out["saved"] is not None and out["saved"].success, out["log"][-3000:]
    out["meta"] = json.loads((tmp_path / save_as / "map.json").read_text())
    return out


@pytest.mark.parametrize("map_while_checking", [True, False])
def test_mapper_node_maps_a_tilted_map_frame_in_a_gravity_aligned_frame(tmp_path, map_while_checking):
    import trimesh

    _tilted_tum(tmp_path / "tum")
    run = _map_over_dds(tmp_path, "tilted", f"gravity_map_while_checking:={str(map_while_checking).lower()}")
    meta, log, statuses = run["meta"], run["log"], run["statuses"]
    counters = statuses[-1]["counters"]
    if map_while_checking:  # the window's frames were mapped in the tilted frame, then again in the aligned one
        assert counters.get("gravity_restarts") == 1 and counters.get("mapped_before_gravity_verdict", 0) >= 1, counters
        assert "the map restarted in 'map_gravity'" in log
    else:  # they waited for the verdict
        assert "gravity_restarts" not in counters and "mapped_before_gravity_verdict" not in counters, counters
    assert counters["integrated"] == 16, counters  # each frame counted once
    g = meta["gravity"]
    # the verdict: the TF frame's up is 65 deg from its +z; the map is rotated so that true up is +z
    assert g["applied"] and g["mode"] == "auto" and g["frame"] == "map_gravity" and g["parent_frame"] == "map", g
    true_up = TILT[:3, :3] @ Z
    assert g["rotation_deg"] == pytest.approx(_angle(true_up, Z), abs=2.0)
    alignment = np.array(meta["gravity_alignment"])
    assert _angle(alignment[:3, :3] @ true_up, Z) < 2.0
    assert "is not gravity aligned" in log and "'map_gravity'" in log
    # every frame mapped, none lost to the wait; outputs in the aligned frame, announced on /tf_static
    assert meta["frames_integrated"] == 16, (meta["frames_integrated"], log[-2000:])
    assert statuses[-1]["frame"] == "map_gravity" and statuses[-1]["held_for_gravity"] == 0
    assert statuses[-1]["segmentation_service"] == "disabled"  # use_segmentation:=false (tools wait for "ready")
    assert run["entities"] and run["entities"][-1].header.frame_id == "map_gravity"
    assert np.allclose(run["statics"][("map", "map_gravity")], np.linalg.inv(alignment), atol=1e-6)
    assert json.loads((tmp_path / "tilted" / "entities.json").read_text())["map_frame"] == "map_gravity"
    # the floor is horizontal in the map: the most populated 4 cm height slice holds much of the surface
    z = trimesh.load(tmp_path / "tilted" / "meshes" / "0.ply", force="mesh", process=False).vertices[:, 2]
    counts, _ = np.histogram(z, bins=np.arange(z.min(), z.max() + 0.04, 0.04))
    assert counts.max() / len(z) > 0.3


def test_a_z_up_frame_is_mapped_while_the_check_reads_and_never_restarted(tmp_path):
    """The default on a z-up TF frame (REP 103): the window's frames are mapped as they come (none waits for the
    verdict), nothing is rotated or restarted, nothing published in between."""
    _tilted_tum(tmp_path / "tum", transform=None)
    run = _map_over_dds(tmp_path, "upright")
    meta, g, counters = run["meta"], run["meta"]["gravity"], run["statuses"][-1]["counters"]
    assert not g.get("applied") and np.allclose(meta["gravity_alignment"], np.eye(4)), g
    assert meta["frames_integrated"] == 16 and counters["integrated"] == 16, counters
    # the verdict came after the window's 6 x 2 frames: those before it were in the map already
    assert counters.get("mapped_before_gravity_verdict", 0) >= 6, counters
    assert "gravity_restarts" not in counters, counters
    assert run["statuses"][-1]["frame"] == "map" and run["entities"][-1].header.frame_id == "map"
    assert ("map", "map_gravity") not in run["statics"]


def test_gravity_align_false_trusts_the_tilted_frame_and_warns(tmp_path):
    """The old behaviour stays selectable: the frame is trusted (no rotation, no wait), the check warns."""
    _tilted_tum(tmp_path / "tum")
    run = _map_over_dds(tmp_path, "trusted", "gravity_align:=false")
    meta, g = run["meta"], run["meta"]["gravity"]
    assert g["mode"] == "tf" and not g["applied"] and np.allclose(meta["gravity_alignment"], np.eye(4))
    assert g["estimate"]["angle_from_z_deg"] == pytest.approx(_angle(TILT[:3, :3] @ Z, Z), abs=2.0)
    assert "the fixed frame's up is" in g["note"] and "provisional" not in g["note"], g
    assert "the fixed frame's up is" in run["log"] and run["statuses"][-1]["frame"] == "map"
    assert ("map", "map_gravity") not in run["statics"] and run["entities"][-1].header.frame_id == "map"
