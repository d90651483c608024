"""The CAD replacer node in its own process over DDS (loopback): URDF + TF out, scene actions in."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest
import trimesh
from testsupport.ros import call_service, domain_id, spin_until, stop_client_and_node

pytestmark = pytest.mark.ros


def _posed(model, pose):
    mesh = model.mesh()
    mesh.apply_transform(pose)
    return mesh


def _pose(x: float, y: float, z: float, yaw: float = 0.0) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    t = np.eye(4)
    t[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    t[:3, 3] = (x, y, z)
    return t


def _room():
    """Entities of a small room (floor, table with a cup, fridge, shelf) and its contact graph."""
    from cad_replacement.cad import build_model
    from recon_core.entity import Entity
    from scene_graph.builder import ContactGraphBuilder
    from scene_graph.config import load_scene_graph_config

    table, fridge, shelf, cup = (build_model(c, 0) for c in ("table", "fridge", "shelf", "cup"))
    floor = trimesh.creation.box(extents=(6, 6, 0.05))
    floor.apply_translation((0, 0, -0.025))
    parts = [(1, "floor", floor, "layout"), (2, "table", _posed(table, _pose(0, 0, 0)), ""),
             (3, "fridge", _posed(fridge, _pose(-2, 1.5, 0, -np.pi / 2)), ""),
             (4, "shelf", _posed(shelf, _pose(2, 0, 0, np.pi)), ""),
             (5, "cup", _posed(cup, _pose(0.1, 0, float(table.size[2]))), "")]
    entities = [Entity(i, c, m.vertices, m.faces, category=cat, is_thing=c != "floor", revision=1)
                for i, c, m, cat in parts]
    builder = ContactGraphBuilder(load_scene_graph_config())
    builder.update(entities)
    return entities, builder.build(name="room")


def _publish_room(node, entities, graph, graph_first_s: float = 0.0) -> None:
    """Stand in for the contact graph node: publish the room's node geometry and its graph (with
    `graph_first_s` > 0: the graph first, the entities that long after)."""
    from scene_recon_interfaces.msg import ContactGraph, PanopticEntityArray
    from std_msgs.msg import Header

    from ros_nodes.contact_graph_node import graph_to_msg
    from ros_nodes.entity_conversions import entity_to_msg
    from ros_nodes.qos import ENTITIES, LATCHED

    pub_entities = node.create_publisher(PanopticEntityArray, "contact_graph_entities", ENTITIES)
    pub_graph = node.create_publisher(ContactGraph, "contact_graph", LATCHED)
    assert spin_until(node, lambda: pub_entities.get_subscription_count() > 0, 60), "node never subscribed"
    header = Header(frame_id="map")
    if graph_first_s > 0:
        assert spin_until(node, lambda: pub_graph.get_subscription_count() > 0, 30), "node never subscribed"
        pub_graph.publish(graph_to_msg(graph, header))
        spin_until(node, lambda: False, graph_first_s)
    pub_entities.publish(PanopticEntityArray(header=header, entities=[entity_to_msg(e) for e in entities]))
    if graph_first_s <= 0:
        pub_graph.publish(graph_to_msg(graph, header))


def test_scene_urdf_tf_and_actions_over_dds(tmp_path):
    import rclpy
    import yourdfpy
    from scene_recon_interfaces.srv import ApplySceneAction
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String
    from std_srvs.srv import Trigger
    from tf2_msgs.msg import TFMessage

    from ros_nodes.qos import LATCHED, TF_STATIC

    entities, graph = _room()
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id("spare1")), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    out_dir = tmp_path / "scene"
    proc = subprocess.Popen([sys.executable, "-m", "ros_nodes.cad_replacer_node", "--ros-args",
                             "-p", "seeds_per_class:=1", "-p", f"output_dir:={out_dir}", "-p", "min_period_s:=0.0"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    os.environ["ROS_DOMAIN_ID"] = env["ROS_DOMAIN_ID"]
    rclpy.init()
    node = rclpy.create_node("planner_client")
    descriptions: list = []
    joint_states: list = []
    tf: dict[str, np.ndarray] = {}
    static: dict[str, str] = {}

    def on_tf(msg):
        for t in msg.transforms:
            tf[t.child_frame_id] = np.array([t.transform.translation.x, t.transform.translation.y,
                                             t.transform.translation.z, t.transform.rotation.z,
                                             t.transform.rotation.w])

    def on_static(msg):
        static.update({t.child_frame_id: t.header.frame_id for t in msg.transforms})

    try:
        node.create_subscription(String, "robot_description", descriptions.append, LATCHED)
        node.create_subscription(JointState, "joint_states", joint_states.append, 10)
        node.create_subscription(TFMessage, "/tf", on_tf, 100)
        node.create_subscription(TFMessage, "/tf_static", on_static, TF_STATIC)
        _publish_room(node, entities, graph)
        # (each topic arrives on its own: under load /tf_static can come after the description)
        ready = spin_until(node, lambda: bool(descriptions) and "cup_5" in tf and bool(joint_states)
                           and "table_2" in static, 120)
        assert ready, (f"description {bool(descriptions)}, tf frames {sorted(tf)}, static {sorted(static)}, "
                       f"joint states {len(joint_states)}, node exit {proc.poll()}")
        urdf_path = tmp_path / "scene.urdf"
        urdf_path.write_text(descriptions[-1].data.replace(f"file://{out_dir}/", f"{out_dir}/"))
        urdf = yourdfpy.URDF.load(str(urdf_path))
        assert urdf.validate() and "fridge_3" in urdf.link_map and "cup_5" in urdf.link_map
        assert "<!-- revision 1 -->" in descriptions[-1].data
        assert static.get("table_2") == "floor_1"  # furniture on the floor: fixed joint on /tf_static
        cup_before = tf["cup_5"].copy()

        act = node.create_client(ApplySceneAction, "apply_scene_action")
        assert act.wait_for_service(timeout_sec=30)
        door = next(n for n in joint_states[-1].name if n.startswith("fridge_3__door"))
        res, _ = call_service(node, act, ApplySceneAction.Request(
            action=ApplySceneAction.Request.SET_JOINT, joint_name=door, joint_value=1.0))
        assert res.success, res.message
        assert res.revision == 2
        assert spin_until(node, lambda: door in joint_states[-1].name and abs(
            joint_states[-1].position[joint_states[-1].name.index(door)] - 1.0) < 1e-6, 10)
        assert spin_until(node, lambda: "<!-- revision 2 -->" in descriptions[-1].data, 10)

        res, _ = call_service(node, act, ApplySceneAction.Request(
            action=ApplySceneAction.Request.REPARENT, object_name="cup_5", new_parent="shelf_4"))
        assert res.success, res.message
        assert res.revision == 3
        assert spin_until(node, lambda: np.linalg.norm(tf["cup_5"][:3] - cup_before[:3]) > 0.05, 10)

        before = descriptions[-1].data
        bad, _ = call_service(node, act, ApplySceneAction.Request(
            action=ApplySceneAction.Request.SET_JOINT, joint_name=door, joint_value=5.0))
        assert not bad.success and "outside its limits" in bad.message and bad.revision == 3
        unknown, _ = call_service(node, act, ApplySceneAction.Request(
            action=ApplySceneAction.Request.MOVE_OBJECT, object_name="unicorn"))
        assert not unknown.success and "unicorn" in unknown.message
        # the pass from scratch (due final_replace_s = 1 s after the graph) must not undo the actions
        spin_until(node, lambda: False, 3.0)
        assert descriptions[-1].data == before
        assert abs(joint_states[-1].position[joint_states[-1].name.index(door)] - 1.0) < 1e-6

        export = node.create_client(Trigger, "export_scene")
        assert export.wait_for_service(timeout_sec=10)
        res, _ = call_service(node, export, Trigger.Request())
        assert res.success and (out_dir / "scene.urdf").is_file() and (out_dir / "joint_states.json").is_file()
    finally:
        out = stop_client_and_node(node, proc)
    assert "scene revision 1" in out, out
    assert "scene revision 2" not in out and "scene revision 4" not in out, out  # revisions 2, 3 are the actions


def test_a_graph_waits_for_its_entities(tmp_path):
    """The graph and its entities come on two topics; a graph that comes first waits for them
    (``entities_wait_s``), so the first scene published already holds the objects."""
    import rclpy
    from std_msgs.msg import String

    from ros_nodes.qos import LATCHED

    entities, graph = _room()
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id("spare1")), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    proc = subprocess.Popen([sys.executable, "-m", "ros_nodes.cad_replacer_node", "--ros-args",
                             "-p", "seeds_per_class:=1", "-p", f"output_dir:={tmp_path / 'scene'}",
                             "-p", "min_period_s:=0.0", "-p", "final_replace_s:=0.0"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    os.environ["ROS_DOMAIN_ID"] = env["ROS_DOMAIN_ID"]
    rclpy.init()
    node = rclpy.create_node("planner_client")
    descriptions: list = []
    try:
        node.create_subscription(String, "robot_description", descriptions.append, LATCHED)
        _publish_room(node, entities, graph, graph_first_s=1.0)
        assert spin_until(node, lambda: bool(descriptions), 120), f"no description; node exit {proc.poll()}"
        first = descriptions[0].data
        assert "<!-- revision 1 -->" in first and "cup_5" in first and "fridge_3" in first
        spin_until(node, lambda: False, 1.0)
        assert len(descriptions) == 1
    finally:
        out = stop_client_and_node(node, proc)
    assert "without them" not in out, out


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (exists and is not a zombie)."""
    try:
        with open(f"/proc/{pid}/stat", encoding="utf-8") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            return fh.read().replace(b"\0", b" ").decode(errors="replace")[:200]
    except OSError:
        return "?"


def _descendants(pid: int) -> set[int]:
    """Live descendant process ids of ``pid`` (from /proc: the fork server and its workers)."""
    parents: dict[int, int] = {}
    for stat in os.listdir("/proc"):
        if not stat.isdigit():
            continue
        try:
            with open(f"/proc/{stat}/stat", encoding="utf-8") as fh:
                fields = fh.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] != "Z":
            parents[int(stat)] = int(fields[1])
    out: set[int] = set()
    todo = [pid]
    while todo:
        p = todo.pop()
        kids = {c for c, pp in parents.items() if pp == p}
        todo.extend(kids - out)
        out |= kids
    return out


def test_the_node_replaces_in_worker_processes_and_stops_them_on_shutdown(tmp_path):
    import rclpy
    from std_msgs.msg import String

    from ros_nodes.qos import LATCHED

    entities, graph = _room()
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id("spare1")), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    proc = subprocess.Popen([sys.executable, "-m", "ros_nodes.cad_replacer_node", "--ros-args",
                             "-p", "seeds_per_class:=1", "-p", f"output_dir:={tmp_path / 'scene'}",
                             "-p", "min_period_s:=0.0", "-p", "replace.workers:=2",
                             "-p", "replace.parallel_min_objects:=2"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    os.environ["ROS_DOMAIN_ID"] = env["ROS_DOMAIN_ID"]
    rclpy.init()
    node = rclpy.create_node("planner_client")
    descriptions: list = []
    helpers: set[int] = set()
    try:
        node.create_subscription(String, "robot_description", descriptions.append, LATCHED)
        _publish_room(node, entities, graph)
        assert spin_until(node, lambda: bool(descriptions), 120), f"no description, node exit {proc.poll()}"
        for name in ("table_2", "fridge_3", "shelf_4", "cup_5"):
            assert f'link name="{name}"' in descriptions[-1].data, name
        helpers = _descendants(proc.pid)
        assert len(helpers) >= 3, helpers  # the fork server and two workers
    finally:
        out = stop_client_and_node(node, proc, timeout=30)
    assert proc.returncode == 0, out
    # the fork server, the workers and the resource tracker notice the node's end on their pipes
    deadline = time.monotonic() + 10.0
    while any(_alive(p) for p in helpers) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = {p: _cmdline(p) for p in helpers if _alive(p)}
    assert not left, f"processes left running: {left}\n{out}"
