"""`rgbd_player`: publish an RGB-D recording (bag or frame folder) as live camera topics + TF.

`ros2 bag play` needs rosbag2, which the PyPI ROS 2 wheels lack; this node reads any source the
data layer reads (rosbag2 .mcap/.db3, TUM, 7-Scenes), so the mapper can be driven from a file
exactly as from a live camera. Frames are published at their recorded rate (scaled by `rate`)
with their original stamps; the camera pose goes out as `map_frame -> camera_frame` on /tf.

Like `ros2 bag play --clock`: with `publish_clock` the recording's time goes out on /clock (every
frame and every `clock_period_s` in between, scaled by `rate`), so nodes with `use_sim_time` run on
it; `start_offset_s` skips the first seconds; `loop` starts over; the service `~/set_paused`
(std_srvs/SetBool, true = pause) holds playback and the clock, and resuming continues from the same
frame with the same timing. Parameters: `RGBDPlayerConfig` (declared through `ros_nodes.parameters`).
`/diagnostics` (`ros_nodes.diagnostics`, every second and once more when playback ends): state, frames
published and their rate, the median lateness of a frame behind its schedule, frames the reader
skipped; ERROR when the source cannot be played, WARN when it played without its subscribers or
the reader skipped frames within the last seconds.
"""

from __future__ import annotations

import collections
import json
import sys
import time
from dataclasses import dataclass

import rclpy
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import String
from std_srvs.srv import SetBool
from tf2_msgs.msg import TFMessage

from panoptic_mapping.dataio import DataInputConfig, DatasetError
from panoptic_mapping.dataio.registry import open_dataset
from recon_core.config import Settings, setting
from ros_nodes import diagnostics as diag
from ros_nodes.conversions import (
    depth_to_image,
    intrinsics_to_camera_info,
    labels_to_image,
    make_transform_stamped,
    ns_to_stamp,
    rgb_to_image,
)
from ros_nodes.parameters import declare_config, warn_unknown_parameters
from ros_nodes.qos import PROGRESS_TOPIC, SENSOR_RECORDING, STATUS, TF_DYNAMIC
from ros_nodes.runner import init_ros, start_exit_watchdog


@dataclass
class RGBDPlayerConfig(Settings):
    """Settings of the player node (what to play, how fast, under which names)."""

    source: str = setting("", doc="bag (.mcap/.db3) or TUM / 7-Scenes folder to play")
    rate: float = setting(1.0, min=0.0, min_exclusive=True, doc="playback speed factor")
    loop: bool = setting(False, doc="start over at the end")
    map_frame: str = setting("map", doc="parent frame of the published camera pose")
    camera_frame: str = setting("camera_color_optical_frame", doc="frame id of the images and the pose's child")
    topic_prefix: str = setting("/camera", doc="images and camera info go to <prefix>/color/..., <prefix>/depth/...")
    color_topic: str = setting("", doc="color image topic (empty: <prefix>/color/image_raw)")
    depth_topic: str = setting("", doc="depth image topic (empty: <prefix>/depth/image_rect_raw)")
    camera_info_topic: str = setting("", doc="camera info topic (empty: <prefix>/color/camera_info)")
    start_offset_s: float = setting(0.0, min=0.0, doc="skip the recording's first seconds")
    stride: int = setting(1, min=1, doc="play every n-th frame pair only (a preset's data.stride, as "
                          "`scene-recon map --preset` reads the recording)")
    publish_clock: bool = setting(False, doc="publish the recording's time on /clock (for use_sim_time nodes)")
    #: Every frame's own sample goes out before it; between frames 100 Hz (0.01 s) made a 30 Hz recording ~4
    #: samples a frame, each taken by every use_sim_time node (rclpy's time source, a Python callback per
    #: sample), and the player alone spent ~1 of its 3.5 CPU s on /clock (a 30 Hz bag, py-spy). 20 Hz between
    #: frames keeps a sparse recording's time moving (`ros2 bag play --clock` sends 40 Hz in all).
    clock_period_s: float = setting(0.05, min=0.001, doc="period (s) of /clock between frames (each frame also "
                                    "sends its own stamp)")
    labels_topic_in: str = setting("", doc="label image topic in the recording (empty: auto-detect)")
    #: Start only once this many subscribers listen to every stream (0: at once), so that no frame
    #: is lost to DDS discovery when a mapper is launched beside the player.
    wait_for_subscribers: int = setting(0, min=0, doc="subscribers every stream needs before playing")
    #: The same for the ground-truth label topic (an oracle segmentation service listens there).
    wait_for_label_subscribers: int = setting(0, min=0, doc="subscribers the label topic needs before playing")
    wait_timeout_s: float = setting(30.0, min=0.0, doc="play anyway after this long (s) without them")
    #: A publisher sees a subscriber (its count goes up) before that subscriber has matched the
    #: publisher in turn; frames sent in between can be lost. Measured: 1 of 30 frames lost now and
    #: then without a grace period, none with 0.5 s.
    wait_grace_s: float = setting(0.5, min=0.0, doc="once the subscribers are there, wait this long (s) more")
    #: A reliable reader that matched late, or fell behind, recovers what it missed from the writers' history,
    #: which goes away with the player: after the last frame the player stays until every reliable
    #: subscriber has acknowledged everything (at most this long). Leaving 0.5 s after the last frame, the
    #: mapper's /tf reader of a loaded machine missed the last 8 poses of a 30-frame bag.
    #: Back-pressure: a recording is played no faster than the mapper maps it. Once the mapper's progress
    #: (`mapper_progress`) is heard, a frame waits while `pace_max_lag` published frames are still to be
    #: done there (the schedule and /clock stand still meanwhile, as when paused), so a slow or loaded mapper
    #: gets every frame, in order, and an oracle's label images are still buffered when it asks for them.
    #: A mapper that makes no progress for `pace_timeout_s` is not waited for any more (warned).
    pace_topic: str = setting(PROGRESS_TOPIC, doc="the mapper's progress topic the playback is paced by "
                              "(empty: play at the recorded timing whatever the mapper does)")
    pace_max_lag: int = setting(10, min=1, doc="frames published and not yet done by the mapper before "
                                "playback waits")
    pace_timeout_s: float = setting(60.0, min=0.0, doc="stop pacing after the mapper made no progress this long (s)")
    drain_timeout_s: float = setting(10.0, min=0.0, doc="after playing, wait at most this long (s) for reliable "
                                     "subscribers to acknowledge every message")


class RGBDPlayer(Node):
    def __init__(self) -> None:
        super().__init__("rgbd_player")
        settings = declare_config(self, RGBDPlayerConfig)
        self.path = settings.source
        self.rate = settings.rate
        self.loop = settings.loop
        self.map_frame = settings.map_frame
        self.camera_frame = settings.camera_frame
        self.labels_topic_in = settings.labels_topic_in
        self.wait_for_subscribers = settings.wait_for_subscribers
        self.wait_for_label_subscribers = settings.wait_for_label_subscribers
        self.wait_timeout_s = settings.wait_timeout_s
        self.wait_grace_s = settings.wait_grace_s
        self.drain_timeout_s = settings.drain_timeout_s
        self._matched_at: float | None = None
        self.start_offset_ns = int(settings.start_offset_s * 1e9)
        self.stride = settings.stride
        self.clock_period_s = settings.clock_period_s
        prefix = settings.topic_prefix.rstrip("/")
        self.pub_color = self.create_publisher(Image, settings.color_topic or f"{prefix}/color/image_raw",
                                               SENSOR_RECORDING)
        self.pub_depth = self.create_publisher(Image, settings.depth_topic or f"{prefix}/depth/image_rect_raw",
                                               SENSOR_RECORDING)
        self.pub_info = self.create_publisher(CameraInfo, settings.camera_info_topic
                                              or f"{prefix}/color/camera_info", SENSOR_RECORDING)
        self.pub_clock = (self.create_publisher(Clock, "/clock", QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE)) if settings.publish_clock else None)
        self.paused = False
        self._paused_at: float | None = None
        self._last_clock = 0.0
        self.create_service(SetBool, "~/set_paused", self._srv_set_paused)
        self.pub_labels = self.create_publisher(Image, "/ground_truth/panoptic_labels", SENSOR_RECORDING)
        self.pub_tf = self.create_publisher(TFMessage, "/tf", TF_DYNAMIC)
        self.pace_max_lag = settings.pace_max_lag
        self.pace_timeout_s = settings.pace_timeout_s
        self._progress: dict | None = None  # the mapper's newest progress message
        self._progress_changed = 0.0
        self._sent_stamps: collections.deque[int] = collections.deque()  # published, maybe not done yet
        #: `published` when the mapper was first heard saying it has received nothing (starting, or restarted);
        #: None once it has received a frame. Frames published since then are on their way to it.
        self._published_at_silence: int | None = None
        self._pacing_since: float | None = None
        self.paced_s = 0.0  # time spent waiting for the mapper
        self.pace_waits = 0
        self.pace_topic = settings.pace_topic
        if settings.pace_topic:
            self.create_subscription(String, settings.pace_topic, self._on_progress, STATUS)
        self.published = 0
        self.finished = False
        self.last_error = ""
        self._failed = False
        self._unmatched = False  # played without the subscribers it waited for
        self.publish_rate, self.lateness_ms = diag.RateWindow(), diag.LatencyWindow()
        self._recent = diag.RecentIncrease()
        self.diagnostics = diag.NodeDiagnostics(self, "RGB-D playback", self.health)
        self._frames = None
        self._t0_wall = self._t0_data = None
        self._pending = None
        if not self.path:
            self._error("parameter 'source' is empty: give a bag or frame folder to play")
            return
        self._open()
        self._created = time.monotonic()
        # no timer: `main` calls `_tick` between spins and sleeps until the next frame is due (`next_wait_s`);
        # a 2 ms timer cost 0.2 of a core of the 2 a 30 Hz bag graph has (rclpy builds a wait set per spin)
        self._next_due: float | None = None

    def _open(self) -> None:
        cfg = DataInputConfig(require_pose=False)
        cfg.topics.labels = self.labels_topic_in
        cfg.stride = self.stride
        try:
            self._loader = open_dataset(self.path, cfg)
        except DatasetError as exc:
            self._error(f"cannot play {self.path}: {exc}")
            return
        self._frames = iter(self._loader)
        self._t0_wall = self._t0_data = None
        self._sent_stamps.clear()  # a loop starts over: its stamps repeat (pacing by stamp restarts too)
        self._first_ns: int | None = None

    def _srv_set_paused(self, req: SetBool.Request, res: SetBool.Response) -> SetBool.Response:
        """Pause (true) or resume (false): the schedule moves by the time spent paused."""
        now = time.monotonic()
        if req.data and not self.paused:
            self.paused, self._paused_at = True, now
        elif not req.data and self.paused:
            if self._t0_wall is not None and self._paused_at is not None:
                self._t0_wall += now - self._paused_at
            self.paused, self._paused_at = False, None
        res.success = True
        res.message = f"{'paused' if self.paused else 'playing'} after {self.published} frames"
        self.get_logger().info(res.message)
        return res

    def _on_progress(self, msg: String) -> None:
        try:
            progress = json.loads(msg.data)
        except ValueError:
            return
        if self._progress is None or {k: progress.get(k) for k in ("oldest_waiting_ns", "newest_received_ns")} != \
                {k: self._progress.get(k) for k in ("oldest_waiting_ns", "newest_received_ns")}:
            self._progress_changed = time.monotonic()
        self._progress = progress
        if progress.get("oldest_waiting_ns") is None and progress.get("newest_received_ns") is None:
            if self._published_at_silence is None:
                self._published_at_silence = self.published
        else:
            self._published_at_silence = None

    def lag(self) -> int:
        """Published frames the mapper has still to do (0 before its progress was heard)."""
        p = self._progress
        if p is None:
            return 0
        oldest, newest = p.get("oldest_waiting_ns"), p.get("newest_received_ns")
        if oldest is None and newest is None:
            # a mapper that has received nothing yet (starting, or restarted after a crash): the frames published
            # since it said so are on their way. Unpaced here, a player 8x faster than recorded sent a whole
            # 90-frame bag before a mapper on loaded cores took its first, and the readers' history (30) lost 25.
            return self.published - (self._published_at_silence or 0)
        sent = self._sent_stamps
        if oldest is not None:
            while sent and sent[0] < oldest:
                sent.popleft()
            return len(sent)
        if newest is not None:
            while sent and sent[0] <= newest:
                sent.popleft()
        return len(sent)

    def _paced(self, now: float) -> bool:
        """Whether the next frame waits for the mapper (back-pressure); the schedule moves by the wait."""
        if self._progress is None or self.pace_max_lag <= 0:
            return False
        if self.lag() < self.pace_max_lag:
            if self._pacing_since is not None:  # resume: the schedule moves by the time waited
                waited = now - self._pacing_since
                if self._t0_wall is not None:
                    self._t0_wall += waited
                self.paced_s += waited
                self._pacing_since = None
            return False
        if self._pacing_since is None:
            self._pacing_since = now
            self.pace_waits += 1
        if self.pace_timeout_s and now - max(self._progress_changed, self._pacing_since) > self.pace_timeout_s:
            self.get_logger().warning(f"the mapper made no progress for {self.pace_timeout_s:g} s with "
                                      f"{self.lag()} frames to do; playing on without pacing")
            self.pace_max_lag = 0
            self._pacing_since = None
            return False
        return True

    def data_time_ns(self, now: float) -> int | None:
        """The recording's time at wall time `now` (None before the first frame)."""
        if self._t0_wall is None or self._t0_data is None:
            return None
        return int(self._t0_data + (now - self._t0_wall) * self.rate * 1e9)

    def _publish_clock(self, stamp_ns: int) -> None:
        if self.pub_clock is not None:
            self.pub_clock.publish(Clock(clock=ns_to_stamp(stamp_ns)))

    def _tick(self) -> None:
        if self.finished or self._frames is None or self.paused:
            return
        # every stream must be matched, TF included: a mapper that gets images but missed their TF
        # (volatile QoS) would drop every frame
        streams = (self.pub_color, self.pub_depth, self.pub_info, self.pub_tf)
        if self._t0_wall is None and (
            min(p.get_subscription_count() for p in streams) < self.wait_for_subscribers
            or self.pub_labels.get_subscription_count() < self.wait_for_label_subscribers
        ):
            if time.monotonic() - self._created < self.wait_timeout_s:
                return
            self.get_logger().warning(f"subscribers missing after {self.wait_timeout_s:.0f} s; playing anyway")
            self._unmatched = True
            self.wait_for_subscribers = self.wait_for_label_subscribers = 0
        if self._t0_wall is None and (self.wait_for_subscribers or self.wait_for_label_subscribers):
            if self._matched_at is None:
                self._matched_at = time.monotonic()
            if time.monotonic() - self._matched_at < self.wait_grace_s:
                return
        if (self._t0_wall is None and self.pace_topic and self._progress is None and self.pace_max_lag > 0
                and self.count_publishers(self.pace_topic) > 0
                and time.monotonic() - self._created < self.wait_timeout_s):
            return  # a mapper is there: its first progress says how far ahead the player may go
        while self._pending is None:
            try:
                frame = next(self._frames)
                if self._first_ns is None:
                    self._first_ns = frame.timestamp_ns
                if frame.timestamp_ns - self._first_ns >= self.start_offset_ns:
                    self._pending = frame
            except StopIteration:
                skipped = {k: v for k, v in self._loader.skips.as_dict().items() if v}
                paced = (f"; waited {self.paced_s:.1f} s for the mapper ({self.pace_waits} times)"
                         if self.pace_waits else "")
                self.get_logger().info(f"played {self.published} frames; skipped: {skipped or 'none'}{paced}")
                if self.loop:
                    self._open()
                    return
                self.finished = True
                return
            except DatasetError as exc:
                self._error(f"stopped playing: {exc}")
                return
        f = self._pending
        now = time.monotonic()
        if self._t0_wall is None:
            self._t0_wall, self._t0_data = now, f.timestamp_ns
        due = self._t0_wall + (f.timestamp_ns - self._t0_data) * 1e-9 / max(self.rate, 1e-6)
        self._next_due = due
        if self._paced(now):
            return  # the mapper is behind: this frame (and the clock) wait for it
        if now < due:
            if self.pub_clock is not None and now - self._last_clock >= self.clock_period_s:
                self._last_clock = now
                self._publish_clock(min(self.data_time_ns(now) or f.timestamp_ns, f.timestamp_ns))
            return
        stamp = f.timestamp_ns
        self._last_clock = now
        self._publish_clock(stamp)  # the clock first: a sim-time node sees its frame's time already
        if f.pose is not None:
            self.pub_tf.publish(TFMessage(transforms=[
                make_transform_stamped(f.pose, self.map_frame, self.camera_frame, stamp)]))
        self.pub_info.publish(intrinsics_to_camera_info(f.intrinsics, stamp, self.camera_frame))
        self.pub_color.publish(rgb_to_image(f.color, stamp, self.camera_frame))
        self.pub_depth.publish(depth_to_image(f.depth, stamp, self.camera_frame))
        if "labels" in f.extras:
            self.pub_labels.publish(labels_to_image(f.extras["labels"], stamp, self.camera_frame))
        self.published += 1
        if self.pace_topic:
            self._sent_stamps.append(stamp)
        self.publish_rate.tick(now)
        self.lateness_ms.add(1000 * (now - due))
        self._pending = None
        self._next_due = None  # the next frame is read at once

    #: The longest the player sleeps between two looks at its schedule (s) while paused, paced or done (a
    #: message, the mapper's progress or a pause request, ends the sleep at once) ...
    IDLE_WAIT_S = 0.05
    #: ... and before the first frame (waiting for subscribers, a loop starting over).
    START_WAIT_S = 0.01

    def next_wait_s(self) -> float:
        """How long `main` may spin (take messages and service calls) before `_tick` is due again: until the
        next frame's time (and the next /clock sample), 0 when the next frame is to be read."""
        if self.finished or self._frames is None or self.paused or self._pacing_since is not None:
            return self.IDLE_WAIT_S
        if self._t0_wall is None:
            return self.START_WAIT_S
        if self._pending is None or self._next_due is None:
            return 0.0
        wait = self._next_due - time.monotonic()
        if self.pub_clock is not None:
            wait = min(wait, self.clock_period_s)
        return min(max(wait, 0.0), self.IDLE_WAIT_S)

    def drain(self) -> bool:
        """Wait (at most `drain_timeout_s`) until every reliable subscriber has acknowledged every message;
        False (and a warning) when one has not."""
        deadline = time.monotonic() + self.drain_timeout_s
        pubs = [self.pub_tf, self.pub_info, self.pub_color, self.pub_depth, self.pub_labels]
        for pub in pubs:
            left = max(deadline - time.monotonic(), 0.0)
            if not pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))):
                self.get_logger().warning(f"{pub.topic_name}: a subscriber has not acknowledged every message "
                                          f"after {self.drain_timeout_s:g} s; leaving anyway")
                return False
        return True

    def _error(self, message: str) -> None:
        self.get_logger().error(message)
        self.last_error, self._failed, self.finished = message, True, True

    def state(self) -> str:
        if self._failed:
            return "failed"
        if self.finished:
            return "finished"
        if self.paused:
            return "paused"
        return "waiting for subscribers" if self._t0_wall is None else "playing"

    def health(self) -> diag.Health:
        """What /diagnostics reports."""
        loader = getattr(self, "_loader", None)
        skipped = sum(loader.skips.as_dict().values()) if loader is not None else 0
        state = self.state()
        h = diag.Health(hardware_id=self.camera_frame, values={
            "state": state, "source": self.path, diag.KEY_INPUT_RATE: self.publish_rate.rate_hz(),
            diag.KEY_LATENCY: self.lateness_ms.median_ms(), diag.KEY_PROCESSED: self.published,
            diag.KEY_SKIPPED: skipped, diag.KEY_QUEUE: int(self._pending is not None),
            "subscribers": min((p.get_subscription_count() for p in (self.pub_color, self.pub_depth, self.pub_tf)),
                               default=0),
            "paced_s": round(self.paced_s, 2), "mapper_lag": self.lag(),
            diag.KEY_LAST_ERROR: self.last_error})
        if self._failed:
            h.escalate(diag.ERROR, self.last_error)
        if self._unmatched:
            h.escalate(diag.WARN, "played without the subscribers it waited for: frames may be lost")
        if self._recent.grew("skipped", skipped):
            h.escalate(diag.WARN, "frames skipped by the reader")
        if h.level == diag.OK:
            h.message = f"{state}: {self.published} frames published"
        return h


def main(args: list[str] | None = None) -> int:
    stop = init_ros(args)  # SIGINT/SIGTERM set `stop`: the loop ends, the node is destroyed, exit 0
    start_exit_watchdog(stop, nothing_to_save=True)
    node = RGBDPlayer()
    warn_unknown_parameters(node)
    try:
        while rclpy.ok() and not node.finished and not stop.is_set():
            rclpy.spin_once(node, timeout_sec=node.next_wait_s())  # (0: take what is there, do not wait)
            node._tick()
        node.diagnostics.publish()  # the final state (finished / failed) before the node goes away
        if not stop.is_set():
            node.drain()
        # (and a moment for the last diagnostics)
        end = time.monotonic() + 0.5
        while rclpy.ok() and time.monotonic() < end and not stop.is_set():
            rclpy.spin_once(node, timeout_sec=0.05)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
