"""The runner's own client node: progress from the graph's outputs, "the scene is final", the export.

It listens only to small messages (the mapper's JSON status, the contact graph, the URDF string),
never to the entity meshes, and calls the CAD replacer's `export_scene` service. It spins on a
background thread so the runner's main loop can watch its child processes at the same time.
"""

from __future__ import annotations

import json
import re
import threading
import time
from dataclasses import dataclass

#: The CAD replacer marks every URDF it publishes with the scene revision.
REVISION = re.compile(r"<!-- revision (\d+) -->")


@dataclass
class Progress:
    """What the graph has reported so far (times are `time.monotonic()`)."""

    status: dict | None = None
    status_at: float = 0.0
    graph_nodes: int = 0
    graph_at: float = 0.0
    graphs: int = 0
    revision: int = 0
    links: int = 0
    description_at: float = 0.0
    replacer: dict | None = None  # the CAD replacer's status (busy, from_scratch)
    replacer_at: float = 0.0

    def line(self) -> str:
        s = self.status or {}
        parts = [f"frames integrated {s.get('frames_integrated', 0)}", f"dropped {s.get('dropped_frames', 0)}",
                 f"queue {s.get('queue', 0)}", f"graph {max(self.graph_nodes - 1, 0)} objects",
                 f"scene revision {self.revision} ({self.links} links)"]
        return " | ".join(parts)


class GraphMonitor:
    """rclpy node in the runner process (rclpy is imported only when a runner starts one)."""

    def __init__(self, map_frame: str = "map") -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions
        from scene_recon_interfaces.msg import ContactGraph
        from scene_recon_interfaces.srv import SaveMap
        from std_msgs.msg import String
        from std_srvs.srv import Trigger

        from recon_core.ros_env import ensure_ros_environment

        ensure_ros_environment()
        self._rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("scene_recon_runner", context=self.context)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.progress = Progress()
        self._lock = threading.Lock()
        self.node.create_subscription(String, "mapper_status", self._on_status, latched)
        self.node.create_subscription(ContactGraph, "contact_graph", self._on_graph, latched)
        self.node.create_subscription(String, "robot_description", self._on_description, latched)
        self.node.create_subscription(String, "cad_replacer_status", self._on_replacer, latched)
        self._trigger = Trigger
        self.export_client = self.node.create_client(Trigger, "export_scene")
        self._save_map = SaveMap
        self.save_client = self.node.create_client(SaveMap, "save_map")
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, name="monitor", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ callbacks
    def _spin(self) -> None:
        while not self._stop.is_set() and self.context.ok():
            self.executor.spin_once(timeout_sec=0.1)

    def _on_status(self, msg) -> None:
        try:
            status = json.loads(msg.data)
        except ValueError:
            return
        with self._lock:
            self.progress.status, self.progress.status_at = status, time.monotonic()

    def _on_graph(self, msg) -> None:
        with self._lock:
            self.progress.graph_nodes, self.progress.graph_at = len(msg.nodes), time.monotonic()
            self.progress.graphs += 1

    def _on_replacer(self, msg) -> None:
        try:
            status = json.loads(msg.data)
        except ValueError:
            return
        with self._lock:
            self.progress.replacer, self.progress.replacer_at = status, time.monotonic()

    def _on_description(self, msg) -> None:
        match = REVISION.search(msg.data)
        with self._lock:
            self.progress.revision = int(match.group(1)) if match else self.progress.revision
            self.progress.links = msg.data.count("<link ")
            self.progress.description_at = time.monotonic()

    # ------------------------------------------------------------------ queries
    def snapshot(self) -> Progress:
        with self._lock:
            return Progress(**vars(self.progress))

    def settled(self, since: float, quiet_s: float) -> bool:
        """True once the mapper, reporting after `since`, has nothing left to do, and neither the contact
        graph nor the URDF changed for `quiet_s` seconds, the URDF being newer than the graph."""
        p = self.snapshot()
        s = p.status
        if s is None or p.status_at < since:
            return False
        idle = s.get("queue", 1) == 0 and s.get("pending_segmentations", 0) == 0 and not s.get(
            "unpublished_changes", False)
        now = time.monotonic()
        last_change = max(p.graph_at, p.description_at)
        # the replacer has seen the newest graph, its last pass ran from scratch and is over: its scene is the
        # batch one (`scene-recon replace`); without its status, the URDF must be newer than the graph
        if p.replacer is not None:
            replaced = (p.replacer_at >= p.graph_at and not p.replacer.get("busy")
                        and p.replacer.get("from_scratch", True))
        else:
            replaced = p.description_at >= p.graph_at
        return idle and replaced and p.revision > 0 and now - last_change >= quiet_s and now - p.status_at < 5.0

    def export(self, timeout_s: float = 120.0) -> tuple[bool, str]:
        """Ask the CAD replacer to write the scene folder; (success, URDF path or the reason)."""
        return self._call(self.export_client, self._trigger.Request(), timeout_s)

    def save_map(self, path: str, timeout_s: float = 120.0) -> tuple[bool, str]:
        """Ask the mapper to save its map and entities under its data root; (success, message)."""
        return self._call(self.save_client, self._save_map.Request(path=path), timeout_s)

    def _call(self, client, request, timeout_s: float) -> tuple[bool, str]:
        if not client.wait_for_service(timeout_sec=min(timeout_s, 10.0)):
            return False, f"{client.srv_name} service not available"
        future = client.call_async(request)
        deadline = time.monotonic() + timeout_s
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.05)
        if not future.done():
            future.cancel()
            return False, f"{client.srv_name} did not answer within {timeout_s:.0f} s"
        res = future.result()
        return bool(res.success), str(res.message)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.executor.shutdown(timeout_sec=5)
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)
