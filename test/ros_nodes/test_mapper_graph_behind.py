"""The mapper is not idle while the contact graph is behind (issue 24, done-when): on a loaded machine the
contact graph took 4-5 s to turn the mapper's last entities into a graph, and `scene-recon ros-run`, seeing the
mapper idle (everything published) and the scene quiet for 3 s, exported the scene of the graph before
(2 walls of 4 missing). While `contact_graph` has a publisher, `mapper_status` reports `graph_behind` (and
`unpublished_changes`) until a graph whose header carries the stamp of the newest entities published came."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from testsupport.ros import domain_id, play_recording, spin_until, stop_client_and_node

pytestmark = pytest.mark.ros


def test_mapper_status_waits_for_the_graph_of_its_newest_entities(tmp_path):
    import rclpy
    from scene_recon_interfaces.msg import ContactGraph, PanopticEntityArray
    from std_msgs.msg import String
    from testsupport.frames import toy_room_tum

    from ros_nodes.qos import ENTITIES, LATCHED, STATUS

    toy_room_tum(tmp_path / "tum", 8, 0.6 * np.pi)
    domain = str(domain_id("spare3"))
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=domain)
    os.environ["ROS_DOMAIN_ID"] = domain
    py = sys.executable
    mapper = subprocess.Popen([py, "-m", "ros_nodes.mapper_node", "--ros-args", "-p", f"data_root:={tmp_path}",
                               "-p", "use_segmentation:=false", "-p", "tf_reliable:=true", "-p", "in_order:=true",
                               "-p", "status_period_s:=0.3", "-p", "publish_period_s:=0.5",
                               "-p", "gravity_pause_s:=1.0"],
                              env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    rclpy.init()
    node = rclpy.create_node("graph_stand_in")
    statuses: list[dict] = []
    stamps: list = []
    try:
        node.create_subscription(String, "mapper_status", lambda m: statuses.append(json.loads(m.data)), STATUS)
        node.create_subscription(PanopticEntityArray, "panoptic_entities", lambda m: stamps.append(m.header.stamp),
                                 ENTITIES)
        graph = node.create_publisher(ContactGraph, "contact_graph", LATCHED)  # a contact graph runs
        graph.publish(ContactGraph())  # ... and has published nothing built from this mapper's entities
        assert spin_until(node, lambda: bool(statuses), 60), "mapper node did not come up"
        assert not statuses[-1]["graph_behind"]  # nothing published yet: nothing to be behind on
        player = play_recording(py, tmp_path / "tum", env)
        assert player.returncode == 0, player.stdout + player.stderr

        def published_and_quiet() -> bool:
            s = statuses[-1]
            return s["entity_publications"] > 0 and s["queue"] == 0 and s["frames_integrated"] > 0 and bool(stamps)

        assert spin_until(node, published_and_quiet, 30), statuses[-1:]
        spin_until(node, lambda: False, 1.5)  # the newest publication in, a status or two after it
        assert statuses[-1]["graph_behind"] and statuses[-1]["unpublished_changes"], statuses[-1]
        # the graph of the newest entities: the mapper is idle
        last = ContactGraph()
        last.header.stamp = stamps[-1]
        graph.publish(last)
        assert spin_until(node, lambda: not statuses[-1]["graph_behind"], 10), statuses[-1]
        assert not statuses[-1]["unpublished_changes"], statuses[-1]
    finally:
        log = stop_client_and_node(node, mapper)
    assert "Traceback" not in log, log[-3000:]
