"""`segmentation_service`: serves `scene_recon_interfaces/srv/SegmentImage` on `segment_image`.

A thin adapter around `panoptic_mapping.segmentation`: the backend (`onnx`, `oracle`, `none`) is
picked by ROS parameters, images go through `ros_nodes.conversions`, and every failure on a request
(bad encoding, empty image, no ground truth for the stamp) is answered with success=false and a
message while the node keeps serving.

Parameters: `config_file` (the segmentation YAML, empty: config/segmentation.yaml), every key of
that file under its dotted name (see `ros_nodes.parameters`), among them
  backend                  onnx | oracle | none
  onnx.model               onnx: exported .onnx file (its convention is read off the graph)
  onnx.model_config        onnx: optional model config YAML (config/segmentation/*.yaml)
  onnx.class_table         onnx: class table YAML (give the mapper node the same `class_table`)
  onnx.device              onnx: auto (CUDA when onnxruntime offers it) | cpu | cuda
  oracle.ground_truth      oracle: a generated scene's <bag>_groundtruth folder (or the bag folder)
  oracle.level             oracle: clean | default | hard (levels of the YAML)
  oracle.seed              oracle: noise seed
  oracle.levels.<level>.*  oracle: the noise levels themselves
and the node's own settings (`SegmentationServiceConfig`):
  labels_topic    oracle: ground-truth label images (32SC1) to match by stamp
  label_buffer    oracle: how many label images to keep
  label_wait_s    oracle: how long a request waits for its label image to arrive
  stats_period_s  period of the latency log (mean/max over the period)

`/diagnostics` (`ros_nodes.diagnostics`, every second): requests and failures since start, the request
rate, the median request and backend latencies of the recent requests, the newest failure; ERROR when
the last request failed, WARN when one failed within the last seconds.

The oracle's label images come from `/ground_truth/panoptic_labels` (published by `rgbd_player`
for generated bags); a request is matched to the label image whose stamp equals the color image's.
"""

from __future__ import annotations

import sys
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import numpy as np
import rclpy
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from scene_recon_interfaces.msg import SegmentInfo
from scene_recon_interfaces.srv import SegmentImage
from sensor_msgs.msg import Image, RegionOfInterest

from panoptic_mapping.segmentation import (
    OracleSegmenter,
    PanopticSegmentation,
    SegmentationConfig,
    SegmentationError,
    make_segmenter,
)
from panoptic_mapping.segmentation.config import DEFAULT_SEGMENTATION_YAML
from recon_core.config import ConfigError, Settings, setting
from recon_core.frame import DatasetError
from ros_nodes import diagnostics as diag
from ros_nodes.conversions import image_to_depth, image_to_labels, image_to_rgb, labels_to_image, stamp_to_ns
from ros_nodes.parameters import declare_config, declare_config_file, warn_unknown_parameters
from ros_nodes.qos import SENSOR_RECORDING
from ros_nodes.runner import init_ros, shutdown_node, spin_until_stopped, start_exit_watchdog, steady_timer

NODE_NAME = "segmentation_service"
DEFAULT_LABELS_TOPIC = "/ground_truth/panoptic_labels"


class LabelBuffer:
    """The latest ground-truth label images by stamp; a request may wait briefly for its own.

    The player publishes color and labels at the same instant, but they travel on different
    topics: the request for a frame can arrive before that frame's label image. The label topic
    arrives in stamp order, so once a later label image has come, a missing one never will: the request
    fails at once instead of after `label_wait_s` (a mapper that integrates in order waits for that answer;
    0.5 s per keyframe whose label image had left the buffer, issue 26). A recording played in a loop
    starts its stamps over; a request of the new pass that comes before its own label image, while the
    newest one is still the old pass's last, fails that way too.
    Images whose labels fit 16 bits are kept in 16 bits (half the memory of a deep buffer).
    """

    def __init__(self, size: int) -> None:
        self._size = max(int(size), 1)
        self._images: OrderedDict[int, np.ndarray] = OrderedDict()
        self._cond = threading.Condition()
        self._last_put: int | None = None

    def put(self, stamp_ns: int, labels: np.ndarray) -> None:
        if labels.size and labels.min() >= 0 and labels.max() <= np.iinfo(np.uint16).max:
            labels = labels.astype(np.uint16)
        with self._cond:
            self._images[stamp_ns] = labels
            self._images.move_to_end(stamp_ns)
            self._last_put = stamp_ns
            while len(self._images) > self._size:
                self._images.popitem(last=False)
            self._cond.notify_all()

    def _settled(self, stamp_ns: int) -> bool:
        return stamp_ns in self._images or (self._last_put is not None and self._last_put > stamp_ns)

    def wait_for(self, stamp_ns: int, timeout_s: float) -> np.ndarray | None:
        with self._cond:
            self._cond.wait_for(lambda: self._settled(stamp_ns), timeout=max(timeout_s, 0.0))
            labels = self._images.get(stamp_ns)
        return None if labels is None else labels.astype(np.int32)

    def count(self) -> int:
        with self._cond:
            return len(self._images)

    def describe(self) -> str:
        with self._cond:
            if not self._images:
                return "no label image received yet"
            stamps = sorted(self._images)
            return f"{len(stamps)} buffered, stamps {_fmt_stamp(stamps[0])} .. {_fmt_stamp(stamps[-1])}"


class LatencyStats:
    """Backend and whole-request latencies since the last report; for /diagnostics also the totals since
    start, the recent latencies, the request rate and the newest failure."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._backend: list[float] = []
        self._total: list[float] = []
        self._failures = 0
        self.requests = self.failures = 0
        self.last_error = ""
        self.last_failed = False
        self.recent_total, self.recent_backend = diag.LatencyWindow(), diag.LatencyWindow()
        self.rate = diag.RateWindow()

    def add(self, backend_ms: float | None, total_ms: float, error: str = "") -> None:
        """One request: its backend latency (None: it failed, with `error`) and its whole time."""
        with self._lock:
            self._total.append(total_ms)
            self.requests += 1
            self.last_failed = backend_ms is None
            if backend_ms is None:
                self._failures += 1
                self.failures += 1
                self.last_error = error
            else:
                self._backend.append(backend_ms)
                self.recent_backend.add(backend_ms)
        self.recent_total.add(total_ms)
        self.rate.tick()

    def report(self) -> str | None:
        """One line (and reset), or None when there were no requests."""
        with self._lock:
            if not self._total:
                return None
            b = np.asarray(self._backend) if self._backend else np.zeros(1)
            t = np.asarray(self._total)
            line = (f"{len(t)} request(s), {self._failures} failed; backend latency mean {b.mean():.1f} ms, "
                    f"max {b.max():.1f} ms; request mean {t.mean():.1f} ms, max {t.max():.1f} ms")
            self._backend, self._total, self._failures = [], [], 0
            return line


@dataclass
class SegmentationServiceConfig(Settings):
    """ROS-side settings of the service; the segmentation itself is `SegmentationConfig`."""

    labels_topic: str = setting(DEFAULT_LABELS_TOPIC, doc="oracle: ground-truth label images (32SC1)")
    label_buffer: int = setting(64, min=1, doc="oracle: how many label images are kept (a paced player runs at "
                                "most the gravity window (30) + pace_max_lag (10) frames ahead of the requests)")
    label_wait_s: float = setting(0.5, min=0.0, doc="oracle: how long (s) a request waits for its label image")
    stats_period_s: float = setting(10.0, min=0.0, min_exclusive=True, doc="period (s) of the latency log")


class SegmentationService(Node):
    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.config = declare_config(self, SegmentationConfig,
                                     declare_config_file(self, DEFAULT_SEGMENTATION_YAML))
        settings = declare_config(self, SegmentationServiceConfig)
        self.labels_topic = settings.labels_topic
        self.label_wait_s = settings.label_wait_s
        buffer_size = settings.label_buffer
        stats_period_s = settings.stats_period_s
        self.config.oracle.noise()  # unknown level: fail at start, naming the valid ones
        self.segmenter = make_segmenter(self.config)
        self.backend = self.config.backend
        self.stats = LatencyStats()
        self.labels = LabelBuffer(buffer_size)
        self.create_service(SegmentImage, "segment_image", self.on_request,
                            callback_group=MutuallyExclusiveCallbackGroup())
        if isinstance(self.segmenter, OracleSegmenter):
            self.create_subscription(Image, self.labels_topic, self.on_labels, SENSOR_RECORDING,
                                     callback_group=MutuallyExclusiveCallbackGroup())
        steady_timer(self, stats_period_s, self.log_stats, MutuallyExclusiveCallbackGroup())
        self._recent = diag.RecentIncrease()
        self.diagnostics = diag.NodeDiagnostics(self, "2D panoptic segmentation", self.health,
                                                callback_group=MutuallyExclusiveCallbackGroup())
        details = {
            "onnx": f"model {self.config.onnx.model or self.config.onnx.model_config}: "
                    f"{getattr(self.segmenter, 'description', '')}, on {getattr(self.segmenter, 'provider', '?')}",
            "oracle": f"ground truth {self.config.oracle.ground_truth}, level {self.config.oracle.level}, "
                      f"seed {self.config.oracle.seed}, labels from {self.resolve_topic_name(self.labels_topic)}",
            "none": "no segments (geometry only)",
        }[self.backend]
        self.get_logger().info(f"serving {self.resolve_service_name('segment_image')}: backend {self.backend} "
                               f"({details})")

    # ------------------------------------------------------------------ callbacks
    def on_labels(self, msg: Image) -> None:
        try:
            self.labels.put(stamp_to_ns(msg.header.stamp), image_to_labels(msg))
        except DatasetError as exc:
            self.get_logger().warning(f"ignoring label image on {self.labels_topic}: {exc}")

    def on_request(self, request: SegmentImage.Request, response: SegmentImage.Response) -> SegmentImage.Response:
        t0 = time.perf_counter()
        try:
            result = self.segment(request)
        except (DatasetError, SegmentationError, ValueError) as exc:
            return self._fail(response, str(exc), t0)
        except Exception as exc:  # a backend bug must not take the service down
            self.get_logger().error(f"segmentation failed unexpectedly: {exc!r}")
            return self._fail(response, f"internal error: {exc!r}", t0)
        header = request.color.header
        response.labels = labels_to_image(result.labels, stamp_to_ns(header.stamp), header.frame_id)
        response.segments = [_segment_info(s) for s in result.segments]
        response.latency_ms = float(result.latency_ms)
        response.success = True
        response.message = f"{self.backend}: {len(result.segments)} segment(s)"
        self.stats.add(result.latency_ms, (time.perf_counter() - t0) * 1e3)
        return response

    def segment(self, request: SegmentImage.Request) -> PanopticSegmentation:
        """Decode the request and run the backend; raises with a message for the caller."""
        color_msg = request.color
        if color_msg.height == 0 or color_msg.width == 0:
            raise SegmentationError(f"empty color image ({color_msg.width}x{color_msg.height})")
        color = image_to_rgb(color_msg)
        depth = None
        if request.has_depth:
            depth, _ = image_to_depth(request.depth)
            if depth.shape != color.shape[:2]:
                raise SegmentationError(f"depth {depth.shape[1]}x{depth.shape[0]} and color "
                                        f"{color.shape[1]}x{color.shape[0]} differ in size; depth must be registered")
        if not isinstance(self.segmenter, OracleSegmenter):
            return self.segmenter.segment(color, depth)
        stamp = stamp_to_ns(color_msg.header.stamp)
        labels = self.labels.wait_for(stamp, self.label_wait_s)
        if labels is None:
            raise SegmentationError(
                f"oracle: no ground-truth label image with stamp {_fmt_stamp(stamp)} on "
                f"{self.resolve_topic_name(self.labels_topic)} ({self.labels.describe()}); the color image "
                "must carry the stamp of a published label image (rgbd_player publishes both for generated bags)"
            )
        if labels.shape != color.shape[:2]:
            raise SegmentationError(f"label image {labels.shape[::-1]} and color {color.shape[1::-1]} differ in size")
        return self.segmenter.segment_labels(labels, depth, key=stamp)

    def health(self) -> diag.Health:
        """What /diagnostics reports."""
        st = self.stats
        h = diag.Health(values={
            diag.KEY_INPUT_RATE: st.rate.rate_hz(), diag.KEY_LATENCY: st.recent_total.median_ms(),
            "backend_latency_ms": st.recent_backend.median_ms(), diag.KEY_RECEIVED: st.requests,
            diag.KEY_PROCESSED: st.requests - st.failures, "failed": st.failures, "backend": self.backend,
            diag.KEY_LAST_ERROR: st.last_error})
        if isinstance(self.segmenter, OracleSegmenter):
            h.values["label_images"] = self.labels.count()
        if st.last_failed:
            h.escalate(diag.ERROR, f"last request failed: {st.last_error}")
        elif self._recent.grew("failed", st.failures):
            h.escalate(diag.WARN, f"requests failed lately: {st.last_error}")
        if h.level == diag.OK:
            h.message = f"{st.requests} request(s) served ({self.backend})"
        return h

    def log_stats(self) -> None:
        line = self.stats.report()
        if line:
            self.get_logger().info(f"latency: {line}")

    def _fail(self, response: SegmentImage.Response, message: str, t0: float) -> SegmentImage.Response:
        self.get_logger().warning(f"request failed: {message}")
        response.success = False
        response.message = message
        self.stats.add(None, (time.perf_counter() - t0) * 1e3, message)
        return response


def _segment_info(s: Any) -> SegmentInfo:
    x, y, w, h = s.box
    return SegmentInfo(id=int(s.id), class_id=int(s.class_id), class_name=s.class_name, is_thing=bool(s.is_thing),
                       instance_id=int(s.instance_id), score=float(s.score),
                       box=RegionOfInterest(x_offset=int(x), y_offset=int(y), width=int(w), height=int(h)))


def _fmt_stamp(ns: int) -> str:
    return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"


def main(args: list[str] | None = None) -> int:
    stop = init_ros(args)
    start_exit_watchdog(stop)
    try:
        node = SegmentationService()
    except (SegmentationError, ConfigError, DatasetError, KeyError, OSError) as exc:
        rclpy.logging.get_logger(NODE_NAME).fatal(f"cannot start: {exc}")
        rclpy.try_shutdown()
        return 1
    warn_unknown_parameters(node)
    try:
        spin_until_stopped(node, stop, threads=2)
    finally:
        node.log_stats()
        shutdown_node(node)
    return 0


if __name__ == "__main__":
    sys.exit(main())
