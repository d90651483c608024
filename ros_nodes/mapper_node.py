"""`panoptic_mapper`: the volumetric panoptic mapper as a ROS 2 node (thin adapter over PanopticMapper).

Inputs: color + depth images and camera info (approximately synchronised here), camera pose from
TF (`map_frame` <- image frame). Keyframes are sent to the segmentation service asynchronously:
a slow or dead service never blocks integration — other frames keep integrating geometry, and a
keyframe whose answer does not come within `segmentation_timeout_s` integrates without labels.
Outputs: `panoptic_entities` (PanopticEntityArray, transient-local: a consumer started or restarted
later gets the current entities at once) and `panoptic_map_markers` (MarkerArray) at
`publish_period_s` when the map changed; `mapper_status` (std_msgs/String, JSON, transient-local,
every `status_period_s`): frames integrated, frames dropped (backlog) and every other counter,
queue length, keyframes waiting for labels, whether changes await publication, checkpoints;
`/diagnostics` (diagnostic_msgs/DiagnosticArray, every second, `ros_nodes.diagnostics`): the same
counters with the input rate, latencies and a level (ERROR: the last frame failed; WARN: frames
dropped or skipped, keyframes mapped without labels, or the segmentation service missing).
Services save_map / load_map / reset_map / extract_entities.

Under load: the services run on a callback group of their own and take the map's lock between two
frames (the integration loop steps aside while a service waits), so they answer within about one
frame's integration time while frames keep arriving. Frames the mapper cannot keep up with are
dropped oldest first (`max_queue`), counted (`dropped_backlog`) and warned about.

Files: every path a request names (save_map, load_map) is confined to `data_root`
(`recon_core.paths.confined_path`: relative paths are taken in it, `..`, NUL bytes, empty paths and
anything resolving outside it are refused with a failure response). A damaged map given to load_map
is refused the same way and the current map is kept.

Checkpoints (`checkpoint.*` of the mapper config): every `checkpoint.every_n_frames` frames and/or
`checkpoint.every_s` seconds, and on shutdown (SIGINT/SIGTERM), into `<data_root>/checkpoints`
(generations written atomically, `panoptic_mapping.checkpoint`); the state is copied under the lock
and written by a background thread. `resume:=true` starts from the newest good checkpoint.

Gravity: the depth of the first frames (`gravity_window_frames` x `gravity_stride`, gravity.* of
config/data.yaml) tells where up is in the TF `map_frame`. With `gravity_align` (the default) the
frames of that window wait for the verdict; when the map frame's +z is more than
gravity.min_correction_deg from up (a visual SLAM's frame is often its first camera's), the map is
built in a gravity-aligned frame `aligned_frame` instead, published on /tf_static as a child of
`map_frame`, and every output (entities, markers, saved maps) is in it; otherwise nothing changes.
The window's frames are mapped in `map_frame` while the check reads them (`gravity_map_while_checking`,
the default; nothing is published before the verdict), and kept: a verdict that the frame is not z up
restarts the map in the aligned frame from them (`gravity_restarts`), so only such a frame pays for the
check, where waiting for the verdict held every frame of every stream (30-45 frames of a 30 Hz camera).
A stream that pauses before the window is full decides on the frames read (after `tf_wait_s` x 4 of
silence). `gravity_align:=false` only checks and warns (the frame is trusted).

Parameters: `config_file` (the mapper YAML, empty: config/mapper.yaml), every key of that file under
its dotted name (`mode`, `tsdf.voxel_size_m`, `keyframes.enabled`, ...; see `ros_nodes.parameters`),
and the node's own settings, `MapperNodeConfig` (topics, frames, timeouts, publishing).
"""

from __future__ import annotations

import collections
import contextlib
import hashlib
import itertools
import json
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from rclpy.time import Time
from scene_recon_interfaces.msg import ContactGraph, PanopticEntityArray
from scene_recon_interfaces.srv import ExtractEntities, LoadMap, ResetMap, SaveMap, SegmentImage
from sensor_msgs.msg import CameraInfo, Image, Imu
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

from panoptic_mapping.checkpoint import CHECKPOINT_DIR, Checkpointer, CheckpointStore
from panoptic_mapping.config import MapperConfig
from panoptic_mapping.dataio import DataInputConfig
from panoptic_mapping.dataio.transforms import TransformLookupError
from panoptic_mapping.fusion import BACKGROUND, PanopticMasks
from panoptic_mapping.gravity import (
    AccelerometerCheck,
    GravityEstimate,
    GravityMonitor,
    alignment_from_estimate,
    rotation_angle_deg,
    up_of_alignment,
)
from panoptic_mapping.mapper import MapSnapshot, PanopticMapper
from panoptic_mapping.pipeline import ahead_segments, class_metas, segment_ahead, segmentation_worker
from recon_core.classes import load_class_table
from recon_core.config import CONFIG_DIR, Settings, load_config, setting
from recon_core.errors import CheckpointError, SceneReconError
from recon_core.frame import DatasetError, RGBDFrame
from recon_core.paths import confined_path
from ros_nodes import diagnostics as diag
from ros_nodes.conversions import (
    camera_info_to_intrinsics,
    image_to_depth,
    image_to_labels,
    image_to_rgb,
    make_transform_stamped,
    stamp_to_ns,
)
from ros_nodes.entity_conversions import DEFAULT_MAP_ROOT, entity_to_msg, map_markers
from ros_nodes.image_pairing import ImagePairer
from ros_nodes.parameters import declare_config, declare_config_file
from ros_nodes.qos import ENTITIES, LATCHED, PROGRESS_TOPIC, RECORDING_DEPTH, STATUS, TF_STATIC
from ros_nodes.runner import run_node, steady_timer
from ros_nodes.sensor_subscription import SensorSubscription
from ros_nodes.tf_listener import TFListener


@dataclass
class _Pending:
    frame: RGBDFrame
    color_msg: Image
    depth_msg: Image
    future: object
    sent: float
    #: its depth segmentation, started on the worker process while the labels are computed (issue 26)
    segments: tuple | None = None


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
    #: Keyframes integrate when their labels arrive; meanwhile later frames integrate (a slow service never
    #: holds the camera up). With `in_order`, later frames wait for the keyframe instead (at most
    #: `segmentation_timeout_s`): frames integrate in recorded order, as `scene-recon map` integrates
    #: them, so a played bag gives the offline map. For recordings; live cameras keep the default.
    in_order: bool = setting(False, doc="integrate frames strictly in order (a keyframe holds later frames "
                             "until its labels arrive or time out)")
    #: Started together (a launch file, the runner), the service may be discovered a moment after the
    #: first frames: until it has been seen once, a keyframe waits this long for it instead of being
    #: mapped without labels. After that, a missing service never holds integration up.
    segmentation_startup_wait_s: float = setting(
        5.0, min=0.0, doc="until the service was first seen, a keyframe waits this long (s) for it")
    #: The node's own work (integration, publishing) runs on a thread of its own (`_mapping_loop`); the executor
    #: only hands over messages, service requests and timers. rclpy's multi-threaded executor rebuilds its wait
    #: set in Python for each callback: in a 30 Hz bag run its spinning thread alone used about as much CPU as
    #: the mapping loop (4.9 s against 4.8 s), in the same process and under the same interpreter lock. The
    #: events executor (rclpy.experimental, C++) does that work without the lock: 226-229 of 300 frames
    #: integrated against 184-207 with the multi-threaded one, same code otherwise, interleaved runs on a loaded
    #: machine (docs/ROS.md).
    executor: str = setting("events", choices=("events", "multi_threaded"),
                            doc="the node's executor: events (rclpy.experimental.EventsExecutor, one thread) or "
                            "multi_threaded (rclpy's MultiThreadedExecutor, 5 threads)")
    tf_wait_s: float = setting(0.5, min=0.0, doc="how long (s) a frame waits for its pose and camera info")
    tf_reliable: bool = setting(False, doc="subscribe /tf reliable (a played recording: no pose is lost while "
                                "discovery completes; matches reliable TF publishers only)")
    #: Reliable TF is complete but not always prompt: beside 1.5 MB image pairs, a TF sample lost on the
    #: way is resent at the writer's next heartbeat (Fast DDS: every 3 s), and measured on 200 played
    #: 640x480 frames, 9-17 frames gave up waiting after 0.5 s with their pose 1-3 s behind (none at 4 s).
    #: Our nodes' writers (the player's TF) send heartbeats every 0.1 s (`ros_nodes.dds_profile`); 4 s stays for
    #: another tool's writer (`ros2 bag play` without that profile).
    tf_wait_reliable_s: float = setting(4.0, min=0.0, doc="with tf_reliable: how long (s) a frame waits for its "
                                        "pose and camera info (a lost sample is resent at the next heartbeat)")
    publish_period_s: float = setting(2.0, min=0.0, min_exclusive=True,
                                      doc="entities and markers are published at most this often (s)")
    #: The duty above counts the mapper's own cost only; each publication also has the contact graph and the CAD
    #: replacer rebuild (and once more from scratch a second later) on the same cores: a 30 Hz bag on 2 cores, one
    #: publication 7 s in had the contact graph build for 0.5 s and the CAD replacer re-match for 3.3 s while
    #: the mapper was 120 frames behind. So while behind, the consumers get the map when the mapper has caught
    #: up, or after this long behind (a camera the mapper never catches up with).
    publish_behind_period_s: float = setting(20.0, min=0.0, doc="while 10 or more frames wait to be integrated, "
                                             "publish at most this often (s), counted from falling behind")
    publish_meshes: bool = setting(True, doc="entity messages carry their meshes")
    max_queue: int = setting(30, min=1, doc="frames waiting to be integrated; older ones are dropped")
    class_table: str = setting("", doc="class table YAML (default config/classes.yaml); the segmentation "
                               "service's onnx.class_table must be the same")
    data_root: str = setting(DEFAULT_MAP_ROOT, doc="folder the paths of save_map / load_map are confined "
                             "to (relative paths are taken in it); checkpoints go to <data_root>/checkpoints")
    resume: bool = setting(False, doc="start from the newest good checkpoint in <data_root>/checkpoints")
    status_period_s: float = setting(10.0, min=0.0, min_exclusive=True,
                                     doc="period (s) of the status log line and the mapper_status topic")
    gravity_check: bool = setting(True, doc="estimate up from the depth of the first frames (gravity.* of "
                                  "config/data.yaml) and warn when the TF map frame's +z is not up")
    gravity_align: bool = setting(True, doc="with gravity_check: the first frames wait for its verdict, and a "
                                  "map frame whose +z is not up (past gravity.min_correction_deg) is mapped in "
                                  "the gravity-aligned frame aligned_frame (child of map_frame on /tf_static); "
                                  "false: the map frame is trusted, only checked")
    aligned_frame: str = setting("", doc="name of the gravity-aligned frame (empty: <map_frame>_gravity)")
    #: Waiting for the verdict held the window's frames (window x stride, plus their reading: 1.0-1.5 s of a
    #: 30 Hz bag on 2 cores, 30-45 frames the mapper then had to catch up on) for every stream, while a ROS map
    #: frame is z up as a rule (REP 103) and the verdict then changes nothing.
    gravity_map_while_checking: bool = setting(True, doc="with gravity_align: the window's frames are mapped in "
                                               "the TF map frame while the check reads them and kept until its "
                                               "verdict; a frame whose +z is not up restarts the map in the aligned "
                                               "frame from them. false: they wait for the verdict")
    gravity_window_frames: int = setting(10, min=0, doc="frames the gravity check reads (0: gravity.window_frames "
                                         "of config/data.yaml)")
    gravity_stride: int = setting(3, min=0, doc="every n-th frame goes to the gravity check (0: gravity.stride); "
                                  "with gravity_align, window x stride frames (1 s at 30 Hz) wait for it")
    gravity_pause_s: float = setting(0.0, min=0.0, doc="a gravity window whose stream pauses this long (s) decides "
                                     "on the frames it has (0: 4 x tf_wait_s, at least 1 s); a service asking "
                                     "for the map (extract_entities, save_map) decides it at once")
    imu_topic: str = setting("", doc="sensor_msgs/Imu topic whose accelerometer checks the map frame's up (TF "
                             "rotates each reading into the map frame; the verdict goes to the map's gravity "
                             "record as `imu`); empty: no IMU")
    imu_samples: int = setting(0, min=0, doc="readings the IMU check averages (0: gravity.imu_samples)")
    #: "Settled" needs the consumers too: on a loaded machine the contact graph took 4-5 s to turn the
    #: mapper's last entities into a graph, and a runner that saw the mapper idle (everything published) and
    #: the scene quiet for 3 s exported the scene of the graph before (2 walls of 4 missing, 2 runs of 2).
    graph_topic: str = setting("contact_graph", doc="ContactGraph built from these entities (its header carries "
                               "their stamp): while it has a publisher, mapper_status reports graph_behind (and "
                               "unpublished_changes) until a graph of the newest entities came; empty: not watched")


class MapperNode(Node):
    def __init__(self) -> None:
        super().__init__("panoptic_mapper")
        self.config = declare_config(self, MapperConfig, declare_config_file(self, CONFIG_DIR / "mapper.yaml"))
        self.settings = settings = declare_config(self, MapperNodeConfig)
        self.map_frame = settings.map_frame
        self.sync_slop_ns = int(settings.sync_slop_s * 1e9)
        self.use_segmentation = settings.use_segmentation
        self.seg_timeout_s = settings.segmentation_timeout_s
        self.seg_startup_wait_s = settings.segmentation_startup_wait_s
        self.in_order = settings.in_order
        self.executor_kind = settings.executor  # read by ros_nodes.runner
        self._seg_seen = False
        self.tf_wait_s = max(settings.tf_wait_s, settings.tf_wait_reliable_s) if settings.tf_reliable \
            else settings.tf_wait_s
        self.hold_idle_s = settings.gravity_pause_s or self.HOLD_IDLE_FACTOR * max(settings.tf_wait_s, 0.25)
        self.publish_period_s = settings.publish_period_s
        self.publish_behind_period_s = settings.publish_behind_period_s
        self.include_meshes = settings.publish_meshes
        self.max_queue = settings.max_queue
        self.class_table = load_class_table(settings.class_table) if settings.class_table else None
        self.data_root = Path(settings.data_root).expanduser().resolve()
        self.mapper = PanopticMapper(self.config, class_metas(self.class_table))
        if self.use_segmentation:
            self._start_worker()
        self.gravity_config = gcfg = load_config(DataInputConfig, CONFIG_DIR / "data.yaml").gravity
        gcfg.window_frames = settings.gravity_window_frames or gcfg.window_frames
        gcfg.stride = settings.gravity_stride or gcfg.stride
        # cheaper than the CLI's (it runs inside the integration loop): a quarter of the pixels
        gcfg.downsample, gcfg.samples_per_frame = max(gcfg.downsample, 4), min(gcfg.samples_per_frame, 1500)
        self.gravity_monitor = GravityMonitor(self.gravity_config) if settings.gravity_check else None
        self.gravity_align = settings.gravity_check and settings.gravity_align
        self.aligned_frame = settings.aligned_frame or f"{settings.map_frame}_gravity"
        # frames of the gravity window waiting for its verdict, then released one per step, in order
        self._held: list[tuple[RGBDFrame, Image, Image]] = []
        self._held_since = 0.0
        self._released: collections.deque[tuple[RGBDFrame, Image, Image]] = collections.deque()
        # ... or, mapping while the check reads (`gravity_map_while_checking`), the window's frames as mapped, kept
        # until its verdict (None: no window open)
        self._window: list[tuple[RGBDFrame, Image, Image]] | None = \
            [] if self.gravity_align and self.gravity_monitor is not None and settings.gravity_map_while_checking \
            else None
        self._window_since = 0.0
        gcfg.imu_samples = settings.imu_samples or gcfg.imu_samples
        self.imu_check = AccelerometerCheck(gcfg) if settings.imu_topic else None
        # the map is guarded by `lock`; a service waiting for it makes the integration loop step
        # aside (`_services_waiting`), so a service answers within one frame's integration time
        self.lock = threading.Lock()
        self._services_waiting = 0
        self._waiting_lock = threading.Lock()
        self.last_service_wait_s = 0.0
        self.checkpointer: Checkpointer | None = None
        self.checkpoint_frames = 0
        self._checkpoint_thread: threading.Thread | None = None
        if self.config.checkpoint.enabled:
            store = CheckpointStore(self.data_root / CHECKPOINT_DIR, keep=self.config.checkpoint.keep)
            self.checkpointer = Checkpointer(store, self.config.checkpoint)
            if settings.resume:
                self._resume(store)
        # integration runs on its own thread (`_mapping_loop`), so TF and images keep arriving meanwhile. With
        # the multi-threaded executor (`executor`), inputs run on callback groups of their own; TF has a group to
        # itself: sharing one with the image stream starved it (frames then all lacked poses); services have
        # their own group. The events executor runs every callback on its one thread, in order of arrival.
        inputs = MutuallyExclusiveCallbackGroup()
        services = MutuallyExclusiveCallbackGroup()
        self.tf = TFListener(self, callback_group=MutuallyExclusiveCallbackGroup(), reliable=settings.tf_reliable)
        # camera topics: RELIABLE or BEST_EFFORT, whatever the driver offers (ros_nodes.sensor_subscription)
        # with a deep history, so a frame the mapper is slow to take is not overwritten. A live camera too: the
        # history only holds what the input callbacks have not taken yet, and they wait while an Open3D call of
        # the integration thread holds the interpreter lock; with the sensor profiles' 5 (170 ms at 30 Hz), a
        # 30 Hz bag on 2 loaded cores lost 30-60 of 300 colour and depth images, each independently, each loss
        # a frame. What is dropped when the mapper is behind is the node's own queue's choice (max_queue,
        # oldest first, counted), whole frames.
        depth = RECORDING_DEPTH
        self.sensor_subs = [SensorSubscription(self, Image, settings.color_topic, self._on_color, inputs, depth=depth),
                            SensorSubscription(self, Image, settings.depth_topic, self._on_depth, inputs, depth=depth),
                            SensorSubscription(self, CameraInfo, settings.camera_info_topic, self._on_info, inputs,
                                               depth=depth)]
        if settings.imu_topic:  # its own group: 100-400 Hz of tiny messages never wait for a frame
            self.imu_sub = SensorSubscription(self, Imu, settings.imu_topic, self._on_imu,
                                              MutuallyExclusiveCallbackGroup())
        self.seg_client = self.create_client(SegmentImage, settings.segmentation_service)
        self.pub_entities = self.create_publisher(PanopticEntityArray, "panoptic_entities", ENTITIES)
        self.pub_markers = self.create_publisher(MarkerArray, "panoptic_map_markers", 1)
        self.pub_status = self.create_publisher(String, "mapper_status", STATUS)
        self.pub_tf_static = self.create_publisher(TFMessage, "/tf_static", TF_STATIC)
        self.create_service(SaveMap, "save_map", self._srv_save, callback_group=services)
        self.create_service(LoadMap, "load_map", self._srv_load, callback_group=services)
        self.create_service(ResetMap, "reset_map", self._srv_reset, callback_group=services)
        self.create_service(ExtractEntities, "extract_entities", self._srv_extract, callback_group=services)
        # the two camera topics paired by stamp; an image waits until its partner comes or can no longer come
        # (both input callbacks share one group: the pairing is never entered twice at once)
        self.pairer: ImagePairer[Image] = ImagePairer(self.sync_slop_ns)
        self._head: Image | None = None  # the frame at the head of the queue, how long it waited there
        self._head_waited = 0.0
        self._head_tick = 0.0
        self.info: CameraInfo | None = None
        self.queue: collections.deque[tuple[Image, Image, float]] = collections.deque()
        self.pending: list[_Pending] = []
        #: A frame taken off the queue by the processing step and not yet integrated, held or pending (0 or 1).
        self._in_hand = 0
        self.counters = collections.Counter()
        self._drop_warned_at = -1e9
        #: depth segmentations started ahead for queued frames (`_segment_queued`): id of the depth message ->
        #: (that message, the intrinsics used, `segment_ahead`'s result)
        self._ahead: dict[int, tuple] = {}
        # for /diagnostics: the input rate, recent latencies, the newest error (the counts are `counters`)
        self.input_rate = diag.RateWindow()
        self.integrate_ms = diag.LatencyWindow()
        self.segmentation_ms = diag.LatencyWindow()
        self.last_error = ""
        self._last_step_failed = False
        self._publish_failed = False
        self._camera_frame = ""
        self._recent = diag.RecentIncrease()
        self._changed = self.mapper.frames_integrated > 0  # a resumed map is published at once
        #: start and cost (monotonic s) of the last publication: the next waits for cost / duty after the start
        self._last_publish = (0.0, 0.0)
        self._published_revision: dict[int, tuple[str, int]] = {}  # id -> (mesh digest, revision published)
        # entity messages by (id, revision, with mesh): unchanged entities are not converted again
        self._msg_cache: dict[tuple[int, int, bool], object] = {}
        # the stamp of the newest entities published (strictly increasing: on sim time the clock stands still
        # once a recording has ended) and of the entities the newest contact graph was built from
        self._published_stamp_ns = 0
        self._graph_stamp_ns = -1
        self.graph_topic = settings.graph_topic
        if self.graph_topic:
            self.create_subscription(ContactGraph, self.graph_topic, self._on_graph, LATCHED,
                                     callback_group=MutuallyExclusiveCallbackGroup())
        # integration and publishing run on a thread of their own (`_mapping_loop`), not on executor timers
        self._loop_stop = threading.Event()
        self._wake = threading.Event()  # a frame, a segmentation answer or a service leaving wakes the loop
        self._loop_thread: threading.Thread | None = None
        steady_timer(self, settings.status_period_s, self._report, inputs)
        # back-pressure for a played recording (rgbd_player's pace_topic): which frames are still to be done
        self.pub_progress = self.create_publisher(String, PROGRESS_TOPIC, STATUS)
        self._progress_sent: tuple = ()
        self._progress_at = 0.0
        steady_timer(self, self.PROGRESS_PERIOD_S, self._publish_progress, MutuallyExclusiveCallbackGroup())
        self.diagnostics = diag.NodeDiagnostics(self, "panoptic mapping", self.health, callback_group=inputs)
        self._publish_alignment()  # a resumed map keeps its frame
        self._loop_thread = threading.Thread(target=self._mapping_loop, name="mapping-loop", daemon=True)
        self._loop_thread.start()
        self.get_logger().info(f"data root {self.data_root}; checkpoints "
                               + (f"every {self.config.checkpoint.every_n_frames} frames / "
                                  f"{self.config.checkpoint.every_s:g} s" if self.checkpointer else "disabled"))

    def _start_worker(self) -> None:
        """Start the depth segmentation worker process (`segment_ahead`) now rather than on the first keyframe:
        its start then overlaps the wait for the camera instead of holding the first keyframe's integration while
        frames pile up (a 30 Hz bag on 2 cores: the first frames integrated 2-4 s after the first frame came).
        Never fatal: a worker that cannot start leaves the segmentation on this node's thread."""
        segmentation_worker().start()

    def _resume(self, store: CheckpointStore) -> None:
        if not store.generations():
            self.get_logger().warning(f"resume: no checkpoint in {store.folder}; starting an empty map")
            return
        try:
            ckpt = store.load_latest()  # damaged generations are logged and skipped
        except CheckpointError as exc:
            self.get_logger().error(f"resume: {exc}; starting an empty map")
            return
        for why in ckpt.skipped:
            self.get_logger().warning(f"resume: {why}; using the older checkpoint {ckpt.path}")
        self.mapper = ckpt.mapper
        self.checkpoint_frames = self.mapper.frames_integrated
        self.gravity_monitor = None  # the resumed map keeps its record
        self._window = None
        assert self.checkpointer is not None
        self.checkpointer.start(self.mapper.frames_integrated)
        self.get_logger().info(f"resumed from checkpoint {ckpt.path} ({self.mapper.frames_integrated} frames)")

    # ------------------------------------------------------------------ map lock
    @contextlib.contextmanager
    def _service_turn(self) -> Iterator[None]:
        """The map's lock, for a service: the integration loop steps aside while one waits.

        The time waited is kept in `last_service_wait_s` (and reported by the services' messages)."""
        t0 = time.perf_counter()
        with self._waiting_lock:
            self._services_waiting += 1
        try:
            with self.lock:
                self.last_service_wait_s = time.perf_counter() - t0
                yield
        finally:
            with self._waiting_lock:
                self._services_waiting -= 1
            self._wake.set()

    def _timing(self, t0: float) -> str:
        return (f"({1000 * self.last_service_wait_s:.0f} ms waiting for the map, "
                f"{1000 * (time.perf_counter() - t0):.0f} ms in all)")

    # ------------------------------------------------------------------ inputs
    def _on_info(self, msg: CameraInfo) -> None:
        self.info = msg

    def _on_color(self, msg: Image) -> None:
        for color, depth in self.pairer.add_color(stamp_to_ns(msg.header.stamp), msg):
            self._enqueue(color, depth)
        self._count_unpaired()

    def _on_depth(self, msg: Image) -> None:
        for color, depth in self.pairer.add_depth(stamp_to_ns(msg.header.stamp), msg):
            self._enqueue(color, depth)
        self._count_unpaired()

    def _count_unpaired(self) -> None:
        """The pairing's counts of images whose partner can no longer come (`ros_nodes.image_pairing`)."""
        n = self.pairer.counts
        for key, value in (("unpaired_depth", n.unpaired_depth), ("unpaired_color", n.unpaired_color),
                           ("unpaired_expired", n.expired)):
            if value:
                self.counters[key] = value

    def _enqueue(self, color: Image, depth: Image) -> None:
        self.queue.append((color, depth, time.monotonic()))
        self._wake.set()
        stamp = stamp_to_ns(depth.header.stamp)
        self._newest_received = stamp if self._newest_received is None else max(self._newest_received, stamp)
        self.counters["received"] += 1
        self.input_rate.tick()
        self._camera_frame = color.header.frame_id
        while len(self.queue) > self.max_queue:  # cannot keep up: drop the oldest, keep the newest
            self.queue.popleft()
            self.counters["dropped_backlog"] += 1
            # throttled here: rclpy's own throttle inspects the caller's source on every call (ms per
            # dropped frame, taken from the frames that are still mapped)
            if time.monotonic() - self._drop_warned_at >= 5.0:
                self._drop_warned_at = time.monotonic()
                self.get_logger().warning(
                    f"mapper cannot keep up: oldest queued frame dropped ({self.counters['dropped_backlog']} "
                    f"dropped so far, {self.counters['integrated']} integrated; queue {self.max_queue})")

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
            self._failed(f"frame at {stamp * 1e-9:.3f} s skipped: {exc}")
            return None

    # ------------------------------------------------------------------ processing
    #: The loop's longest sleep while nothing can be done (s): the period the frame at the head of the queue
    #: is looked at while it waits for its pose or camera info (a new frame or a segmentation answer wakes it).
    LOOP_IDLE_S = 0.01

    def _mapping_loop(self) -> None:
        """Integration (`_process`) and publishing, one step after another, until the node stops.

        A thread, not a 10 ms executor timer: the executor only hands over messages, service requests and
        timers, so the events executor's single thread (`executor`) is never held by an integration, and no
        step waits for the executor to hand it a timer (with the multi-threaded executor too: 184 / 207 of a
        30 Hz bag's 300 frames integrated against 171 / 192 from the timer, two interleaved runs on a loaded
        machine, docs/ROS.md). The loop runs a step as soon as the previous one ends and sleeps only when a
        step changed nothing.
        Publishing stays on this thread, as it shared the integration's callback group before: beside
        integration, its mesh-to-message conversion competed with integration and the services for the
        interpreter (service answers under load went from < 1 s to 2-6 s, test_node_faults); its duty cycle is
        capped (PUBLISH_DUTY)."""
        next_publish = time.monotonic() + self.publish_period_s
        while not self._loop_stop.is_set():
            self._wake.clear()
            before = self._loop_state()
            try:
                self._process()
                if time.monotonic() >= next_publish:
                    next_publish = time.monotonic() + self.publish_period_s
                    self._publish()
            except Exception as exc:  # one failing step never ends the loop (the node would map nothing more)
                self.counters["loop_errors"] += 1
                self.last_error = f"mapping loop: {type(exc).__name__}: {exc}"
                self.get_logger().error(self.last_error, throttle_duration_sec=5.0)
                self._loop_stop.wait(self.LOOP_IDLE_S)
                continue
            if self._loop_state() == before:
                self._wake.wait(self.LOOP_IDLE_S)

    def _loop_state(self) -> tuple:
        """What a loop step that did something changes."""
        return len(self.queue), len(self._released), len(self.pending), len(self._held), self.mapper.frames_integrated

    def _stop_loop(self) -> None:
        """Stop the mapping loop after its current step."""
        self._loop_stop.set()
        self._wake.set()
        thread = self._loop_thread
        if thread is not None and thread.is_alive() and thread is not threading.current_thread():
            thread.join(timeout=120)

    def destroy_node(self) -> None:
        self._stop_loop()
        super().destroy_node()

    def _process(self) -> None:
        if self._services_waiting:
            return  # a service waits for the map: let it have it first
        with self.lock:
            self._process_locked()
        self._maybe_checkpoint()

    def _process_locked(self) -> None:
        # `status()` reads the queue, the pending labels and the map from another thread without the map's lock:
        # the frame this step takes off the queue counts as queued until the step is over, or a status read
        # in between saw nothing left to do (a keyframe counted, not yet pending: a settled run that was not)
        self._in_hand = 1 if (self.queue or self._released) else 0
        try:
            self._process_step()
        finally:
            self._in_hand = 0

    def _process_step(self) -> None:
        self._collect_segmentations()
        if self.in_order and self.pending:
            return
        if self._released:  # the gravity window's frames, in order, before any newer one
            held, held_color, held_depth = self._released.popleft()
            held.index = self.mapper.frames_integrated
            self._route(held, held_color, held_depth)
            return
        if self._held and not self.queue and time.monotonic() - self._held_since > self.hold_idle_s:
            self._decide_alignment("the stream paused before the window was full")
            return
        if self._window and not self.queue and time.monotonic() - self._window_since > self.hold_idle_s:
            self._close_window("the stream paused before the window was full")
            return
        if not self.queue:
            return
        color_msg, depth_msg, _arrived = self.queue[0]
        # waiting is measured from when the frame reached the head of the queue, not from its stamp
        # (replayed recordings carry old stamps) nor its arrival (behind a backlog every queued frame had
        # waited longer than tf_wait_s already, and a camera info that came a moment late dropped them all:
        # 13 of 60 frames of a played bag)
        # ... and only in the loop's own short steps: Open3D holds the interpreter lock through a long call
        # (an integration, an extraction for publishing), during which the TF thread cannot take the
        # pose that may be waiting for it; counted in wall time, such a stall spent the whole wait and
        # frames were skipped with their pose already delivered (9-29 of 200 real frames)
        now = time.monotonic()
        if self._head is not depth_msg:
            self._head, self._head_waited = depth_msg, 0.0
        else:
            self._head_waited += min(now - self._head_tick, self.WAIT_STEP_S)
        self._head_tick = now
        waited = self._head_waited
        if self.info is None:
            if waited < self.tf_wait_s:
                return
            self.queue.popleft()
            self.counters["no_camera_info"] += 1
            self.get_logger().warning("frame skipped: no camera info received yet", throttle_duration_sec=5.0)
            return
        if (self.use_segmentation and not self._seg_seen and waited < self.seg_startup_wait_s
                and not self.seg_client.service_is_ready()):
            return  # the service is starting beside us: keep the frame at the head of the queue
        # TF travels on a topic of its own (and is taken by another executor thread): the image may be here
        # before the pose of its instant. Looked up then, the pose would be the previous sample held forward
        # (extrapolation up to 50 ms: a frame period), and a played bag's map would depend on which of the
        # two callbacks ran first. Like tf2's message filter, the frame waits (at most tf_wait_s) for TF
        # to reach its stamp; only then is a short extrapolation accepted (counted: tf_extrapolated, as is a
        # frame just before the first TF sample, whose pose is that sample's).
        stamp = stamp_to_ns(depth_msg.header.stamp)
        span = self.tf.time_range(self.map_frame, color_msg.header.frame_id)
        if span is not None and stamp > span[1] and waited < self.tf_wait_s:
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
        if span is not None and not span[0] <= stamp <= span[1]:
            self.counters["tf_extrapolated"] += 1
            self.get_logger().warning(f"frame at {stamp * 1e-9:.3f} s: no TF around its stamp (TF from "
                                      f"{span[0] * 1e-9:.3f} to {span[1] * 1e-9:.3f} s after waiting up to "
                                      f"{self.tf_wait_s:g} s); its pose is extrapolated", throttle_duration_sec=5.0)
        if self._holding():
            self._held.append((frame, color_msg, depth_msg))
            self._held_since = time.monotonic()
            self._check_gravity(frame)  # the verdict releases the held frames
            return
        if self._window is not None:
            self._window.append((frame, color_msg, depth_msg))
            self._window_since = time.monotonic()
        if self._check_gravity(frame):
            return  # the map restarted in the gravity-aligned frame: this frame is mapped again with the window's
        self._route(frame, color_msg, depth_msg)

    #: The most one step of the processing loop adds to a frame's wait (s): see `_process_step`.
    WAIT_STEP_S = 0.05
    #: A gravity window whose stream pauses for this many tf_wait_s decides on the frames read.
    HOLD_IDLE_FACTOR = 4.0

    def _route(self, frame: RGBDFrame, color_msg: Image, depth_msg: Image) -> None:
        """A posed frame to the map: skipped when the camera stood still, sent for labels when it is a
        keyframe (integrated when they arrive), integrated at once otherwise."""
        entry = self._ahead.pop(id(depth_msg), None)  # its depth segmentation, if started while it was queued
        ahead = entry[2] if entry is not None and entry[0] is depth_msg and entry[1] == frame.intrinsics else None
        if self.mapper.is_static(frame):  # a still camera: the frame adds nothing (static.* of the config)
            self.counters["static_frames"] += 1
            return
        if self.mapper.is_keyframe(frame):
            if not self.use_segmentation:
                self.mapper.mark_keyframe(frame)
            elif self.seg_client.service_is_ready():
                self._seg_seen = True
                req = SegmentImage.Request(color=color_msg, has_depth=True, depth=depth_msg)
                future = self.seg_client.call_async(req)
                future.add_done_callback(lambda _f: self._wake.set())  # the answer wakes the mapping loop
                self.pending.append(_Pending(frame, color_msg, depth_msg, future,
                                             time.monotonic(), ahead or segment_ahead(self.mapper, frame)))
                # counted once it is pending (`_process_locked`): keyframes never run ahead of pending + segmented
                self.mapper.mark_keyframe(frame)
                self.counters["segmentation_calls"] += 1
                return
            else:  # not marked: the next frames stay keyframe candidates until the service is up
                self.counters["keyframes_unsegmented"] += 1
                self.get_logger().warning("segmentation service not available: mapping geometry only",
                                          throttle_duration_sec=10.0)
        # without segmentation no label is ever fused: the TSDF-only path (no depth segmentation)
        if self.use_segmentation:
            self._segment_queued()
        self._integrate(frame, None, geometry_only=not self.use_segmentation, segments=ahead)

    #: Queued frames whose depth segmentation may start on the worker process before their turn.
    SEGMENT_AHEAD = 3

    def _segment_queued(self) -> None:
        """Start the depth segmentation of the next queued frames that the label cadence will make label
        frames (`keyframes.label_every_n_frames`) on the worker process (issue 26): with a backlog, it runs
        on the second core while this thread maps the frames before. A guess that misses costs only the
        worker's time; the result is used only for that very message with the same intrinsics."""
        queued = list(itertools.islice(self.queue, self.SEGMENT_AHEAD))
        live = {id(d) for _c, d, _t in queued}
        self._ahead = {k: v for k, v in self._ahead.items() if k in live}
        if self.mapper.config.keyframes.label_every_n_frames <= 0 or self.info is None or not queued:
            return
        try:
            intr = camera_info_to_intrinsics(self.info)
        except DatasetError:
            return
        for i, (_color, depth_msg, _t) in enumerate(queued):
            if id(depth_msg) in self._ahead or not self.mapper.propagates_labels(i + 1):
                continue
            try:
                depth, _bad = image_to_depth(depth_msg)
                frame = RGBDFrame(np.broadcast_to(np.zeros(3, np.uint8), (*depth.shape[:2], 3)), depth, intr, None, 0)
            except DatasetError:
                continue
            self._ahead[id(depth_msg)] = (depth_msg, intr, segment_ahead(self.mapper, frame))

    def _snapshot(self) -> MapSnapshot:
        """A copy of the map to write (caller holds the map's turn); a gravity check still short of its
        window puts its provisional estimate into the record first, so an early save says it too."""
        if (self.gravity_monitor is not None and not self.gravity_monitor.done) or \
                (self.imu_check is not None and not self.imu_check.done):
            self.mapper.gravity = self._gravity_record()
        snapshot = self.mapper.snapshot()
        if self._held:  # a save that early: held frames go to the map right after (the window stays open)
            self.get_logger().warning(f"map written while {len(self._held)} frames wait for the gravity check")
        return snapshot

    def _flush_held(self, why: str) -> None:
        """A service asks for the map while the gravity window holds frames (a short or paused stream):
        the window decides on what it has and its frames go to the map now, in order (caller holds the
        map's lock). Keyframes wait for their labels as in the loop, at most the segmentation timeout."""
        if self._window is not None:
            self._close_window(why)
        if not self._held and not self._released:
            return
        n = len(self._held) + len(self._released)
        if self._held:
            self._decide_alignment(why)
        deadline = time.monotonic() + self.seg_timeout_s + 1.0
        while time.monotonic() < deadline:
            self._collect_segmentations()
            if self._released and not (self.in_order and self.pending):
                held, held_color, held_depth = self._released.popleft()
                held.index = self.mapper.frames_integrated
                self._route(held, held_color, held_depth)
            elif self.pending and not self._released and not self.in_order:
                break  # out of order: the labels integrate when they come
            elif self.pending:
                time.sleep(0.01)  # the labels arrive on another executor thread
            else:
                break
        self.get_logger().info(f"{why}: the gravity window's {n} frames went to the map "
                               f"({self.mapper.frames_integrated} frames integrated)")

    def _gravity_record(self) -> dict:
        """The map's gravity record: the depth check's (GravityMonitor), with the IMU check's as `imu`."""
        mon = self.gravity_monitor
        out = mon.record() if mon is not None else dict(self.mapper.gravity)
        if mon is not None and not np.array_equal(self.mapper.alignment, np.eye(4)):
            out.update(mode="auto", applied=True, rotation_deg=rotation_angle_deg(self.mapper.alignment),
                       input_up=up_of_alignment(self.mapper.alignment).tolist(), frame=self.aligned_frame,
                       parent_frame=self.map_frame, note=self._alignment_note)
        if self.imu_check is not None:
            out["imu"] = self.imu_check.record()
        return out

    def _on_imu(self, msg: Imu) -> None:
        """Accelerometer reading -> the map frame (TF at its stamp) -> the IMU gravity check."""
        check = self.imu_check
        if check is None or check.done:
            return
        try:
            pose = self.tf.lookup(self.map_frame, msg.header.frame_id, stamp_to_ns(msg.header.stamp))
        except TransformLookupError:
            self.counters["imu_without_tf"] += 1
            return
        a = msg.linear_acceleration
        result = check.add(pose[:3, :3] @ np.array([a.x, a.y, a.z], np.float64))
        if result is None:
            return
        self.mapper.gravity = record = self._gravity_record()
        note = record["imu"]["note"]
        if result.ok and result.angle_deg > check.cfg.warn_deg:
            self.get_logger().warning(note)
        else:
            self.get_logger().info(note)

    def _check_gravity(self, frame: RGBDFrame) -> bool:
        """Feed the gravity check (first frames only); its verdict goes to the map's gravity record. True when
        the verdict restarted the map (`_close_window`)."""
        mon = self.gravity_monitor
        if mon is None or mon.done:
            return False
        result = mon.feed(frame.depth, frame.intrinsics, frame.pose)
        if result is None:
            return False
        if self._held:
            self._decide_alignment()
            return False
        if self._window is not None:
            return self._close_window()
        self._report_gravity()
        return False

    def _close_window(self, early: str = "") -> bool:
        """The gravity verdict for a window mapped while the check read it (caller holds the map's lock). A TF
        map frame that is z up (past gravity.min_correction_deg) keeps the map as it is; otherwise the map
        restarts empty in the gravity-aligned frame and the window's frames, kept until now, go to it again
        first, in order, as the frames held for the verdict do (`_released`); labels asked for meanwhile are
        asked for again. Returns whether the map restarted."""
        window, self._window = self._window, None
        if window is None:
            return False
        mon = self.gravity_monitor
        result = None
        if mon is not None:
            result = mon.finish() if not mon.done else mon.result
        self.counters["mapped_before_gravity_verdict"] = self.mapper.frames_integrated
        if early:
            self.get_logger().info(f"{early}: the gravity window's {len(window)} frames decide the check "
                                   f"({self.mapper.frames_integrated} mapped in {self.map_frame!r} meanwhile)")
        if result is None or np.array_equal(alignment_from_estimate(result, self.gravity_config)[0], np.eye(4)):
            self._report_gravity()
            return False
        mapped = self.mapper.frames_integrated
        self._start_over(PanopticMapper(self.config, class_metas(self.class_table)))
        self.counters["integrated"] -= mapped
        self.counters["gravity_restarts"] += 1
        self._apply_alignment(result, early)
        self._report_gravity()
        self._released.extend(window)
        self.get_logger().info(f"the map restarted in {self.aligned_frame!r}: the {len(window)} frames read by the "
                               f"gravity check ({mapped} mapped in {self.map_frame!r}) go to it again")
        return True

    def _start_over(self, fresh: PanopticMapper) -> None:
        """Map into `fresh` (an empty map) from now on (caller holds the map's lock): labels asked for the old map
        are dropped (a frame still to be mapped asks again), it is published and checkpointed from frame 0."""
        self.mapper = fresh
        self.pending.clear()
        self._ahead.clear()
        self._changed = True
        if self.checkpointer is not None:
            self.checkpointer.start(0)

    def _report_gravity(self) -> None:
        mon = self.gravity_monitor
        self.mapper.gravity = self._gravity_record()
        if mon is not None and mon.warning and not self.mapper.gravity.get("applied"):
            self.get_logger().warning(mon.warning)
        else:
            self.get_logger().info(self.mapper.gravity.get("note", ""))

    def _holding(self) -> bool:
        """Whether frames wait for the gravity verdict: aligning, the check still reading, nothing mapped."""
        mon = self.gravity_monitor
        return (self.gravity_align and mon is not None and not mon.done and self.mapper.frames_integrated == 0
                and self._window is None)

    def _decide_alignment(self, early: str = "") -> None:
        """The gravity verdict for the held frames (caller holds the map's lock): a map frame whose +z is
        not up is replaced by the gravity-aligned frame (Sec. 3 of the paper assumes z up), announced on
        /tf_static; then the held frames are released to the map, in order."""
        mon = self.gravity_monitor
        result = None
        if mon is not None and not mon.done:
            result = mon.finish()
        elif mon is not None:
            result = mon.result
        if result is not None and self.gravity_align and self.mapper.frames_integrated == 0:
            self._apply_alignment(result, early)
        self._report_gravity()
        self._released.extend(self._held)
        self._held.clear()

    def _apply_alignment(self, result: GravityEstimate, early: str) -> None:
        transform, note = alignment_from_estimate(result, self.gravity_config)
        if np.array_equal(transform, np.eye(4)):
            return
        self.mapper.set_alignment(transform)
        self._publish_alignment()
        self.get_logger().warning(
            f"the TF frame {self.map_frame!r} is not gravity aligned: its +z is {result.angle_deg:.1f} deg from up "
            f"(estimated from the {result.method} over {result.frames} frames{'; ' + early if early else ''}); "
            f"the map is built in {self.aligned_frame!r} (static TF {self.map_frame} -> {self.aligned_frame}, "
            "z up) and every output is in that frame")
        self._alignment_note = note.replace("gravity auto", "gravity (mapper node)") + \
            f" into {self.aligned_frame!r}, a child of {self.map_frame!r}"

    _alignment_note = ""

    @property
    def output_frame(self) -> str:
        """The frame of the map and every output: the TF map frame, or its gravity-aligned child."""
        return self.map_frame if np.array_equal(self.mapper.alignment, np.eye(4)) else self.aligned_frame

    def _publish_alignment(self) -> None:
        """/tf_static map_frame -> aligned frame for a gravity-aligned map (map point = alignment @ input point)."""
        if np.array_equal(self.mapper.alignment, np.eye(4)):
            return
        pose = np.linalg.inv(self.mapper.alignment)  # the aligned frame's pose in the TF map frame
        if np.any(self.mapper.origin_offset):
            pose = pose @ _translation(self.mapper.origin_offset)
        self.pub_tf_static.publish(TFMessage(transforms=[make_transform_stamped(
            pose, self.map_frame, self.aligned_frame, self.get_clock().now().nanoseconds)]))

    def _collect_segmentations(self) -> None:
        still = []
        for item in self.pending:
            if item.future.done():
                masks = None
                try:
                    res = item.future.result()
                    if res is not None and res.success:
                        masks = self._masks(res)
                        self.counters["segmented_keyframes"] += 1
                    else:
                        self.counters["segmentation_failed"] += 1
                        self.get_logger().warning(f"segmentation failed: {getattr(res, 'message', '')}",
                                                  throttle_duration_sec=5.0)
                except Exception as exc:  # the service died mid-call: map geometry anyway
                    self.counters["segmentation_failed"] += 1
                    self.get_logger().warning(f"segmentation call failed: {exc}", throttle_duration_sec=5.0)
                self.segmentation_ms.add(1000 * (time.monotonic() - item.sent))
                self._integrate(item.frame, masks, segments=item.segments)
            elif time.monotonic() - item.sent > self.seg_timeout_s:
                self.counters["segmentation_timeout"] += 1
                self.get_logger().warning("segmentation service too slow: keyframe integrated without labels",
                                          throttle_duration_sec=5.0)
                self._integrate(item.frame, None, segments=item.segments)
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

    def _integrate(self, frame: RGBDFrame, masks: PanopticMasks | None, geometry_only: bool = False,
                   segments: tuple | None = None) -> None:
        """`segments`: the frame's depth segmentation started ahead (`segment_ahead`), if any."""
        t0 = time.perf_counter()
        try:
            if masks is not None and masks.labels.shape != frame.depth.shape:
                self.get_logger().error("segmentation labels do not match the image size; ignored")
                masks = None
            if geometry_only:
                self.mapper.integrate_geometry(frame)
            else:
                ahead = ahead_segments(segments, self.mapper, self.mapper.fuses_labels(masks))
                self.counters["segmented_ahead"] += ahead is not None  # on the worker process (issue 26)
                self.mapper.integrate(frame, masks, ahead)
            self.counters["integrated"] += 1
            self._changed = True
            self._last_step_failed = False
            self.integrate_ms.add(1000 * (time.perf_counter() - t0))
        except (ValueError, DatasetError) as exc:
            self.counters["integration_error"] += 1
            self._failed(f"frame not integrated: {exc}")

    def _failed(self, message: str) -> None:
        """The last processing step failed: logged, and /diagnostics says ERROR until a frame integrates."""
        self.last_error, self._last_step_failed = message, True
        self.get_logger().error(message, throttle_duration_sec=5.0)

    # ------------------------------------------------------------------ outputs
    def _entities_msg(self, ents: list, include_meshes: bool, publishing: bool, frames: int) -> PanopticEntityArray:
        """The message of extracted entities; runs outside the map's lock (the mesh conversion is slow).

        An entity's published revision changes whenever its mesh does: the mapper's own revision follows
        label updates only, while frames between keyframes grow the geometry too, and consumers (the
        contact graph, the CAD replacer) skip an entity whose revision they have seen. A changed entity
        gets `frames` (frames integrated at extraction) as its revision: that grows across a restart from
        a checkpoint too, so a restarted mapper never reuses a revision for another mesh.
        Only the publisher (one thread) updates the conversion cache and the published revisions."""
        msg = PanopticEntityArray()
        msg.header.frame_id = self.output_frame
        stamp_ns = self.get_clock().now().nanoseconds
        if publishing:
            stamp_ns = max(stamp_ns, self._published_stamp_ns + 1)
        msg.header.stamp = Time(nanoseconds=stamp_ns).to_msg()
        old, cache = self._msg_cache, {}
        revisions: dict[int, tuple[str, int]] = {}
        for e in ents:
            digest = _mesh_digest(e)
            prev = self._published_revision.get(int(e.id))
            if prev is not None and prev[0] == digest:
                revision = prev[1]
            else:
                revision = max(int(e.revision), int(frames), prev[1] + 1 if prev is not None else 0)
            revisions[int(e.id)] = (digest, revision)
            key = (int(e.id), revision, include_meshes)
            entry = old.get(key)
            if entry is None:
                entry = entity_to_msg(e, include_meshes)
                entry.revision = revision
            cache[key] = entry
        msg.entities = list(cache.values())
        msg.removed_ids = sorted(i for i in self._published_revision if i not in revisions)
        if publishing:
            self._msg_cache = cache
            self._published_revision = revisions
        return msg

    #: Publishing (extraction + mesh messages) takes at most this share of the time: a map that grows
    #: every frame changes every entity's mesh, and converting them all at each short period starved
    #: integration and the services.
    PUBLISH_DUTY = 0.3
    #: ... and this share while frames wait to be integrated (a camera faster than the mapper): every
    #: publication also makes the contact graph and the CAD replacer rebuild, on the same cores, so the
    #: consumers see a coarser sequence of maps while the mapper catches up, and the newest map as soon as
    #: it has (the queue empty, the normal duty again).
    PUBLISH_DUTY_BEHIND = 0.05
    #: Frames waiting (a third of a second of a 30 Hz camera) from which the mapper counts as behind.
    BEHIND_FRAMES = 10
    #: when the mapper fell behind (monotonic s; None: not behind), for `publish_behind_period_s`
    _behind_since: float | None = None

    def _publish(self) -> None:
        now = time.monotonic()
        behind = self._queued() >= self.BEHIND_FRAMES
        if not behind:
            self._behind_since = None
        elif self._behind_since is None:
            self._behind_since = now
        if not self._changed or self._services_waiting:
            return
        if self._window:  # the gravity check still reads: its verdict may restart the map in another frame
            return
        start, cost = self._last_publish
        if now < start + cost / (self.PUBLISH_DUTY_BEHIND if behind else self.PUBLISH_DUTY):
            return
        if behind and self._behind_since is not None and \
                now - max(start, self._behind_since) < self.publish_behind_period_s:
            return
        t0 = time.monotonic()
        # `_changed` is cleared when the map is read, the message goes out after the conversions: meanwhile the
        # status still says there are unpublished changes. Without this, a status sent in between reported an
        # idle mapper whose newest entities were not out yet, and `scene-recon ros-run`, seeing the graph quiet
        # (its last one from a publication 10 s before, a mapper behind publishes seldom), exported that
        # older scene (a loaded CI run: 2 of 7 objects).
        self._publishing = True
        try:
            try:
                with self.lock:  # only the extraction needs the map; the conversions run outside
                    self._changed = False
                    ents = self.mapper.entities(with_meshes=True)
                    frames = self.mapper.frames_integrated
                msg = self._entities_msg(ents, self.include_meshes, publishing=True, frames=frames)
            except (RuntimeError, ValueError) as exc:  # never let one bad extraction take the node down
                self.last_error, self._publish_failed = f"entity extraction failed: {exc}", True
                self.get_logger().error(self.last_error, throttle_duration_sec=5.0)
                return
            self._publish_failed = False
            self.pub_entities.publish(msg)
            self._published_stamp_ns = _stamp_ns(msg.header.stamp)
        finally:
            self._publishing = False
        self.counters["publications"] += 1
        # markers only for a listener (RViz): their per-vertex point objects cost as much as everything else
        # a publication does (half the node's publishing time in a 30 Hz bag run), and no node reads them
        if self.pub_markers.get_subscription_count() > 0:
            self.pub_markers.publish(map_markers(ents, self.output_frame, msg.header.stamp))
        self._last_publish = (t0, time.monotonic() - t0)

    def _on_graph(self, msg: ContactGraph) -> None:
        self._graph_stamp_ns = _stamp_ns(msg.header.stamp)

    def graph_behind(self) -> bool:
        """A contact graph runs (`graph_topic` has a publisher) and has not yet published the graph of the
        newest entities published here (the graph's header carries the stamp of the entities it was built from)."""
        return bool(self.graph_topic and self._published_stamp_ns and self._graph_stamp_ns != self._published_stamp_ns
                    and self.count_publishers(self.graph_topic) > 0)

    def status(self) -> dict:
        """What `mapper_status` and the status log line report."""
        cp = self.checkpointer
        behind = self.graph_behind()
        return {"frames_integrated": self.mapper.frames_integrated, "keyframes": self.mapper.keyframes,
                "dropped_frames": self.counters["dropped_backlog"], "queue": self._queued(),
                "held_for_gravity": len(self._held), "gravity_window": len(self._window or ()),
                "frame": self.output_frame,
                # idle = nothing queued, no keyframe waiting for labels, every change published and, where a
                # contact graph runs, in its newest graph
                "pending_segmentations": len(self.pending),
                "unpublished_changes": bool(self._changed) or self._publishing or behind,
                "graph_behind": behind,
                "entity_publications": self.counters["publications"],
                "counters": dict(self.counters), "checkpoints": cp.saved if cp else 0,
                "last_checkpoint": str(cp.last_path) if cp and cp.last_path else "",
                "last_checkpoint_s": round(cp.last_cost_s, 3) if cp else 0.0,
                # frames in the newest checkpoint written: what a restarted (resume:=true) mapper starts from
                "checkpoint_frames": self.checkpoint_frames,
                "gravity": self.mapper.gravity.get("note", ""),
                # whether keyframes can get labels now (tools start a bag once this says "ready")
                "segmentation_service": self.segmentation_state()}

    def segmentation_state(self) -> str:
        """The segmentation service as this node sees it: "ready", "missing" or "disabled" (geometry only)."""
        if not self.use_segmentation:
            return "disabled"
        return "ready" if self.seg_client.service_is_ready() else "missing"

    #: Counters of frames skipped as unusable (no pose, no camera info, bad image, an image whose partner was lost).
    SKIP_COUNTERS = ("no_tf", "no_camera_info", "bad_image", "unpaired_depth", "unpaired_color")
    #: Counters of keyframes integrated without labels.
    UNLABELLED_COUNTERS = ("keyframes_unsegmented", "segmentation_timeout", "segmentation_failed")

    def health(self) -> diag.Health:
        """What /diagnostics reports: the counters of `status()`, rates, latencies and a level."""
        c = self.counters
        skipped = sum(c[k] for k in self.SKIP_COUNTERS)
        unlabelled = sum(c[k] for k in self.UNLABELLED_COUNTERS)
        h = diag.Health(hardware_id=self._camera_frame, values={
            diag.KEY_INPUT_RATE: self.input_rate.rate_hz(), diag.KEY_LATENCY: self.integrate_ms.median_ms(),
            "segmentation_latency_ms": self.segmentation_ms.median_ms(),
            diag.KEY_RECEIVED: c["received"], diag.KEY_PROCESSED: c["integrated"],
            "frames_integrated": self.mapper.frames_integrated, "keyframes": self.mapper.keyframes,
            diag.KEY_DROPPED: c["dropped_backlog"], diag.KEY_SKIPPED: skipped, diag.KEY_QUEUE: self._queued(),
            "pending_segmentations": len(self.pending), "keyframes_without_labels": unlabelled,
            "poses_extrapolated": c["tf_extrapolated"],
            "segmentation_service": self.segmentation_state(),
            "unpublished_changes": bool(self._changed) or self._publishing,
            "checkpoints": self.checkpointer.saved if self.checkpointer else 0, diag.KEY_LAST_ERROR: self.last_error})
        if self._recent.grew("dropped", c["dropped_backlog"]):
            h.escalate(diag.WARN, "dropping frames (cannot keep up)")
        if self._recent.grew("skipped", skipped):
            h.escalate(diag.WARN, "frames skipped (no pose, no camera info or a bad image)")
        if self._recent.grew("extrapolated", c["tf_extrapolated"]):
            h.escalate(diag.WARN, "TF lags behind the images (poses extrapolated)")
        if self._recent.grew("unlabelled", unlabelled):
            h.escalate(diag.WARN, "keyframes mapped without labels (segmentation missing, slow or failing)")
        if h.values["segmentation_service"] == "missing":
            h.escalate(diag.WARN, f"segmentation service {self.seg_client.srv_name} missing")
        if self._publish_failed:
            h.escalate(diag.ERROR, self.last_error)
        if self._last_step_failed:
            h.escalate(diag.ERROR, f"last frame failed: {self.last_error}")
        if h.level == diag.OK:
            h.message = f"{self.mapper.frames_integrated} frames integrated, queue {self._queued()}"
        return h

    #: Period (s) of `mapper_progress` (published when it changed, and once a second anyway).
    PROGRESS_PERIOD_S = 0.05

    def progress(self) -> dict:
        """What `mapper_progress` says, for a player that paces itself by the mapper (rgbd_player's
        pace_topic): the stamp of the oldest frame received and not yet done (queued, released by the
        gravity window, or a keyframe waiting for its labels; frames the gravity window holds for more
        frames are not behind and do not count), else None, and the newest stamp received. A frame
        the player published is still to be done when its stamp is >= the oldest waiting one, or,
        with none waiting, > the newest received (on its way)."""
        oldest: list[int] = []
        try:  # read without the map's lock (held through a long integration); a race is fixed next tick
            if self.queue:
                oldest.append(stamp_to_ns(self.queue[0][1].header.stamp))
            if self._released:
                oldest.append(stamp_to_ns(self._released[0][2].header.stamp))
            oldest += [stamp_to_ns(p.depth_msg.header.stamp) for p in list(self.pending)]
        except (IndexError, RuntimeError):
            pass
        return {"oldest_waiting_ns": min(oldest) if oldest else None, "newest_received_ns": self._newest_received,
                "backlog": len(self.queue) + len(self._released) + len(self.pending),
                "held_for_gravity": len(self._held)}

    _newest_received: int | None = None
    _publishing = False  # an entity publication is between reading the map and publishing (`_publish`)

    def _publish_progress(self) -> None:
        progress = self.progress()
        key = tuple(progress.values())
        now = time.monotonic()
        if key != self._progress_sent or now - self._progress_at > 1.0:
            self._progress_sent, self._progress_at = key, now
            self.pub_progress.publish(String(data=json.dumps(progress)))

    def _queued(self) -> int:
        """Frames not integrated yet: the queue, the gravity window's held and released frames and the frame
        the processing step has in hand (``_process_locked``)."""
        return len(self.queue) + len(self._held) + len(self._released) + self._in_hand

    def _report(self) -> None:
        status = self.status()
        self.pub_status.publish(String(data=json.dumps(status)))
        line = (f"frames integrated {self.counters['integrated']}, dropped {status['dropped_frames']}, keyframes "
                f"{status['keyframes']}, queue {status['queue']}, checkpoints {status['checkpoints']}, "
                f"counters {dict(self.counters)}")
        if status["dropped_frames"]:
            self.get_logger().warning(line)
        else:
            self.get_logger().info(line)

    # ------------------------------------------------------------------ checkpoints
    def _maybe_checkpoint(self) -> None:
        cp = self.checkpointer
        if cp is None or not cp.due(self.mapper.frames_integrated):
            return
        if self._checkpoint_thread is not None and self._checkpoint_thread.is_alive():
            return  # the previous one is still being written
        with self.lock:
            # asked again under the lock: a service (reset_map, load_map) may have replaced the map since,
            # and a reset one is never checkpointed (as on shutdown); the newest checkpoint of a map that was
            # reset while this step waited for the lock had been an empty map (seen in CI)
            if not cp.due(self.mapper.frames_integrated):
                return
            snapshot = self._snapshot()  # a copy: the write below runs while mapping goes on
        cp.start(int(snapshot.meta["frames_integrated"]))  # the next interval counts from this snapshot
        self._checkpoint_thread = threading.Thread(target=self._write_checkpoint, args=(snapshot,),
                                                   name="checkpoint", daemon=True)
        self._checkpoint_thread.start()

    def _write_checkpoint(self, snapshot: MapSnapshot) -> None:
        assert self.checkpointer is not None
        try:
            path = self.checkpointer.save(snapshot, {"frames_integrated": snapshot.meta["frames_integrated"]})
            self.checkpoint_frames = int(snapshot.meta["frames_integrated"])
            self.get_logger().info(f"checkpoint {path} ({self.checkpointer.last_cost_s:.2f} s)")
        except (OSError, ValueError) as exc:
            self.counters["checkpoint_failed"] += 1
            self.get_logger().error(f"checkpoint failed: {exc}", throttle_duration_sec=30.0)

    def on_shutdown(self) -> None:
        """Checkpoint what was integrated since the last checkpoint (the runner calls this on SIGINT/SIGTERM)."""
        self._stop_loop()
        if self._checkpoint_thread is not None:
            self._checkpoint_thread.join(timeout=60)
        with self.lock:  # frames still waiting for the gravity verdict are mapped (geometry) before the checkpoint
            if self._window is not None:
                self._close_window("shutting down")
            if self._held:
                self._decide_alignment("shutting down")
            while self._released:
                frame = self._released.popleft()[0]
                if self.mapper.frames_integrated == 0 or not self.mapper.is_static(frame):
                    self._integrate(frame, None, geometry_only=True)
        cp = self.checkpointer
        if cp is None or self.mapper.frames_integrated == 0 or (
                cp.last_path is not None and cp.last_frames == self.mapper.frames_integrated):
            return
        with self.lock:
            snapshot = self._snapshot()
        self._write_checkpoint(snapshot)

    # ------------------------------------------------------------------ services
    def _confined(self, requested: str) -> Path:
        return confined_path(self.data_root, requested)

    def _srv_save(self, req: SaveMap.Request, res: SaveMap.Response) -> SaveMap.Response:
        from recon_core.entity import save_entities

        t0 = time.perf_counter()
        try:
            folder = self._confined(req.path)
            with self._service_turn():
                self._flush_held("save_map asked for the map")
                snapshot = self._snapshot()
                ents = self.mapper.entities()
            snapshot.write(folder)
            save_entities(ents, folder, self.output_frame)
            res.success, res.message = True, f"map saved to {folder} {self._timing(t0)}"
        except (OSError, ValueError) as exc:  # PathConfinementError is both
            res.success, res.message = False, f"cannot save to {req.path!r}: {exc}"
        return res

    def _srv_load(self, req: LoadMap.Request, res: LoadMap.Response) -> LoadMap.Response:
        try:
            folder = self._confined(req.path)
            mapper = PanopticMapper.load(folder)  # read outside the lock: mapping goes on meanwhile
            with self._service_turn():
                self.mapper = mapper
                self.gravity_monitor = None  # the loaded map keeps its gravity record (and its frame)
                self._window = None
                self._released.extend(self._held)
                self._held.clear()
                self._publish_alignment()
                self.pending.clear()
                self._changed = True
                if self.checkpointer is not None:  # the next checkpoint interval counts from the loaded map
                    self.checkpointer.start(mapper.frames_integrated)
            res.success, res.message = True, f"map loaded from {folder}"
        except (OSError, ValueError, SceneReconError) as exc:
            res.success, res.message = False, f"cannot load {req.path!r}: {exc} (the current map is kept)"
        except Exception as exc:  # a damaged file must never take the node down
            res.success, res.message = False, (f"cannot load {req.path!r}: {type(exc).__name__}: {exc} "
                                               "(the current map is kept)")
        if not res.success:
            self.get_logger().error(res.message)
        return res

    def _srv_reset(self, _req: ResetMap.Request, res: ResetMap.Response) -> ResetMap.Response:
        t0 = time.perf_counter()
        fresh = PanopticMapper(self.config, class_metas(self.class_table))  # allocated outside the lock
        with self._service_turn():
            if self.gravity_monitor is not None and self.gravity_monitor.done:
                fresh.gravity = dict(self.mapper.gravity)  # the same TF frame: the check stands
            fresh.set_alignment(self.mapper.alignment, fresh.gravity)  # the same TF frame: the same up
            fresh.recentre(self.mapper.origin_offset)
            self._start_over(fresh)
            self.queue.clear()
            self._held.clear()
            self._released.clear()
            if self._window is not None:  # still reading: the frames after the reset are the window's
                self._window = []
        res.success, res.message = True, f"map reset {self._timing(t0)}"
        return res

    def _srv_extract(self, req: ExtractEntities.Request, res: ExtractEntities.Response) -> ExtractEntities.Response:
        t0 = time.perf_counter()
        try:
            with self._service_turn():
                self._flush_held("extract_entities asked for the map")
                ents = self.mapper.entities(with_meshes=True)  # boxes come from the meshes
                frames = self.mapper.frames_integrated
            res.entities = self._entities_msg(ents, req.include_meshes, publishing=False, frames=frames)
            res.success, res.message = True, f"{len(res.entities.entities)} entities {self._timing(t0)}"
        except (RuntimeError, ValueError) as exc:
            res.success, res.message = False, f"entity extraction failed: {exc}"
        return res



def _translation(offset: np.ndarray) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = offset
    return t


def _stamp_ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _mesh_digest(e) -> str:
    """A fingerprint of an entity's mesh and labels (what a consumer would see change)."""
    h = hashlib.sha1(f"{e.class_name}|{e.class_id}|{e.category}|{e.revision}".encode())
    if e.vertices is not None:
        h.update(np.ascontiguousarray(e.vertices, np.float64).tobytes())
    if e.faces is not None:
        h.update(np.ascontiguousarray(e.faces, np.int64).tobytes())
    return h.hexdigest()


def main(args: list[str] | None = None) -> int:
    return run_node(MapperNode, args, threads=5)


if __name__ == "__main__":
    sys.exit(main())
