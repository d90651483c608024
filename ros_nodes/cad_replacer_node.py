"""`cad_replacer`: stage 4 (CAD replacement) as a ROS 2 node over ``cad_replacement``.

Inputs: ``contact_graph_json`` (std_msgs/String, latched: the graph in the JSON of `recon_core.contact_graph`,
lossless — unrefined boxes, plane areas, contact ratios —, the very file `scene-recon replace` reads),
or else ``contact_graph`` (scene_recon_interfaces/ContactGraph, latched; used until a JSON graph has
been seen, for publishers that only have the typed message), and ``contact_graph_entities``
(PanopticEntityArray: the geometry behind the nodes as the contact-graph builder left it — the same
geometry `scene-recon replace` reads from the `graph` command's `nodes/` folder). After every graph update the replacer
re-matches only the entities whose revision, parent or box changed and republishes:

* ``robot_description`` (std_msgs/String, transient-local): the scene URDF, root ``map``, link meshes
  as ``file://`` URIs under ``output_dir`` (RViz's RobotModel and planners load it as it is);
* ``/tf_static``: the fixed joints; ``/tf`` (every ``tf_period_s``): the floating joints of movable
  objects and the articulated joints at their current values;
* ``joint_states`` (sensor_msgs/JointState): the movable joints (revolute/prismatic);
* ``cad_markers`` (MarkerArray, latched): every link as a MESH_RESOURCE marker in the map frame.

Services: ``apply_scene_action`` (ApplySceneAction: set a joint, move, re-parent; validated by
``cad_replacement.actions``, a refused action changes nothing) and ``export_scene`` (std_srvs/Trigger:
writes the scene folder of ``cad_replacement.export`` (scene.urdf, scene.xml, scene.glb, joint_states.json)
plus replacement.json and contact_graph.json into ``output_dir``; the message names the URDF).
Every publication carries the scene revision in the URDF (``<!-- revision N -->``) and in the
``joint_states`` header's frame id is the map frame. Parameters: ``CadReplacerNodeConfig`` and
``CadReplacementConfig`` under ``replace.`` (dotted names, see ``ros_nodes.parameters``).
``/diagnostics`` (``ros_nodes.diagnostics``, every second): graphs received and their rate, replacements,
the median replacement time, objects, revision, the newest error; ERROR when the last replacement failed
(the previous scene stays published), WARN when entities were skipped within the last seconds.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from geometry_msgs.msg import Point, Pose, Quaternion, Transform, Vector3
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from scene_recon_interfaces.msg import ContactGraph as ContactGraphMsg
from scene_recon_interfaces.msg import PanopticEntityArray
from scene_recon_interfaces.srv import ApplySceneAction
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import Marker, MarkerArray

from cad_replacement.actions import ActionError, SceneAction, apply_action
from cad_replacement.cad.library import CadLibrary
from cad_replacement.export import export_scene, scene_to_tree
from cad_replacement.physical_check import PhysicalCheck
from cad_replacement.replace_config import CadReplacementConfig
from cad_replacement.replacer import CadReplacer, object_node_ids
from cad_replacement.scene_model import ReplacedScene
from cad_replacement.workers import ReplaceWorkers, resolve_workers
from recon_core.config import Settings, setting
from recon_core.contact_graph import ContactGraph
from recon_core.entity import Entity
from recon_core.errors import EntityError
from recon_core.io import write_text_atomic
from recon_core.kinematic_tree import KinematicTree
from ros_nodes import diagnostics as diag
from ros_nodes.contact_graph_node import graph_from_msg
from ros_nodes.conversions import make_transform_stamped, matrix_to_transform, ns_to_stamp, transform_to_matrix
from ros_nodes.entity_conversions import DEFAULT_MAP_ROOT, msg_to_entity
from ros_nodes.parameters import declare_config
from ros_nodes.qos import ENTITIES, LATCHED, TF_DYNAMIC, TF_STATIC
from ros_nodes.runner import run_node, steady_timer

ACTION_KIND = {ApplySceneAction.Request.SET_JOINT: "set_joint", ApplySceneAction.Request.MOVE_OBJECT: "move",
               ApplySceneAction.Request.REPARENT: "reparent"}


@dataclass
class CadReplacerNodeConfig(Settings):
    """ROS-side settings of the CAD replacer; the replacement itself is `CadReplacementConfig` (``replace.``)."""

    graph_topic: str = setting("contact_graph", doc="ContactGraph input (latched; the JSON one wins)")
    graph_json_topic: str = setting("contact_graph_json", doc="contact graph as JSON (std_msgs/String, latched)")
    entities_topic: str = setting("contact_graph_entities",
                                  doc="PanopticEntityArray input: node geometry (the contact graph node's)")
    description_topic: str = setting("robot_description", doc="URDF output (std_msgs/String, latched)")
    joint_states_topic: str = setting("joint_states", doc="JointState output")
    markers_topic: str = setting("cad_markers", doc="MarkerArray output (latched)")
    seeds_per_class: int = setting(10, min=1,
                                   doc="procedural CAD models per class (articulated classes, shelves: 2x)")
    cad_dir: str = setting("", doc="folder of imported CAD assets (<class>/<model>/ with a URDF); empty: none")
    output_dir: str = setting("scene_recon_data/scene", doc="where the scene's URDF and meshes are written")
    tf_period_s: float = setting(0.1, min=0.01, doc="period of /tf and joint_states (s)")
    min_period_s: float = setting(0.5, min=0.0, doc="replace at most this often (s)")
    mesh_root: str = setting(DEFAULT_MAP_ROOT, doc="entity meshes given by mesh_uri are read only under this folder "
                             "(the mapper's data_root); empty: inline meshes only")
    #: Replacement is incremental (an unchanged object keeps its match); the physical check's choices
    #: among ranked candidates can then depend on the order objects came in. Once no graph came for this
    #: long, the scene is replaced once more from scratch (= `scene-recon replace`) and published if it differs.
    final_replace_s: float = setting(1.0, min=0.0, doc="replace from scratch after this long (s) without a new "
                                     "graph (0: never)")
    #: A graph and its entities come on two topics, in either order. A graph whose objects' entities have
    #: not come yet would give a scene without those objects, published and replaced a moment later.
    entities_wait_s: float = setting(2.0, min=0.0, doc="wait up to this long (s) for the entities a new graph "
                                     "names before replacing without them")


class CadReplacerNode(Node):
    def __init__(self) -> None:
        super().__init__("cad_replacer")
        self.settings = declare_config(self, CadReplacerNodeConfig)
        replace_cfg = declare_config(self, CadReplacementConfig, prefix="replace.")
        library = CadLibrary(root=self.settings.cad_dir or None, seeds_per_class=self.settings.seeds_per_class)
        # One worker pool for the node's life: a replacer made afresh (final replacement) keeps the warm workers.
        n_workers = resolve_workers(replace_cfg.workers)
        self._workers = ReplaceWorkers(library, n_workers) if n_workers > 1 else None
        self._make_replacer = lambda: CadReplacer(library, replace_cfg,
                                                  physical_check=PhysicalCheck(method=replace_cfg.method),
                                                  workers=self._workers)
        self.replacer = self._make_replacer()
        self._incremental = False
        self._last_input = time.monotonic()
        self.output_dir = Path(self.settings.output_dir).resolve()
        self.mesh_root = Path(self.settings.mesh_root).expanduser().resolve() if self.settings.mesh_root else None
        self.lock = threading.RLock()  # _install publishes the dynamic state under the same lock
        self.scene: ReplacedScene | None = None
        self.tree: KinematicTree | None = None
        self.frames: dict[str, str] = {}
        self.joint_names: list[str] = []
        self.records: list[dict] = []
        self.entities: dict[int, Entity] = {}
        self.graph: ContactGraph | None = None  # the newest graph (read from the typed message or the JSON)
        self._replaced_graph: ContactGraph | None = None  # the graph the current scene was replaced from
        self._dirty = False
        self._last = -float("inf")
        self._graph_objects: set[int] = set()  # the object node ids of the newest graph
        self._graph_time = -float("inf")  # when the newest graph came (monotonic s)
        self._acted = False  # an action changed the scene since the newest input
        self.counters = {"graphs": 0, "replacements": 0, "rematched": 0, "actions": 0, "refused": 0,
                         "bad_entities": 0, "failed": 0}
        self.input_rate, self.replace_ms = diag.RateWindow(), diag.LatencyWindow()
        self.last_error = ""
        self._last_failed = False
        self._recent = diag.RecentIncrease()
        work = MutuallyExclusiveCallbackGroup()
        io = MutuallyExclusiveCallbackGroup()
        s = self.settings
        self.pub_description = self.create_publisher(String, s.description_topic, LATCHED)
        self.pub_status = self.create_publisher(String, "cad_replacer_status", LATCHED)
        self.pub_markers = self.create_publisher(MarkerArray, s.markers_topic, LATCHED)
        self.pub_joints = self.create_publisher(JointState, s.joint_states_topic, 10)
        self.pub_tf = self.create_publisher(TFMessage, "/tf", TF_DYNAMIC)
        self.pub_tf_static = self.create_publisher(TFMessage, "/tf_static", TF_STATIC)
        self.create_subscription(PanopticEntityArray, s.entities_topic, self._on_entities, ENTITIES,
                                 callback_group=io)
        self.create_subscription(ContactGraphMsg, s.graph_topic, self._on_graph, LATCHED, callback_group=io)
        self.create_subscription(String, s.graph_json_topic, self._on_graph_json, LATCHED, callback_group=io)
        self._json_seen = False
        self.create_service(ApplySceneAction, "apply_scene_action", self._srv_action, callback_group=io)
        self.create_service(Trigger, "export_scene", self._srv_export, callback_group=io)
        steady_timer(self, 0.05, self._maybe_replace, work)
        steady_timer(self, s.tf_period_s, self._publish_dynamic, io)
        self.diagnostics = diag.NodeDiagnostics(self, "CAD replacement", self.health, callback_group=io)

    # ------------------------------------------------------------------ inputs
    def _on_entities(self, msg: PanopticEntityArray) -> None:
        fresh: dict[int, Entity] = {}
        for e in msg.entities:
            old = self.entities.get(int(e.id))
            if old is not None and old.revision == int(e.revision):
                continue
            try:
                fresh[int(e.id)] = msg_to_entity(e, self.mesh_root)
            except EntityError as exc:
                self.counters["bad_entities"] += 1
                self.last_error = f"entity {e.id} skipped: {exc}"
                self.get_logger().warning(f"entity {e.id} skipped: {exc}", throttle_duration_sec=5.0)
        with self.lock:
            self._last_input = time.monotonic()
            for i in msg.removed_ids:
                self.entities.pop(int(i), None)
            self.entities.update(fresh)
            if fresh or msg.removed_ids:
                self._dirty, self._acted = True, False

    def _new_graph(self, graph: ContactGraph) -> None:
        """Make ``graph`` the newest (under the lock): a replacement is due once its objects' entities are here."""
        self.graph = graph
        self._graph_objects, self._graph_time = set(object_node_ids(graph)), time.monotonic()
        self._dirty, self._acted = True, False

    def _read_graph(self, read: Callable[[], ContactGraph]) -> ContactGraph | None:
        """The graph ``read`` returns, or None (counted, logged) for one that cannot be read: the last stays."""
        try:
            return read()
        except Exception as exc:  # one bad graph must not take the node down
            self.counters["failed"] += 1
            self.last_error, self._last_failed = f"graph not readable: {type(exc).__name__}: {exc}", True
            self.get_logger().error(f"{self.last_error}; the current scene stays")
            return None

    def _on_graph(self, msg: ContactGraphMsg) -> None:
        if self._json_seen:  # the same graph comes as JSON too, without the typed message's losses
            return
        graph = self._read_graph(lambda: graph_from_msg(msg))
        if graph is None:
            return
        with self.lock:
            if self._json_seen:
                return
            self._new_graph(graph)
        self.counters["graphs"] += 1
        self.input_rate.tick()

    def _on_graph_json(self, msg: String) -> None:
        self._json_seen = True
        graph = self._read_graph(lambda: ContactGraph.from_dict(json.loads(msg.data)))
        if graph is None:
            return
        with self.lock:
            self._last_input = time.monotonic()
            self._new_graph(graph)
        self.counters["graphs"] += 1
        self.input_rate.tick()

    # ------------------------------------------------------------------ replacement
    def _awaiting_entities(self) -> bool:
        """Whether the newest graph names objects whose entities have not come, and may still (under the lock)."""
        return (bool(self._graph_objects - self.entities.keys())
                and time.monotonic() - self._graph_time < self.settings.entities_wait_s)

    def _maybe_replace(self) -> None:
        with self.lock:
            # (a scene acted on is the user's: a pass from scratch would undo the actions, so it waits for input)
            final = (not self._dirty and self._incremental and self.graph is not None and not self._acted
                     and self.settings.final_replace_s > 0
                     and time.monotonic() - self._last_input >= self.settings.final_replace_s)
            if final:
                self.replacer = self._make_replacer()  # no result of an earlier graph carries over
                self._incremental = False
            elif (not self._dirty or self.graph is None
                  or time.monotonic() - self._last < self.settings.min_period_s or self._awaiting_entities()):
                return
            else:  # (without final passes every scene counts as final)
                self._incremental = self.settings.final_replace_s > 0
            self._dirty = False
            self._last = time.monotonic()
            graph = self.graph
            entities = dict(self.entities)
            base = self.scene  # an action installed during the replacement replaces this scene
            missing = len(self._graph_objects - entities.keys())
        if missing:
            self.get_logger().warning(f"{missing} object(s) of the graph came without entities within "
                                      f"{self.settings.entities_wait_s:g} s: replacing without them")
        self._publish_status(busy=True)
        t0 = time.perf_counter()
        try:
            result = self.replacer.replace(graph, entities)
        except Exception as exc:  # one bad graph must not take the node down: the last scene stays
            self.counters["failed"] += 1
            self.last_error, self._last_failed = f"replacement failed: {type(exc).__name__}: {exc}", True
            self.get_logger().error(f"{self.last_error}; the current scene stays")
            self._publish_status(busy=False)
            return
        self._last_failed = False
        self.replace_ms.add(1000 * (time.perf_counter() - t0))
        self.counters["replacements"] += 1
        self.counters["rematched"] += result.rematched
        with self.lock:
            if final and self.scene is not base:
                self.get_logger().info("replaced from scratch, but the scene was acted on meanwhile: it stays")
                self._publish_status(busy=False)
                return
            if final and self.scene is not None and self._urdf_body(result.scene) == self._urdf_body(self.scene):
                self.get_logger().info("replaced from scratch: the same scene; revision kept")
                self._publish_status(busy=False)
                return
            # (numbered here: an action may have installed a revision while this one was being replaced)
            revision = result.scene.revision = self.scene.revision + 1 if self.scene is not None else 1
            self.records = [r.to_dict() for r in result.records]
            self._replaced_graph = graph
            self._install(result.scene)
        self._publish_status(busy=False)
        self.get_logger().info(f"scene revision {revision}: {len(result.scene)} objects, {result.rematched} "
                               f"re-matched in {time.perf_counter() - t0:.2f} s"
                               f"{' (from scratch)' if final else ''}; {self.counters}")

    def on_shutdown(self) -> None:
        """Stop the CAD worker processes (``runner.shutdown_node`` calls this before destroying the node)."""
        if self._workers is not None:
            self._workers.close()

    def health(self) -> diag.Health:
        """What /diagnostics reports: the node's counters, the input rate, the median replacement time."""
        with self.lock:
            scene, c = self.scene, dict(self.counters)
            pending = self._dirty
        h = diag.Health(values={
            diag.KEY_INPUT_RATE: self.input_rate.rate_hz(), diag.KEY_LATENCY: self.replace_ms.median_ms(),
            diag.KEY_RECEIVED: c["graphs"], diag.KEY_PROCESSED: c["replacements"], "failed": c["failed"],
            "rematched": c["rematched"], diag.KEY_SKIPPED: c["bad_entities"], "actions": c["actions"],
            "refused_actions": c["refused"], "objects": len(scene) if scene is not None else 0,
            "revision": scene.revision if scene is not None else 0, "replacement_pending": pending,
            diag.KEY_LAST_ERROR: self.last_error})
        if self._last_failed:
            h.escalate(diag.ERROR, self.last_error)
        elif self._recent.grew("skipped", c["bad_entities"]):
            h.escalate(diag.WARN, f"entities skipped: {self.last_error}")
        if h.level == diag.OK:
            h.message = (f"scene revision {scene.revision}: {len(scene)} objects" if scene is not None
                         else "waiting for a contact graph")
        return h

    def _urdf_body(self, scene: ReplacedScene) -> str:
        """The scene's URDF without its revision: what tells two scenes apart."""
        mesh_dir = self.output_dir / "meshes"
        return scene_to_tree(scene).urdf_text(mesh_dir, f"file://{mesh_dir}/")

    def _publish_status(self, busy: bool) -> None:
        """`cad_replacer_status` (JSON, latched): revision, whether a replacement runs, and whether the
        current scene was replaced from scratch (then it is what `scene-recon replace` gives)."""
        with self.lock:
            status = {"revision": self.scene.revision if self.scene is not None else 0, "busy": busy,
                      "from_scratch": not self._incremental, "counters": dict(self.counters)}
        self.pub_status.publish(String(data=json.dumps(status)))

    def _install(self, scene: ReplacedScene) -> None:
        """Make ``scene`` current and publish its description, static TF, markers and dynamic state."""
        tree = scene_to_tree(scene)
        link_names, joint_names = tree.safe_names()
        mesh_dir = self.output_dir / "meshes"
        text = tree.urdf_text(mesh_dir, f"file://{mesh_dir}/")
        text = text.replace("</robot>", f"  <!-- revision {scene.revision} -->\n</robot>")
        self.scene, self.tree, self.frames = scene, tree, link_names
        self.joint_names = [n for j, n in zip(tree.joints, joint_names, strict=True) if j.movable]
        self.pub_description.publish(String(data=text))
        stamp = self.get_clock().now().nanoseconds
        static = [make_transform_stamped(j.origin, link_names[j.parent], link_names[j.child], stamp)
                  for j in tree.joints if j.type == "fixed"]
        self.pub_tf_static.publish(TFMessage(transforms=static))
        self.pub_markers.publish(self._markers(tree, link_names, mesh_dir, stamp))
        self._publish_dynamic()

    def _markers(self, tree: KinematicTree, link_names: dict[str, str], mesh_dir: Path, stamp: int) -> MarkerArray:
        out = MarkerArray(markers=[Marker(action=Marker.DELETEALL)])
        poses = tree.link_poses()
        for k, link in enumerate(tree.links):
            if link.mesh is None or not len(link.mesh.faces):
                continue
            m = Marker(type=Marker.MESH_RESOURCE, action=Marker.ADD, ns="cad", id=k)
            m.header.frame_id = tree.root
            m.header.stamp = ns_to_stamp(stamp)
            m.mesh_resource = f"file://{mesh_dir}/{link_names[link.name]}.stl"
            m.pose = _pose_msg(poses[link.name])
            m.scale.x = m.scale.y = m.scale.z = 1.0
            r, g, b, a = link.rgba or (0.7, 0.7, 0.7, 1.0)
            m.color.r, m.color.g, m.color.b, m.color.a = float(r), float(g), float(b), float(a)
            out.markers.append(m)
        return out

    def _publish_dynamic(self) -> None:
        with self.lock:
            tree, frames, names = self.tree, self.frames, self.joint_names
        if tree is None:
            return
        stamp = self.get_clock().now().nanoseconds
        moving = [make_transform_stamped(j.transform(tree.joint_values.get(j.name, j.zero_value)),
                                         frames[j.parent], frames[j.child], stamp)
                  for j in tree.joints if j.type != "fixed"]
        if moving:
            self.pub_tf.publish(TFMessage(transforms=moving))
        movable = [j for j in tree.joints if j.movable]
        state = JointState(name=names, position=[float(tree.joint_values.get(j.name, j.zero_value)) for j in movable])
        state.header.stamp = ns_to_stamp(stamp)
        state.header.frame_id = tree.root
        self.pub_joints.publish(state)

    # ------------------------------------------------------------------ services
    def _srv_action(self, req: ApplySceneAction.Request, res: ApplySceneAction.Response) -> ApplySceneAction.Response:
        with self.lock:
            scene = self.scene
        res.revision = scene.revision if scene is not None else 0
        if scene is None:
            res.success, res.message = False, "no scene yet: waiting for a contact graph"
            return res
        kind = ACTION_KIND.get(req.action)
        if kind is None:
            res.success, res.message = False, f"unknown action {req.action}; use SET_JOINT, MOVE_OBJECT or REPARENT"
            return res
        if req.frame_id and req.frame_id != scene.frame_id:
            res.success, res.message = False, f"poses must be given in {scene.frame_id!r}, not {req.frame_id!r}"
            return res
        pose = _matrix(req.pose) if kind == "move" else None
        action = SceneAction(kind, object_name=req.object_name, joint=req.joint_name, value=req.joint_value,
                             pose=pose, new_parent=req.new_parent)
        try:
            updated = apply_action(scene, action)
        except ActionError as exc:
            self.counters["refused"] += 1
            res.success, res.message = False, str(exc)
            return res
        with self.lock:
            self._install(updated)
            self._acted = True
        self.counters["actions"] += 1
        res.success, res.message, res.revision = True, f"{kind} applied", updated.revision
        return res

    def _srv_export(self, _req: Trigger.Request, res: Trigger.Response) -> Trigger.Response:
        with self.lock:
            tree, records, scene, graph = self.tree, list(self.records), self.scene, self._replaced_graph
        if tree is None or scene is None:
            res.success, res.message = False, "no scene yet: waiting for a contact graph"
            return res
        urdf = export_scene(scene, self.output_dir).urdf
        if graph is not None:  # the input, as `scene-recon replace` leaves it: the folder can be scored alone
            graph.save(self.output_dir / "contact_graph.json")
        write_text_atomic(self.output_dir / "replacement.json",
                          json.dumps({"revision": scene.revision, "objects_detail": records}, indent=1))
        res.success, res.message = True, str(urdf)
        return res


def _pose_msg(matrix: np.ndarray) -> Pose:
    t = matrix_to_transform(matrix)
    return Pose(position=Point(x=t.translation.x, y=t.translation.y, z=t.translation.z),
                orientation=Quaternion(x=t.rotation.x, y=t.rotation.y, z=t.rotation.z, w=t.rotation.w))


def _matrix(pose: Pose) -> np.ndarray:
    return transform_to_matrix(Transform(translation=Vector3(x=pose.position.x, y=pose.position.y,
                                                             z=pose.position.z), rotation=pose.orientation))


def main(args: list[str] | None = None) -> int:
    return run_node(CadReplacerNode, args, threads=3)


if __name__ == "__main__":
    sys.exit(main())
