"""`contact_graph_node`: the contact-graph builder (paper Sec. 2) as a ROS 2 node over ``scene_graph``.

Input: ``panoptic_entities`` (scene_recon_interfaces/PanopticEntityArray) from the mapper. Each
entity carries a ``revision``; only entities whose revision changed are re-initialised (box,
planes), ``removed_ids`` are dropped, then the relations are rebuilt over all nodes.
Outputs (latched, so RViz and late joiners get the current graph): ``contact_graph``
(scene_recon_interfaces/ContactGraph), ``contact_graph_markers`` (visualization_msgs/MarkerArray:
boxes as LINE_LIST, supporting planes as thin CUBEs, support arrows parent -> child, labels) and
``contact_graph_json`` (std_msgs/String, latched: the graph as `recon_core.contact_graph` JSON, the
`graph` command's contact_graph.json, lossless for the CAD replacer) and
``contact_graph_entities`` (PanopticEntityArray, transient-local): the geometry behind every node as
the builder left it (split walls, merged fragments, trimmed contact bands), which is what the CAD
replacer fits to, exactly as `scene-recon replace` fits to the `graph` command's `nodes/` folder.
Its revisions change whenever a node's geometry changes.
The frame id is the entity array's. Parameters: ``config_file`` (the builder YAML, empty:
config/scene_graph.yaml), every key of that file under its dotted name (``support.a_th``,
``proximal.broadphase``, ``support_joints`` for the joint table, ...; see ``ros_nodes.parameters``),
and the node's own settings, ``ContactGraphNodeConfig`` (topics, ``min_period_s``, ``snapshot``,
``mesh_root``: meshes given by ``mesh_uri`` are read only under it, and an entity whose file is
refused or is not a mesh is skipped with a warning, never a crash). The entity subscription is
transient-local: a restarted node gets the mapper's current entities at once. `/diagnostics`
(`ros_nodes.diagnostics`, every second): entity messages received and their rate, graphs built, the
median build time, entities skipped, the newest error; ERROR when the last update was rejected, WARN
when entities were skipped within the last seconds.

The message conversions live here too (the only ROS-facing code of the contact graph).
"""

from __future__ import annotations

import hashlib
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from geometry_msgs.msg import Point, Quaternion, Vector3
from rclpy.node import Node
from scene_recon_interfaces.msg import ContactGraph as ContactGraphMsg
from scene_recon_interfaces.msg import ContactGraphNode as ContactGraphNodeMsg
from scene_recon_interfaces.msg import OrientedBox as OrientedBoxMsg
from scene_recon_interfaces.msg import PanopticEntityArray, ProximalEdge
from scene_recon_interfaces.msg import SupportEdge as SupportEdgeMsg
from shape_msgs.msg import Plane as PlaneMsg
from std_msgs.msg import ColorRGBA, Header, String
from visualization_msgs.msg import Marker, MarkerArray

from recon_core.config import Settings, setting
from recon_core.contact_graph import SCENE, ContactGraph, GraphNode, SupportEdge
from recon_core.entity import EntityError
from recon_core.geometry.box import GravityBox
from recon_core.geometry.plane import Plane, SurfacePlane
from ros_nodes import diagnostics as diag
from ros_nodes.entity_conversions import DEFAULT_MAP_ROOT, entity_to_msg, msg_to_entity, oriented_box_msg
from ros_nodes.parameters import declare_config, declare_config_file
from ros_nodes.qos import ENTITIES as ENTITIES_QOS
from ros_nodes.qos import LATCHED
from ros_nodes.runner import run_node, steady_timer
from scene_graph.builder import ContactGraphBuilder
from scene_graph.classify import ARTICULATED, LAYOUT, RIGID
from scene_graph.config import DEFAULT_CONFIG_FILE, SceneGraphConfig
from scene_graph.joints import load_support_joints

NODE_TYPE = {SCENE: ContactGraphNodeMsg.TYPE_SCENE, LAYOUT: ContactGraphNodeMsg.TYPE_LAYOUT,
             RIGID: ContactGraphNodeMsg.TYPE_RIGID, ARTICULATED: ContactGraphNodeMsg.TYPE_ARTICULATED}
NODE_CATEGORY = {v: k for k, v in NODE_TYPE.items()}
JOINT_TYPE = {"fixed": SupportEdgeMsg.JOINT_FIXED, "floating": SupportEdgeMsg.JOINT_FLOATING}
JOINT_NAME = {v: k for k, v in JOINT_TYPE.items()}
#: Marker colours per category (RGBA).
CATEGORY_RGBA = {LAYOUT: (0.6, 0.6, 0.6, 0.6), RIGID: (0.12, 0.47, 0.71, 1.0),
                 ARTICULATED: (1.0, 0.5, 0.05, 1.0), SCENE: (0.2, 0.7, 0.2, 1.0)}
#: Thickness (m) of the CUBE markers drawn for supporting planes.
PLANE_MARKER_THICKNESS = 0.005



# ---------------------------------------------------------------------------------------------- conversions
def box_to_msg(box: GravityBox | None) -> OrientedBoxMsg:
    if box is None:
        return oriented_box_msg(np.zeros(3), np.zeros(3), 0.0)
    return oriented_box_msg(box.center, box.size, box.yaw)


def box_from_msg(msg: OrientedBoxMsg) -> GravityBox:
    q = msg.center.orientation
    yaw = 2.0 * np.arctan2(q.z, q.w)  # a pure yaw quaternion (gravity-aligned box)
    p, s = msg.center.position, msg.size
    return GravityBox([p.x, p.y, p.z], [abs(s.x), abs(s.y), abs(s.z)], float(yaw))


def plane_to_msg(plane: Plane | None) -> PlaneMsg:
    if plane is None:
        return PlaneMsg(coef=[0.0, 0.0, 0.0, 0.0])
    return PlaneMsg(coef=[float(x) for x in plane.as_vector()])


def plane_from_msg(msg: PlaneMsg) -> Plane | None:
    coef = np.asarray(msg.coef, np.float64)
    if np.linalg.norm(coef[:3]) < 1e-12:
        return None
    return Plane(normal=coef[:3], d=float(coef[3]))


def graph_to_msg(graph: ContactGraph, header: Header) -> ContactGraphMsg:
    """scene_graph.ContactGraph -> scene_recon_interfaces/ContactGraph (root node included)."""
    out = ContactGraphMsg(header=header, root_id=int(graph.root_id))
    for nid in sorted(graph.nodes):
        n = graph.nodes[nid]
        out.nodes.append(ContactGraphNodeMsg(
            id=int(nid), name=n.name, node_type=NODE_TYPE.get(n.category, ContactGraphNodeMsg.TYPE_RIGID),
            class_id=int(n.class_id), class_name=n.class_name, instance_id=int(nid), box=box_to_msg(n.box),
            planes=[plane_to_msg(p.plane) for p in n.planes], cad_id=n.cad_id))
    for child in sorted(graph.supports):
        e = graph.supports[child]
        out.support_edges.append(SupportEdgeMsg(parent_id=int(e.parent_id), child_id=int(child),
                                                plane=plane_to_msg(e.plane), score=float(e.score),
                                                joint_type=JOINT_TYPE.get(e.joint, SupportEdgeMsg.JOINT_FIXED)))
    out.proximal_edges = [ProximalEdge(first_id=int(a), second_id=int(b)) for a, b in graph.proximal]
    return out


def graph_from_msg(msg: ContactGraphMsg) -> ContactGraph:
    """scene_recon_interfaces/ContactGraph -> scene_graph.ContactGraph (refined boxes only)."""
    nodes = {}
    for n in msg.nodes:
        category = NODE_CATEGORY.get(n.node_type, RIGID)
        box = None if category == SCENE else box_from_msg(n.box)
        planes = [SurfacePlane(p) for p in (plane_from_msg(x) for x in n.planes) if p is not None]
        nodes[int(n.id)] = GraphNode(int(n.id), n.name, n.class_name, category, int(n.class_id), box, box, planes,
                                     cad_id=n.cad_id)
    supports = {int(e.child_id): SupportEdge(int(e.parent_id), int(e.child_id), "support", float(e.score),
                                             plane=plane_from_msg(e.plane),
                                             joint=JOINT_NAME.get(e.joint_type, "fixed"))
                for e in msg.support_edges}
    graph = ContactGraph(nodes, supports, [(int(p.first_id), int(p.second_id)) for p in msg.proximal_edges],
                         frame_id=msg.header.frame_id, root_id=int(msg.root_id))
    graph.validate()
    return graph


# ---------------------------------------------------------------------------------------------- markers
def _rgba(category: str, alpha: float | None = None) -> ColorRGBA:
    r, g, b, a = CATEGORY_RGBA.get(category, (0.3, 0.7, 0.3, 1.0))
    return ColorRGBA(r=r, g=g, b=b, a=a if alpha is None else alpha)


def _marker(kind: int, ns: str, mid: int, header: Header) -> Marker:
    m = Marker(type=kind, action=Marker.ADD, ns=ns, id=int(mid), header=header)
    m.pose.orientation.w = 1.0
    return m


def box_lines(box: GravityBox) -> list[Point]:
    """The 12 edges of a box as 24 LINE_LIST points."""
    c = box.corners()
    edges = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]
    return [Point(x=float(c[i][0]), y=float(c[i][1]), z=float(c[i][2])) for e in edges for i in e]


def graph_markers(graph: ContactGraph, header: Header) -> MarkerArray:
    """RViz view: boxes (LINE_LIST), contact patches of supporting planes (thin CUBE), arrows, labels."""
    out = MarkerArray()
    out.markers.append(Marker(action=Marker.DELETEALL, header=header))
    for nid, n in graph.nodes.items():
        if n.box is None:
            continue
        m = _marker(Marker.LINE_LIST, "boxes", nid, header)
        m.scale.x = 0.01
        m.color = _rgba(n.category)
        m.points = box_lines(n.box)
        out.markers.append(m)
        t = _marker(Marker.TEXT_VIEW_FACING, "labels", nid, header)
        t.pose.position = Point(x=float(n.box.center[0]), y=float(n.box.center[1]), z=float(n.box.z_max + 0.08))
        t.scale.z = 0.08
        t.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0)
        t.text = n.name
        out.markers.append(t)
    for child, e in graph.supports.items():
        node, parent = graph.nodes[child], graph.nodes.get(e.parent_id)
        if node.box is None:
            continue
        if e.plane is not None and abs(e.plane.normal[2]) > 1e-9:
            # The supporting plane where the child stands on it: a thin slab of the child's footprint.
            c = node.box.center
            h = -(e.plane.d + e.plane.normal[0] * c[0] + e.plane.normal[1] * c[1]) / e.plane.normal[2]
            p = _marker(Marker.CUBE, "support_planes", child, header)
            p.pose.position = Point(x=float(c[0]), y=float(c[1]), z=float(h))
            p.pose.orientation = Quaternion(z=float(np.sin(node.box.yaw / 2)), w=float(np.cos(node.box.yaw / 2)))
            p.scale = Vector3(x=float(max(node.box.size[0], 0.01)), y=float(max(node.box.size[1], 0.01)),
                              z=PLANE_MARKER_THICKNESS)
            p.color = ColorRGBA(r=0.2, g=0.8, b=0.2, a=0.5)
            out.markers.append(p)
        if parent is None or parent.box is None:
            continue
        a = _marker(Marker.ARROW, "supports", child, header)
        pc, cc = parent.box.center, node.box.center
        a.points = [Point(x=float(pc[0]), y=float(pc[1]), z=float(parent.box.z_max)),
                    Point(x=float(cc[0]), y=float(cc[1]), z=float(cc[2]))]
        a.scale = Vector3(x=0.01, y=0.03, z=0.05)
        a.color = ColorRGBA(r=0.85, g=0.15, b=0.15, a=1.0) if e.joint == "fixed" else ColorRGBA(r=0.9, g=0.8, b=0.1,
                                                                                                   a=1.0)
        out.markers.append(a)
    return out


# ---------------------------------------------------------------------------------------------- node
@dataclass
class ContactGraphNodeConfig(Settings):
    """ROS-side settings of the contact-graph node; the builder itself is `SceneGraphConfig`."""

    entities_topic: str = setting("panoptic_entities", doc="PanopticEntityArray input (the mapper's output)")
    graph_topic: str = setting("contact_graph", doc="ContactGraph output (latched)")
    markers_topic: str = setting("contact_graph_markers", doc="MarkerArray output (latched)")
    graph_json_topic: str = setting("contact_graph_json", doc="the graph as JSON (std_msgs/String, latched)")
    node_entities_topic: str = setting("contact_graph_entities",
                                       doc="PanopticEntityArray output: the geometry behind every node (latched)")
    min_period_s: float = setting(0.0, min=0.0, doc="rebuild the graph at most this often (s)")
    snapshot: bool = setting(False, doc="an entity missing from a message is dropped too, not only removed_ids")
    mesh_root: str = setting(DEFAULT_MAP_ROOT, doc="entity meshes given by mesh_uri are read only under this folder "
                             "(the mapper's data_root); empty: inline meshes only")
    #: The builder updates incrementally (only changed entities are re-initialised); some of its steps
    #: (layout splitting, fragment merging) keep state from earlier updates, so a graph built update by
    #: update can differ from one built at once (`scene-recon graph`). Once no entities came for this long,
    #: the graph is built once more from scratch and published if it differs.
    final_rebuild_s: float = setting(1.0, min=0.0, doc="rebuild from scratch after this long (s) without new "
                                     "entities (0: never)")


class ContactGraphNode(Node):
    def __init__(self) -> None:
        super().__init__("contact_graph")
        cfg = declare_config(self, SceneGraphConfig, declare_config_file(self, DEFAULT_CONFIG_FILE))
        settings = declare_config(self, ContactGraphNodeConfig)
        joints = load_support_joints(cfg.support_joints or None)
        self.min_period_s = settings.min_period_s
        self.snapshot = settings.snapshot
        self.mesh_root = Path(settings.mesh_root).expanduser().resolve() if settings.mesh_root else None
        self.builder = ContactGraphBuilder(cfg, joints)
        self._cfg, self._joints = cfg, joints
        self.final_rebuild_s = settings.final_rebuild_s
        self._incremental = False  # built update by update since the last build from scratch
        self._last_message = time.monotonic()
        self._last_graph_json = ""
        self.pub_graph = self.create_publisher(ContactGraphMsg, settings.graph_topic, LATCHED)
        self.pub_markers = self.create_publisher(MarkerArray, settings.markers_topic, LATCHED)
        self.pub_graph_json = self.create_publisher(String, settings.graph_json_topic, LATCHED)
        self.pub_node_entities = self.create_publisher(PanopticEntityArray, settings.node_entities_topic,
                                                       ENTITIES_QOS)
        self.create_subscription(PanopticEntityArray, settings.entities_topic, self._on_entities, ENTITIES_QOS)
        # node id -> (geometry fingerprint, revision published, message): revisions count geometry changes
        self._node_msgs: dict[int, tuple[str, int, object]] = {}
        self.counters = {"messages": 0, "rebuilt_entities": 0, "builds": 0, "bad_entities": 0}
        self._header: Header | None = None
        self._dirty = False
        self._last_build = -float("inf")
        self.input_rate, self.build_ms = diag.RateWindow(), diag.LatencyWindow()
        self.last_error = ""
        self._last_update_failed = False
        self._graph_nodes = 0
        self._recent = diag.RecentIncrease()
        steady_timer(self, 0.05, self._maybe_build)
        self.diagnostics = diag.NodeDiagnostics(self, "contact graph", self.health)

    def _on_entities(self, msg: PanopticEntityArray) -> None:
        self.counters["messages"] += 1
        self.input_rate.tick()
        self._last_message = time.monotonic()
        self.builder.remove(int(i) for i in msg.removed_ids)
        if self.snapshot:
            present = {int(e.id) for e in msg.entities}
            self.builder.remove([s.id for s in self.builder.source_entities() if s.id not in present])
        fresh = []
        for e in msg.entities:
            if self.builder.source_revision(int(e.id)) == int(e.revision):
                continue  # unchanged (the unlabelled surface too): skip the (costly) mesh conversion
            try:
                fresh.append(msg_to_entity(e, self.mesh_root))
            except EntityError as exc:
                self.counters["bad_entities"] += 1
                self.last_error = str(exc)
                self.get_logger().warning(str(exc), throttle_duration_sec=5.0)
        try:
            rebuilt = self.builder.update(fresh)
        except EntityError as exc:
            self.counters["bad_entities"] += 1
            self.last_error, self._last_update_failed = f"entities rejected: {exc}", True
            self.get_logger().error(self.last_error)
            return
        self._last_update_failed = False
        self.counters["rebuilt_entities"] += len(rebuilt)
        self._header = msg.header
        self._dirty = True
        self._maybe_build()

    def _maybe_build(self) -> None:
        if (not self._dirty and self._incremental and self.final_rebuild_s > 0 and self._header is not None
                and time.monotonic() - self._last_message >= self.final_rebuild_s):
            self._rebuild_from_scratch()
        if not self._dirty or self._header is None or time.monotonic() - self._last_build < self.min_period_s:
            return
        self._dirty = False
        self._last_build = time.monotonic()
        t0 = time.perf_counter()
        graph = self.builder.build(frame_id=self._header.frame_id or "map")
        self._incremental = True
        self._publish(graph, t0)

    def _rebuild_from_scratch(self) -> None:
        """Build the graph from all current entities with a fresh builder (= `scene-recon graph`)."""
        assert self._header is not None
        entities = self.builder.source_entities()  # as given: the unlabelled surface too
        builder = ContactGraphBuilder(self._cfg, self._joints)
        builder.update(entities)
        self.builder = builder
        self._incremental = False
        t0 = time.perf_counter()
        graph = builder.build(frame_id=self._header.frame_id or "map")
        if json.dumps(_without_stats(graph.to_dict())) != self._last_graph_json:
            self.counters["final_rebuilds_changed"] = self.counters.get("final_rebuilds_changed", 0) + 1
            self.get_logger().info("rebuilt from scratch: the graph differs from the incremental one; publishing it")
            self._publish(graph, t0)

    def _publish(self, graph: ContactGraph, t0: float) -> None:
        assert self._header is not None
        self._last_graph_json = json.dumps(_without_stats(graph.to_dict()))
        # the node geometry first: a consumer that reacts to the graph finds it already there
        self.pub_node_entities.publish(self._node_entities_msg(self._header))
        self.pub_graph_json.publish(String(data=json.dumps(graph.to_dict())))
        self.pub_graph.publish(graph_to_msg(graph, self._header))
        self.pub_markers.publish(graph_markers(graph, self._header))
        self.counters["builds"] += 1
        self.build_ms.add(1000 * (time.perf_counter() - t0))
        self._graph_nodes = len(graph.nodes) - 1
        self.get_logger().info(f"contact graph: {len(graph.nodes) - 1} nodes, {len(graph.proximal)} proximal, "
                               f"{1000 * (time.perf_counter() - t0):.0f} ms; {self.counters}")

    def _node_entities_msg(self, header: Header) -> PanopticEntityArray:
        """The builder's node entities; a node keeps its revision while its geometry stays the same."""
        current = self.builder.node_entities()
        msgs: dict[int, tuple[str, int, object]] = {}
        for nid, e in sorted(current.items()):
            digest = hashlib.sha1(np.ascontiguousarray(e.vertices, np.float64).tobytes()
                                  + np.ascontiguousarray(e.faces, np.int64).tobytes()
                                  + f"{e.class_name}|{e.category}".encode()).hexdigest()
            old = self._node_msgs.get(nid)
            if old is not None and old[0] == digest:
                msgs[nid] = old
                continue
            revision = old[1] + 1 if old is not None else 1
            msg = entity_to_msg(e, True)
            msg.revision = revision
            msgs[nid] = (digest, revision, msg)
        removed = sorted(i for i in self._node_msgs if i not in msgs)
        self._node_msgs = msgs
        return PanopticEntityArray(header=header, entities=[m for _, _, m in msgs.values()], removed_ids=removed)



    def health(self) -> diag.Health:
        """What /diagnostics reports: the node's counters, the input rate, the median build time."""
        c = self.counters
        h = diag.Health(hardware_id="", values={
            diag.KEY_INPUT_RATE: self.input_rate.rate_hz(), diag.KEY_LATENCY: self.build_ms.median_ms(),
            diag.KEY_RECEIVED: c["messages"], "builds": c["builds"], "rebuilt_entities": c["rebuilt_entities"],
            diag.KEY_SKIPPED: c["bad_entities"], "graph_nodes": self._graph_nodes, "build_pending": self._dirty,
            diag.KEY_LAST_ERROR: self.last_error})
        if self._last_update_failed:
            h.escalate(diag.ERROR, self.last_error)
        elif self._recent.grew("skipped", c["bad_entities"]):
            h.escalate(diag.WARN, f"entities skipped: {self.last_error}")
        if h.level == diag.OK:
            h.message = (f"{self._graph_nodes} nodes in the graph" if c["builds"]
                         else "waiting for entities")
        return h


def _without_stats(d: dict) -> dict:
    """A graph's dict without its timings (two builds of one graph differ only there)."""
    return {k: v for k, v in d.items() if k != "stats"}


def main(args: list[str] | None = None) -> int:
    return run_node(ContactGraphNode, args)


if __name__ == "__main__":
    sys.exit(main())
