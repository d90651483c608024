#!/usr/bin/env python3
"""A planner's view of the reconstructed scene (docs/PLANNER_CONTRACT.md), using ROS 2 messages only.

Waits for the scene (the URDF on `robot_description` and the `contact_graph`, both transient-local,
so it may start before or after the nodes), lists the objects and what supports each, opens a door
(or pulls a drawer) through the `apply_scene_action` service and prints the resulting joint state
and the door link's TF. Needs nothing of this project but its interface package
(scene_recon_interfaces); run it beside `ros2 launch scene_recon bag.launch.py ...` or
`scene-recon ros-run ...`:

    python3 examples/planner_client.py [--fraction 0.8] [--timeout 120]

The last line printed is a JSON summary (for scripts and the end-to-end test). Exit status 0 when
the scene arrived and the joint moved, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
import xml.etree.ElementTree as ET

import rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from scene_recon_interfaces.msg import ContactGraph, ContactGraphNode, SupportEdge
from scene_recon_interfaces.srv import ApplySceneAction
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
TF_STATIC = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
TF = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)  # matches reliable publishers too
NODE_TYPES = {ContactGraphNode.TYPE_SCENE: "scene", ContactGraphNode.TYPE_LAYOUT: "layout",
              ContactGraphNode.TYPE_RIGID: "rigid", ContactGraphNode.TYPE_ARTICULATED: "articulated"}
JOINTS = {SupportEdge.JOINT_FIXED: "fixed", SupportEdge.JOINT_FLOATING: "floating"}


class SceneClient(Node):
    """Keeps the newest scene description, graph, joint state and TF."""

    def __init__(self) -> None:
        super().__init__("planner_client")
        self.urdf: str | None = None
        self.graph: ContactGraph | None = None
        self.joints: JointState | None = None
        self.tf: dict[str, object] = {}  # child frame -> TransformStamped
        self.create_subscription(String, "robot_description", self._on_urdf, LATCHED)
        self.create_subscription(ContactGraph, "contact_graph", self._on_graph, LATCHED)
        self.create_subscription(JointState, "joint_states", self._on_joints, 10)
        self.create_subscription(TFMessage, "/tf", self._on_tf, TF)
        self.create_subscription(TFMessage, "/tf_static", self._on_tf, TF_STATIC)
        self.action = self.create_client(ApplySceneAction, "apply_scene_action")

    def _on_urdf(self, msg: String) -> None:
        self.urdf = msg.data

    def _on_graph(self, msg: ContactGraph) -> None:
        self.graph = msg

    def _on_joints(self, msg: JointState) -> None:
        self.joints = msg

    def _on_tf(self, msg: TFMessage) -> None:
        for t in msg.transforms:
            self.tf[t.child_frame_id] = t

    def spin_until(self, predicate, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            rclpy.spin_once(self, timeout_sec=0.05)
            if predicate():
                return True
        return False

    def revision(self) -> int:
        match = re.search(r"<!-- revision (\d+) -->", self.urdf or "")
        return int(match.group(1)) if match else 0

    def joint_value(self, name: str) -> float | None:
        if self.joints is None or name not in self.joints.name:
            return None
        return float(self.joints.position[list(self.joints.name).index(name)])


def movable_joints(urdf: str) -> list[dict]:
    """Revolute (doors) and prismatic (drawers) joints of the URDF with their limits and child link."""
    out = []
    for j in ET.fromstring(urdf).iter("joint"):
        kind = j.get("type")
        if kind not in ("revolute", "prismatic"):
            continue
        limit = j.find("limit")
        out.append({"name": j.get("name"), "type": kind, "child": j.find("child").get("link"),
                    "lower": float(limit.get("lower", 0.0)) if limit is not None else 0.0,
                    "upper": float(limit.get("upper", 0.0)) if limit is not None else 0.0})
    return sorted(out, key=lambda j: (j["type"] != "revolute", j["name"]))  # doors first


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fraction", type=float, default=0.8, help="open the joint to this share of its range")
    parser.add_argument("--timeout", type=float, default=120.0, help="seconds to wait for the scene")
    args = parser.parse_args(argv)
    rclpy.init()
    node = SceneClient()
    summary: dict = {"ok": False}
    try:
        if not node.spin_until(lambda: node.urdf is not None and node.graph is not None, args.timeout):
            print("no scene: nothing on robot_description / contact_graph (are the nodes running, same "
                  "ROS_DOMAIN_ID?)", file=sys.stderr)
            return 1
        graph = node.graph
        names = {n.id: n.name for n in graph.nodes}
        parents = {e.child_id: e for e in graph.support_edges}
        print(f"scene revision {node.revision()} in frame '{graph.header.frame_id}': {len(graph.nodes) - 1} objects")
        objects = []
        for n in graph.nodes:
            if n.id == graph.root_id:
                continue
            edge = parents.get(n.id)
            on = names.get(edge.parent_id, "?") if edge else "-"
            joint = JOINTS.get(edge.joint_type, "?") if edge else "-"
            print(f"  {n.name:<20} {n.class_name:<12} {NODE_TYPES.get(n.node_type, '?'):<12} on {on:<20} ({joint})")
            objects.append({"name": n.name, "class": n.class_name, "on": on, "joint": joint})
        summary.update(objects=objects, revision=node.revision())
        joints = movable_joints(node.urdf)
        if not joints:
            print("no door or drawer in this scene: nothing to open")
            summary["ok"] = True
            return 0
        door = joints[0]
        target = door["lower"] + args.fraction * (door["upper"] - door["lower"])
        if not node.action.wait_for_service(timeout_sec=30):
            print("apply_scene_action is not available", file=sys.stderr)
            return 1
        request = ApplySceneAction.Request(action=ApplySceneAction.Request.SET_JOINT, joint_name=door["name"],
                                           joint_value=target)
        future = node.action.call_async(request)
        rclpy.spin_until_future_complete(node, future, timeout_sec=30)
        res = future.result()
        if res is None or not res.success:
            print(f"opening {door['name']} refused: {getattr(res, 'message', 'no answer')}", file=sys.stderr)
            return 1
        print(f"{door['type']} joint {door['name']} -> {target:.3f} (limits {door['lower']:.3f}..{door['upper']:.3f}):"
              f" {res.message}, scene revision {res.revision}")
        moved = node.spin_until(lambda: node.joint_value(door["name"]) is not None
                                and abs(node.joint_value(door["name"]) - target) < 1e-6
                                and door["child"] in node.tf, 10)
        value = node.joint_value(door["name"])
        print(f"joint_states: {door['name']} = {value}")
        t = node.tf.get(door["child"])
        if t is not None:
            tr, q = t.transform.translation, t.transform.rotation
            print(f"TF {t.header.frame_id} -> {t.child_frame_id}: translation ({tr.x:.3f}, {tr.y:.3f}, {tr.z:.3f}), "
                  f"rotation xyzw ({q.x:.3f}, {q.y:.3f}, {q.z:.3f}, {q.w:.3f})")
            summary["tf"] = {"parent": t.header.frame_id, "child": t.child_frame_id,
                             "translation": [tr.x, tr.y, tr.z], "rotation": [q.x, q.y, q.z, q.w]}
        summary.update(ok=moved, joint=door["name"], target=target, value=value, action_revision=int(res.revision))
        return 0 if moved else 1
    finally:
        print(json.dumps(summary))
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
