"""The contact-graph node in its own process, fed PanopticEntityArray messages over DDS (loopback only)."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest
import trimesh
from testsupport.ros import domain_id, stop_client_and_node

pytestmark = pytest.mark.ros


def _entity_msg(eid: int, cls: str, lo, hi, revision: int = 1, category: int | None = None):
    from geometry_msgs.msg import Point
    from scene_recon_interfaces.msg import PanopticEntity
    from shape_msgs.msg import Mesh, MeshTriangle

    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    box = trimesh.creation.box(extents=hi - lo)
    box.apply_translation((lo + hi) / 2)
    msg = PanopticEntity(id=eid, class_name=cls, class_id=-1, is_thing=cls not in ("floor", "wall"),
                         category=category if category is not None else PanopticEntity.CATEGORY_UNKNOWN,
                         confidence=1.0, revision=revision)
    msg.mesh = Mesh(vertices=[Point(x=float(x), y=float(y), z=float(z)) for x, y, z in box.vertices],
                    triangles=[MeshTriangle(vertex_indices=[int(i) for i in f]) for f in box.faces])
    return msg


def _wait_for(node, got: list, predicate, timeout: float) -> bool:
    import rclpy

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
        if got and predicate(got[-1]):
            return True
    return False


def _parents(msg) -> dict[str, str]:
    names = {n.id: n.name for n in msg.nodes}
    return {names[e.child_id]: names[e.parent_id] for e in msg.support_edges}


def test_node_builds_and_updates_the_contact_graph_over_dds():
    import rclpy
    from scene_recon_interfaces.msg import ContactGraph, PanopticEntity, PanopticEntityArray, SupportEdge
    from visualization_msgs.msg import Marker, MarkerArray

    from ros_nodes.contact_graph_node import ENTITIES_QOS, LATCHED

    domain = str(domain_id("contact_graph"))
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=domain)
    os.environ["ROS_DOMAIN_ID"] = domain
    proc = subprocess.Popen([sys.executable, "-m", "ros_nodes.contact_graph_node"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    rclpy.init()
    node = rclpy.create_node("contact_graph_checker")
    graphs: list = []
    markers: list = []
    try:
        node.create_subscription(ContactGraph, "contact_graph", graphs.append, LATCHED)
        node.create_subscription(MarkerArray, "contact_graph_markers", markers.append, LATCHED)
        pub = node.create_publisher(PanopticEntityArray, "panoptic_entities", ENTITIES_QOS)
        deadline = time.monotonic() + 60
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        assert pub.get_subscription_count() > 0, "the node never subscribed"

        first = PanopticEntityArray()
        first.header.frame_id = "test_map"
        first.entities = [
            _entity_msg(1, "floor", [-3, -3, -0.05], [3, 3, 0], category=PanopticEntity.CATEGORY_LAYOUT),
            _entity_msg(2, "table", [0, 0, 0], [1.0, 0.8, 0.75]),
            _entity_msg(3, "cup", [0.4, 0.3, 0.75], [0.48, 0.38, 0.85]),
            _entity_msg(4, "box", [2.0, 2.0, 0.0], [2.3, 2.3, 0.3]),
        ]
        pub.publish(first)
        assert _wait_for(node, graphs, lambda g: len(g.nodes) == 5, 30), proc.poll() or "no graph"
        g = graphs[-1]
        assert g.header.frame_id == "test_map"
        assert _parents(g) == {"floor_1": "scene", "table_2": "floor_1", "cup_3": "table_2", "box_4": "floor_1"}
        joints = {e.child_id: e.joint_type for e in g.support_edges}
        assert joints[3] == SupportEdge.JOINT_FLOATING and joints[2] == SupportEdge.JOINT_FIXED
        cup_edge = next(e for e in g.support_edges if e.child_id == 3)
        np.testing.assert_allclose(cup_edge.plane.coef, [0, 0, 1, -0.75], atol=1e-6)
        assert cup_edge.score > 0.2

        # The cup moves onto the box (new revision), the table is deleted by the mapper.
        second = PanopticEntityArray()
        second.header.frame_id = "test_map"
        second.entities = [first.entities[0], first.entities[3],
                           _entity_msg(3, "cup", [2.1, 2.1, 0.3], [2.18, 2.18, 0.4], revision=2)]
        second.removed_ids = [2]
        pub.publish(second)
        assert _wait_for(node, graphs, lambda g: len(g.nodes) == 4, 30)
        assert _parents(graphs[-1]) == {"floor_1": "scene", "cup_3": "box_4", "box_4": "floor_1"}
        assert _wait_for(node, markers, lambda m: any(x.type == Marker.LINE_LIST for x in m.markers), 10)
        kinds = {(m.ns, m.type) for m in markers[-1].markers}
        assert ("boxes", Marker.LINE_LIST) in kinds and ("supports", Marker.ARROW) in kinds
        assert ("support_planes", Marker.CUBE) in kinds
    finally:
        out = stop_client_and_node(node, proc, timeout=10)
    assert "contact graph:" in out, out


def test_message_conversions_round_trip(tmp_path):
    from scene_recon_interfaces.msg import PanopticEntity
    from std_msgs.msg import Header

    from ros_nodes.contact_graph_node import graph_from_msg, graph_markers, graph_to_msg
    from ros_nodes.entity_conversions import msg_to_entity as entity_from_msg
    from scene_graph.builder import build_contact_graph

    msgs = [_entity_msg(1, "floor", [-2, -2, -0.05], [2, 2, 0], category=PanopticEntity.CATEGORY_LAYOUT),
            _entity_msg(2, "table", [0, 0, 0], [1.0, 0.8, 0.75]),
            _entity_msg(3, "cup", [0.4, 0.3, 0.75], [0.48, 0.38, 0.85])]
    by_uri = PanopticEntity(id=4, class_name="box", revision=3, mesh_uri=f"file://{tmp_path / 'box.ply'}")
    trimesh.creation.box(extents=[0.2, 0.2, 0.2]).apply_translation([-1, -1, 0.1]).export(tmp_path / "box.ply")
    entities = [entity_from_msg(m, mesh_root=tmp_path) for m in [*msgs, by_uri]]  # by URI: only under a root
    assert entities[0].category == "layout" and entities[3].revision == 3 and len(entities[3].faces) == 12
    graph = build_contact_graph(entities)
    msg = graph_to_msg(graph, Header(frame_id="map"))
    assert msg.root_id == 0 and len(msg.nodes) == 5 and len(msg.support_edges) == 4
    back = graph_from_msg(msg)
    assert back.parents() == graph.parents()
    assert back.proximal == graph.proximal
    for nid, node in graph.nodes.items():
        assert back.nodes[nid].name == node.name and back.nodes[nid].category == node.category
        if node.box is not None:
            assert back.nodes[nid].box.iou(node.box) == pytest.approx(1.0)
    assert back.supports[3].joint == "floating" and back.supports[2].joint == "fixed"
    markers = graph_markers(graph, Header(frame_id="map"))
    assert markers.markers[0].action == markers.markers[0].DELETEALL
    boxes = [m for m in markers.markers if m.ns == "boxes"]
    assert len(boxes) == 4 and all(len(m.points) == 24 for m in boxes)
