"""`panoptic_mapper`: the volumetric panoptic mapper as a ROS 2 node (thin adapter over PanopticMapper).

Inputs: color + depth images and camera info (approximately synchronised here), camera pose from
TF (`map_frame` <- image frame). Keyframes are sent to the segmentation service asynchronously:
a slow or dead service never blocks integration — other frames keep integrating geometry, and a
keyframe whose answer does not come within `segmentation_timeout_s` integrates without labels.
Outputs: `panoptic_entities` (PanopticEntityArray) and `panoptic_map_markers` (MarkerArray) at
`publish_period_s` when the map changed; services save_map / load_map / reset_map / extract_entities.

Parameters: `config_file` (the mapper YAML, empty: config/mapper.yaml), every key of that file under
its dotted name (`mode`, `tsdf.voxel_size_m`, `keyframes.enabled`, ...; see `ros_nodes.parameters`),
and the node's own settings, `MapperNodeConfig` (topics, frames, timeouts, publishing).
"""

from __future__ import annotations

import collections
import sys
import time
from dataclasses import dataclass

import numpy as np
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from scene_recon_interfaces.msg import PanopticEntityArray
from scene_recon_interfaces.srv import ExtractEntities, LoadMap, ResetMap, SaveMap, SegmentImage
from sensor_msgs.msg import CameraInfo, Image
from visualization_msgs.msg import MarkerArray

from panoptic_mapping.config import MapperConfig
from panoptic_mapping.dataio.transforms import TransformLookupError
from panoptic_mapping.fusion import BACKGROUND, PanopticMasks
from panoptic_mapping.mapper import PanopticMapper
from panoptic_mapping.pipeline import class_metas
from recon_core.classes import load_class_table
from recon_core.config import CONFIG_DIR, ConfigError, Settings, setting
from recon_core.frame import DatasetError, RGBDFrame
from ros_nodes.conversions import camera_info_to_intrinsics, image_to_depth, image_to_labels, image_to_rgb, stamp_to_ns
from ros_nodes.entity_conversions import entity_to_msg, map_markers
from ros_nodes.parameters import declare_config, declare_config_file
from ros_nodes.qos import ENTITIES, SENSOR_RELIABLE
from ros_nodes.runner import run_node
from ros_nodes.tf_listener import TFListener


@dataclass
class _Pending:
    frame: RGBDFrame
    color_msg: Image
    depth_msg: Image
    future: object
    sent: float


@dataclass
class MapperNodeConfig(Settings):
    """ROS-side settings of the mapper node; the mapping itself is `MapperConfig` (config/mapper.yaml)."""

    map_frame: str = setting("map", doc="fixed frame the camera poses are looked up in (TF)")
    color_topic: str = setting("/camera/color/image_raw", doc="color images")
    depth_topic: str = setting("/camera/depth/image_rect_raw", doc="depth images registered to color")
    camera_info_topic: str = setting("/camera/color/camera_info", doc="intrinsics of the color camera")
    segmentation_service: str = setting("segment_image", doc="SegmentImage service asked for keyframe labels")
    use_segmentation: bool = setting(True, doc="false: map geometry only, never call the service")
    sync_slop_s: float = setting(0.02, min=0.0, doc="max |t_color - t_depth| (s) of an image pair")
    segmentation_timeout_s: float = setting(
        3.0, min=0.0, doc="a keyframe whose labels take longer (s) integrates without them")
    tf_wait_s: float = setting(0.5, min=0.0, doc="how long (s) a frame waits for its pose and camera info")
    publish_period_s: float = setting(2.0, min=0.0, min_exclusive=True,
                                      doc="entities and markers are published at most this often (s)")
    publish_meshes: bool = setting(True, doc="entity messages carry their meshes")
    max_queue: int = setting(30, min=1, doc="frames waiting to be integrated; older ones are dropped")
    class_table: str = setting("", doc="class table YAML (default config/classes.yaml); the segmentation "
                               "service's onnx.class_table must be the same")


class MapperNode(Node):
    def __init__(self) -> None:
        super().__init__("panoptic_mapper")
        self.config = declare_config(self, MapperConfig, declare_config_file(self, CONFIG_DIR / "mapper.yaml"))
        self.settings = settings = declare_config(self, MapperNodeConfig)
        self.map_frame = settings.map_frame
        self.sync_slop_ns = int(settings.sync_slop_s * 1e9)
        self.use_segmentation = settings.use_segmentation
        self.seg_timeout_s = settings.segmentation_timeout_s
        self.tf_wait_s = settings.tf_wait_s
        self.publish_period_s = settings.publish_period_s
        self.include_meshes = settings.publish_meshes
        self.max_queue = settings.max_queue
        self.class_table = load_class_table(settings.class_table) if settings.class_table else None
        self.mapper = PanopticMapper(self.config, class_metas(self.class_table))
        # inputs run on callback groups of their own (other executor threads), so TF and images keep
        # arriving while a frame is being integrated; TF has a group to itself: sharing one with
        # the image stream starved it (frames then all lacked poses); the map is touched by one group
        inputs = MutuallyExclusiveCallbackGroup()
        self.map_group = MutuallyExclusiveCallbackGroup()
        self.tf = TFListener(self, callback_group=MutuallyExclusiveCallbackGroup())
        self.create_subscription(Image, settings.color_topic, self._on_color,
                                 SENSOR_RELIABLE, callback_group=inputs)
        self.create_subscription(Image, settings.depth_topic, self._on_depth,
                                 SENSOR_RELIABLE, callback_group=inputs)
        self.create_subscription(CameraInfo, settings.camera_info_topic, self._on_info, SENSOR_RELIABLE,
                                 callback_group=inputs)
        self.seg_client = self.create_client(SegmentImage, settings.segmentation_service)
        self.pub_entities = self.create_publisher(PanopticEntityArray, "panoptic_entities", ENTITIES)
        self.pub_markers = self.create_publisher(MarkerArray, "panoptic_map_markers", 1)
        self.create_service(SaveMap, "save_map", self._srv_save, callback_group=self.map_group)
        self.create_service(LoadMap, "load_map", self._srv_load, callback_group=self.map_group)
        self.create_service(ResetMap, "reset_map", self._srv_reset, callback_group=self.map_group)
        self.create_service(ExtractEntities, "extract_entities", self._srv_extract, callback_group=self.map_group)
        self.colors: collections.deque[Image] = collections.deque(maxlen=30)
        self.info: CameraInfo | None = None
        self.queue: collections.deque[tuple[Image, Image, float]] = collections.deque()
        self.pending: list[_Pending] = []
        self.counters = collections.Counter()
        self._changed = False
        self._published_revision: dict[int, int] = {}
        # entity messages by (id, revision, with mesh): unchanged entities are not converted again
        self._msg_cache: dict[tuple[int, int, bool], object] = {}
        self.create_timer(0.01, self._process, callback_group=self.map_group)
        self.create_timer(self.publish_period_s, self._publish, callback_group=self.map_group)
        self.create_timer(10.0, self._report, callback_group=inputs)

    # ------------------------------------------------------------------ inputs
    def _on_info(self, msg: CameraInfo) -> None:
        self.info = msg

    def _on_color(self, msg: Image) -> None:
        self.colors.append(msg)

    def _on_depth(self, msg: Image) -> None:
        t = stamp_to_ns(msg.header.stamp)
        best = min(self.colors, key=lambda c: abs(stamp_to_ns(c.header.stamp) - t), default=None)
        if best is None or abs(stamp_to_ns(best.header.stamp) - t) > self.sync_slop_ns:
            self.counters["unpaired_depth"] += 1
            return
        self.queue.append((best, msg, time.monotonic()))
        while len(self.queue) > self.max_queue:  # cannot keep up: drop the oldest, keep the newest
            self.queue.popleft()
            self.counters["dropped_backlog"] += 1

    def _make_frame(self, color_msg: Image, depth_msg: Image) -> RGBDFrame | None:
        stamp = stamp_to_ns(depth_msg.header.stamp)
        try:
            color = image_to_rgb(color_msg)
            depth, n_bad = image_to_depth(depth_msg)
            intr = camera_info_to_intrinsics(self.info)
            pose = self.tf.lookup(self.map_frame, color_msg.header.frame_id, stamp)
            return RGBDFrame(color, depth, intr, pose, stamp, self.mapper.frames_integrated,
                             color_msg.header.frame_id, n_bad)
        except DatasetError as exc:
            self.counters["bad_image"] += 1
            self.get_logger().error(f"frame at {stamp * 1e-9:.3f} s skipped: {exc}", throttle_duration_sec=5.0)
            return None

    # ------------------------------------------------------------------ processing
    def _process(self) -> None:
        self._collect_segmentations()
        if not self.queue:
            return
        color_msg, depth_msg, arrived = self.queue[0]
        # waiting is measured from the frame's arrival, not its stamp: replayed recordings carry old stamps
        waited = time.monotonic() - arrived
        if self.info is None:
            if waited < self.tf_wait_s:
                return
            self.queue.popleft()
            self.counters["no_camera_info"] += 1
            self.get_logger().warning("frame skipped: no camera info received yet", throttle_duration_sec=5.0)
            return
        try:
            frame = self._make_frame(color_msg, depth_msg)
        except TransformLookupError as exc:
            if waited < self.tf_wait_s:
                return  # TF may still arrive: keep the frame at the head of the queue
            self.queue.popleft()
            self.counters["no_tf"] += 1
            self.get_logger().warning(f"frame skipped, no pose: {exc}", throttle_duration_sec=5.0)
            return
        self.queue.popleft()
        if frame is None:
            return
        if self.mapper.is_keyframe(frame):
            if not self.use_segmentation:
                self.mapper.mark_keyframe(frame)
            elif self.seg_client.service_is_ready():
                self.mapper.mark_keyframe(frame)
                req = SegmentImage.Request(color=color_msg, has_depth=True, depth=depth_msg)
                self.pending.append(_Pending(frame, color_msg, depth_msg, self.seg_client.call_async(req),
                                             time.monotonic()))
                self.counters["segmentation_calls"] += 1
                return
            else:  # not marked: the next frames stay keyframe candidates until the service is up
                self.counters["keyframes_unsegmented"] += 1
                self.get_logger().warning("segmentation service not available: mapping geometry only",
                                          throttle_duration_sec=10.0)
        # without segmentation no label is ever fused: the TSDF-only path (no depth segmentation)
        self._integrate(frame, None, geometry_only=not self.use_segmentation)

    def _collect_segmentations(self) -> None:
        still = []
        for item in self.pending:
            if item.future.done():
                masks = None
                try:
                    res = item.future.result()
                    if res is not None and res.success:
                        masks = self._masks(res)
                    else:
                        self.counters["segmentation_failed"] += 1
                        self.get_logger().warning(f"segmentation failed: {getattr(res, 'message', '')}",
                                                  throttle_duration_sec=5.0)
                except Exception as exc:  # the service died mid-call: map geometry anyway
                    self.counters["segmentation_failed"] += 1
                    self.get_logger().warning(f"segmentation call failed: {exc}", throttle_duration_sec=5.0)
                self._integrate(item.frame, masks)
            elif time.monotonic() - item.sent > self.seg_timeout_s:
                self.counters["segmentation_timeout"] += 1
                self.get_logger().warning("segmentation service too slow: keyframe integrated without labels",
                                          throttle_duration_sec=5.0)
                self._integrate(item.frame, None)
            else:
                still.append(item)
        self.pending = still

    def _masks(self, res: SegmentImage.Response) -> PanopticMasks:
        labels = image_to_labels(res.labels)
        n = max([s.id for s in res.segments], default=0) + 1
        cls = np.full(n, BACKGROUND, np.int32)
        thing = np.zeros(n, bool)
        score = np.zeros(n)
        for s in res.segments:
            cls[s.id], thing[s.id], score[s.id] = s.class_id, s.is_thing, s.score
        return PanopticMasks(np.where(labels < n, labels, 0).astype(np.int32), cls, thing, score)

    def _integrate(self, frame: RGBDFrame, masks: PanopticMasks | None, geometry_only: bool = False) -> None:
        try:
            if masks is not None and masks.labels.shape != frame.depth.shape:
                self.get_logger().error("segmentation labels do not match the image size; ignored")
                masks = None
            if geometry_only:
                self.mapper.integrate_geometry(frame)
            else:
                self.mapper.integrate(frame, masks)
            self.counters["integrated"] += 1
            self._changed = True
        except (ValueError, DatasetError) as exc:
            self.counters["integration_error"] += 1
            self.get_logger().error(f"frame not integrated: {exc}", throttle_duration_sec=5.0)

    # ------------------------------------------------------------------ outputs
    def _entities_msg(self, include_meshes: bool) -> PanopticEntityArray:
        ents = self.mapper.entities(with_meshes=True)
        msg = PanopticEntityArray()
        msg.header.frame_id = self.map_frame
        msg.header.stamp = self.get_clock().now().to_msg()
        cache = {}
        for e in ents:
            key = (int(e.id), int(e.revision), include_meshes)
            cache[key] = self._msg_cache.get(key) or entity_to_msg(e, include_meshes)
        self._msg_cache = cache
        msg.entities = list(cache.values())
        ids = {e.id for e in ents}
        msg.removed_ids = sorted(i for i in self._published_revision if i not in ids)
        self._published_revision = {e.id: e.revision for e in ents}
        return msg, ents

    def _publish(self) -> None:
        if not self._changed:
            return
        self._changed = False
        try:
            msg, ents = self._entities_msg(self.include_meshes)
        except (RuntimeError, ValueError) as exc:  # never let one bad extraction take the node down
            self.get_logger().error(f"entity extraction failed: {exc}", throttle_duration_sec=5.0)
            return
        self.pub_entities.publish(msg)
        self.pub_markers.publish(map_markers(ents, self.map_frame, msg.header.stamp))

    def _report(self) -> None:
        self.get_logger().info(f"frames integrated {self.counters['integrated']}, keyframes {self.mapper.keyframes}, "
                               f"counters {dict(self.counters)}")

    # ------------------------------------------------------------------ services
    def _srv_save(self, req: SaveMap.Request, res: SaveMap.Response) -> SaveMap.Response:
        from recon_core.entity import save_entities

        try:
            self.mapper.save(req.path)
            save_entities(self.mapper.entities(), req.path, self.map_frame)
            res.success, res.message = True, f"map saved to {req.path}"
        except OSError as exc:
            res.success, res.message = False, f"cannot save to {req.path!r}: {exc}"
        return res

    def _srv_load(self, req: LoadMap.Request, res: LoadMap.Response) -> LoadMap.Response:
        try:
            self.mapper = PanopticMapper.load(req.path)
            self._changed = True
            res.success, res.message = True, f"map loaded from {req.path}"
        except (OSError, ValueError, ConfigError) as exc:
            res.success, res.message = False, f"cannot load {req.path!r}: {exc} (the current map is kept)"
        return res

    def _srv_reset(self, _req: ResetMap.Request, res: ResetMap.Response) -> ResetMap.Response:
        self.mapper = PanopticMapper(self.config, class_metas(self.class_table))
        self.pending.clear()
        self.queue.clear()
        self._changed = True
        res.success, res.message = True, "map reset"
        return res

    def _srv_extract(self, req: ExtractEntities.Request, res: ExtractEntities.Response) -> ExtractEntities.Response:
        try:
            res.entities, _ = self._entities_msg(req.include_meshes)
            res.success, res.message = True, f"{len(res.entities.entities)} entities"
        except (RuntimeError, ValueError) as exc:
            res.success, res.message = False, f"entity extraction failed: {exc}"
        return res


def main(args: list[str] | None = None) -> int:
    return run_node(MapperNode, args, threads=3)


if __name__ == "__main__":
    sys.exit(main())
