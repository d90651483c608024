"""Run the mapping stage over a recording: frames -> keyframe gating -> segmentation -> mapper.

Used by `scene-recon map` and the benchmarks; the ROS mapper node drives `PanopticMapper`
itself (asynchronous segmentation service), but with the same gating and conversion.
"""

from __future__ import annotations

import atexit
import collections
import dataclasses
import json
import logging
import re
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from panoptic_mapping.config import MapperConfig
from panoptic_mapping.dataio import DataInputConfig
from panoptic_mapping.dataio.diagnose import explain_empty
from panoptic_mapping.dataio.registry import open_dataset
from panoptic_mapping.depth_segmentation import SegmentationWorker
from panoptic_mapping.fusion import BACKGROUND, PanopticMasks
from panoptic_mapping.gravity import (
    GravityConfig,
    GravityEstimate,
    GravityEstimator,
    alignment_from_estimate,
    angle_deg,
    load_alignment,
    rotation_angle_deg,
    rotation_to_z,
    up_of_alignment,
)
from panoptic_mapping.mapper import ClassMeta, PanopticMapper

if TYPE_CHECKING:
    from panoptic_mapping.checkpoint import Checkpoint, Checkpointer
from recon_core.classes import ClassTable, load_class_table
from recon_core.entity import Entity, save_entities
from recon_core.errors import DatasetError, InputError

log = logging.getLogger(__name__)

#: A recording whose first pose is farther than this from its frame's origin is mapped relative to
#: that pose (rounded to whole metres), so 2 cm voxels keep their precision in float32.
RECENTRE_BEYOND_M = 1000.0
#: Past this the coordinates are most likely geodetic (UTM) or in the wrong unit: warned about.
WARN_BEYOND_M = 1_000_000.0
_ANSI = re.compile(r"\x1b\[[0-9;]*m")


class MappingFailed(InputError):
    """Every frame of a recording failed in the mapper."""


def class_metas(table: ClassTable | None = None) -> dict[int, ClassMeta]:
    table = table or load_class_table()
    return {c.id: ClassMeta(c.name, c.is_thing, c.category, c.max_size_m) for c in table}


def masks_from_segmentation(seg: Any) -> PanopticMasks:
    """`PanopticSegmentation` (any backend) -> the mapper's per-mask arrays."""
    n = max([s.id for s in seg.segments], default=0) + 1
    cls = np.full(n, BACKGROUND, np.int32)
    thing = np.zeros(n, bool)
    score = np.zeros(n)
    for s in seg.segments:
        cls[s.id], thing[s.id], score[s.id] = s.class_id, s.is_thing, s.score
    labels = np.where(seg.labels < n, seg.labels, 0).astype(np.int32)
    return PanopticMasks(labels, cls, thing, score)


@dataclass
class MappingRun:
    frames: int = 0
    keyframes: int = 0
    segmentation_calls: int = 0
    wall_s: float = 0.0
    mapper_s: float = 0.0
    segmentation_s: float = 0.0
    read_s: float = 0.0
    stage_ms: dict[str, float] = field(default_factory=dict)
    #: Frames each stage ran on (depth segmentation, fusion, ...: the label frames only); `stage_ms`
    #: is averaged over all frames, `stage_ms_per_call` (summary) over these.
    stage_frames: dict[str, int] = field(default_factory=dict)
    skipped: dict[str, int] = field(default_factory=dict)
    #: Frames the mapper raised on (logged, skipped; the run goes on) and their first errors.
    failed_frames: int = 0
    failures: dict[str, int] = field(default_factory=dict)
    #: Frames of a camera standing still (`static.*` of the mapper config): skipped whole, they add nothing.
    static_frames: int = 0
    #: Map-frame position of the map's origin (non-zero when the recording was recentred).
    origin_offset_m: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    #: The recording ended early (truncated bag); frames before the cut were mapped.
    truncated: bool = False
    #: Stopped by a request (SIGINT/SIGTERM) before the end; a checkpoint holds the progress.
    interrupted: bool = False
    #: Frames taken from the recording so far (posed or not), also those a resumed run skipped.
    frames_read: int = 0
    #: Resumed from a checkpoint: its generation (0: a fresh run), and the frames it had read.
    resumed_generation: int = 0
    resumed_frames_read: int = 0
    #: Checkpoints written by this run and the time they took.
    checkpoints: int = 0
    checkpoint_s: float = 0.0
    #: Label frames whose depth segmentation ran ahead on the worker process (`segment_ahead`), frames
    #: segmented ahead but not used (a guess that missed), and the worker's CPU seconds (not in this
    #: process's CPU time).
    ahead_used: int = 0
    ahead_unused: int = 0
    ahead_cpu_s: float = 0.0
    poses: list[np.ndarray] = field(default_factory=list)

    @property
    def mapper_fps(self) -> float:
        return self.frames / self.mapper_s if self.mapper_s > 0 else 0.0

    def summary(self) -> dict[str, Any]:
        d = {k: v for k, v in asdict(self).items() if k != "poses"}
        d["mapper_fps"] = round(self.mapper_fps, 2)
        d["stage_ms"] = {k: round(v / max(self.frames, 1), 2) for k, v in self.stage_ms.items()}
        d["stage_ms_per_call"] = {k: round(v / max(self.stage_frames.get(k, 0), 1), 2)
                                  for k, v in self.stage_ms.items()}
        for k in ("wall_s", "mapper_s", "segmentation_s", "read_s", "checkpoint_s"):
            d[k] = round(d[k], 3)
        return d

    #: Fields a checkpoint carries over to the resumed run (sums over the whole run).
    _RESUMED = ("frames", "segmentation_calls", "failed_frames", "failures", "stage_ms", "stage_frames",
                "mapper_s", "segmentation_s", "read_s")

    def progress(self, source: str | Path, last_timestamp_ns: int | None) -> dict[str, Any]:
        """What a checkpoint records of this run (see `restore`)."""
        return {"source": str(Path(source).resolve()), "frames_read": self.frames_read,
                "last_timestamp_ns": last_timestamp_ns,
                "run": {k: getattr(self, k) for k in self._RESUMED}}

    def restore(self, progress: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
        """Continue the counts of the run a checkpoint was taken of."""
        for k, v in (progress.get("run") or {}).items():
            if k in self._RESUMED:
                setattr(self, k, type(getattr(self, k))(v))
        self.frames_read = self.resumed_frames_read = int(progress.get("frames_read", 0))
        poses = arrays.get("poses")
        self.poses = [p for p in poses] if poses is not None and poses.ndim == 3 else []


def estimate_gravity(source: str | Path, data_config: DataInputConfig | None = None,
                     cfg: GravityConfig | None = None) -> GravityEstimate:
    """Up of a recording's world frame from the depth of its first posed frames (``cfg.window_frames``
    frames, every ``cfg.stride``-th one, within the data input's own start/stride/max_frames)."""
    return gravity_estimator(source, data_config, cfg).estimate()


def gravity_estimator(source: str | Path, data_config: DataInputConfig | None = None,
                      cfg: GravityConfig | None = None) -> GravityEstimator:
    """The estimator fed with the window of ``estimate_gravity`` (more frames can be added later)."""
    data_config = data_config or DataInputConfig()
    cfg = cfg or data_config.gravity
    window = cfg.window_frames
    if data_config.max_frames:
        window = max(1, min(window, -(-data_config.max_frames // cfg.stride)))
    dcfg = dataclasses.replace(data_config, stride=data_config.stride * cfg.stride, max_frames=window,
                               require_pose=True)
    est = GravityEstimator(cfg)
    with open_dataset(source, dcfg) as loader:
        for frame in loader:
            if frame.pose is not None:
                est.add_frame(frame.depth, frame.intrinsics, frame.pose)
    return est


def resolve_gravity(source: str | Path, data_config: DataInputConfig | None = None,
                    cfg: GravityConfig | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    """The transform input world -> gravity-aligned map frame for ``cfg.mode`` (auto | z | a file), and
    what was done (for map.json / summary.json): mode, the input's up, the angle corrected, a note."""
    transform, info, _est = _resolve_gravity(source, data_config, cfg)
    return transform, info


def _resolve_gravity(source: str | Path, data_config: DataInputConfig | None = None,
                     cfg: GravityConfig | None = None
                     ) -> tuple[np.ndarray, dict[str, Any], GravityEstimator | None]:
    """``resolve_gravity`` and, in auto mode, the estimator (to be refined as the map grows)."""
    data_config = data_config or DataInputConfig()
    cfg = cfg or data_config.gravity
    mode = cfg.mode or "auto"
    info: dict[str, Any] = {"mode": mode}
    estimator: GravityEstimator | None = None
    if mode == "z":
        transform = np.eye(4)
        info["note"] = "gravity z: the input's +z is taken as up"
        if cfg.check_z:  # trusted, but checked: a wrong --gravity z must not pass silently
            est = estimate_gravity(source, data_config, cfg)
            info["estimate"] = est.as_dict()
            if est.ok and est.angle_deg > cfg.warn_deg:
                info["note"] += f" (but its up is estimated {est.angle_deg:.1f} deg from +z, from the {est.method})"
                log.warning("gravity z: the input's +z is taken as up, but the depth says up is %.1f deg from it "
                            "(estimated from the %s): boxes, planes and supports will be tilted; --gravity auto "
                            "rotates the map", est.angle_deg, est.method)
    elif mode == "auto":
        estimator = gravity_estimator(source, data_config, cfg)
        est = estimator.estimate()
        transform, note = alignment_from_estimate(est, cfg)
        info["estimate"] = est.as_dict()
        info["note"] = note
        if not est.ok:
            log.warning("%s", note)
        elif est.angle_deg > cfg.warn_deg:
            log.warning("the input's up is %.1f deg from its +z (estimated from the %s): camera poses are rotated "
                        "into a gravity-aligned map frame (gravity_alignment in map.json)", est.angle_deg, est.method)
    else:
        transform = load_alignment(mode)
        info["mode"], info["file"] = "file", mode
        info["note"] = f"gravity from {mode}: map rotated by {rotation_angle_deg(transform):.1f} deg"
        up = up_of_alignment(transform)
        if angle_deg(up, np.array([0.0, 0.0, 1.0])) > cfg.warn_deg:
            log.warning("the input's up is %.1f deg from its +z (from %s): camera poses are rotated into a "
                        "gravity-aligned map frame", angle_deg(up, np.array([0.0, 0.0, 1.0])), mode)
    up = up_of_alignment(transform)
    info["applied"] = not np.allclose(transform, np.eye(4))
    info["rotation_deg"] = round(rotation_angle_deg(transform), 3)
    info["input_up"] = [round(float(v), 6) for v in up]
    return transform, info, estimator


def _refine_gravity(mapper: PanopticMapper, est: GravityEstimator, cfg: GravityConfig, added: int,
                    seconds: float) -> None:
    """The whole recording's estimate against the applied up, into ``mapper.gravity["refined"]``."""
    refined = est.estimate()
    out: dict[str, Any] = {"frames_added": added, "frames": refined.frames, "ok": refined.ok,
                           "seconds": round(seconds, 3)}
    if not refined.ok:
        out["reason"] = refined.reason
    else:
        applied = np.asarray(mapper.gravity.get("input_up", [0.0, 0.0, 1.0]), float)
        residual = angle_deg(refined.up, applied)
        transform = np.eye(4)
        transform[:3, :3] = rotation_to_z(refined.up)
        out.update({"method": refined.method, "up_in_input": [round(float(v), 6) for v in refined.up],
                    "residual_deg": round(residual, 3), "alignment": transform.tolist(),
                    "suggest_file": residual > cfg.refine_warn_deg})
        if residual > cfg.refine_warn_deg:
            log.warning("gravity: the estimate over the whole recording (%d frames) is %.1f deg from the up "
                        "applied (first %d frames): the map may be tilted; map again with --gravity "
                        "OUT/gravity_refined.txt", refined.frames, residual, refined.frames - added)
        else:
            log.info("gravity refined over %d frames: %.2f deg from the up applied", refined.frames, residual)
    mapper.gravity["refined"] = out


def _choose_origin(mapper: PanopticMapper, pose: np.ndarray, recentre_beyond_m: float) -> None:
    """Recentre a fresh map on the first pose when that pose is far from its frame's origin."""
    t = np.asarray(mapper.aligned_pose(pose), dtype=np.float64)[:3, 3]
    dist = float(np.linalg.norm(t))
    if dist > WARN_BEYOND_M:
        log.warning("the first camera pose is %.0f km from the map frame's origin: geodetic (UTM-like) coordinates "
                    "or a wrong unit? The map is recentred on it; origin_offset_m in map.json maps outputs back",
                    dist / 1000)
    if mapper.frames_integrated or np.any(mapper.origin_offset) or not (0 < recentre_beyond_m < dist):
        return
    mapper.recentre(np.round(t))  # whole metres: the local voxel grid stays aligned with the input frame's
    log.info("map recentred on the first pose: origin_offset_m = %s", mapper.origin_offset.tolist())


def _integrate_or_skip(mapper: PanopticMapper, frame: Any, masks: PanopticMasks | None, run: MappingRun,
                       geometry_only: bool = False, ahead: _SegmentAhead | None = None) -> Any:
    """`mapper.integrate` (`integrate_geometry` when `geometry_only`), with a failing frame logged and
    counted instead of ending the run; `ahead`: the frame's depth segmentation may have been computed ahead."""
    try:
        if geometry_only:
            return mapper.integrate_geometry(frame)
        segments = ahead.take(frame, mapper.fuses_labels(masks)) if ahead is not None else None
        return mapper.integrate(frame, masks, segments)
    except (MemoryError, KeyboardInterrupt):
        raise
    except Exception as exc:  # Open3D raises RuntimeError; a bad frame must not end a long recording
        msg = _ANSI.sub("", str(exc)).strip().splitlines()[0][:160] if str(exc).strip() else type(exc).__name__
        log.warning("frame %d (t=%.3f s) not integrated: %s", frame.index, frame.timestamp_ns * 1e-9, msg)
        run.failed_frames += 1
        run.failures[msg] = run.failures.get(msg, 0) + 1
        return None


#: Frames read ahead of the one being mapped whose depth segmentation may start early (`_SegmentAhead`):
#: with labels on every third frame, a label frame's segmentation runs while the one before is mapped.
SEGMENT_AHEAD = 3
_WORKER: SegmentationWorker | None = None


def segmentation_worker() -> SegmentationWorker:
    """The process-wide depth segmentation worker (started on first use, reused by later runs)."""
    global _WORKER
    if _WORKER is None:
        _WORKER = SegmentationWorker()
        atexit.register(_WORKER.close)
    return _WORKER


class _SegmentAhead:
    """Frames read `ahead` frames in advance; the depth segmentation of those that will fuse labels starts on
    the worker process while earlier frames are mapped (issue 26: two cores). The segmentation is a pure
    function of the frame, so the map is the same, bit for bit, as segmenting each frame when it is
    integrated; which frames fuse labels is guessed from the mapper's state (keyframe gating, the label
    cadence), and a frame guessed wrong is segmented on the mapper's thread as before."""

    def __init__(self, frames: Iterator[Any], mapper: PanopticMapper, ahead: int, worker: SegmentationWorker,
                 run: MappingRun):
        self.frames, self.mapper, self.ahead, self.worker, self.run = frames, mapper, ahead, worker, run
        self.buffer: collections.deque[tuple[Any, Any, Any]] = collections.deque()
        self.done = False

    def __iter__(self) -> _SegmentAhead:
        return self

    def __next__(self) -> Any:
        while not self.done and len(self.buffer) <= self.ahead:
            try:
                self.buffer.append((next(self.frames), None, None))
            except StopIteration:
                self.done = True
        if not self.buffer:
            raise StopIteration
        frame, fut, depth = self.buffer.popleft()
        self._current = (frame, fut, depth)
        return frame

    def start(self) -> None:
        """Before the current frame is integrated: start the frames read ahead that will fuse labels."""
        m = self.mapper
        key: tuple[Any, Any] | None = None  # the keyframes the frames before will have made
        for i, (frame, fut, depth) in enumerate(self.buffer):
            if frame.pose is None:
                continue
            keyframe = m.is_keyframe(frame, key)
            if keyframe:
                key = (frame.pose, frame.timestamp_ns)
            if fut is not None:
                continue
            if keyframe or m.propagates_labels(i + 1):
                depth, intr, area = m.label_depth(frame)
                self.buffer[i] = (frame, self.worker.submit(depth, intr, m.config.depth_segmentation, area), depth)

    def take(self, frame: Any, needed: bool) -> tuple[np.ndarray, np.ndarray] | None:
        """(depth, segment labels) of `frame` when it was segmented ahead and is `needed`, else None."""
        cur, fut, depth = self._current
        self._current = (None, None, None)
        if fut is None or cur is not frame:
            return None
        if not needed:  # left to finish on the worker (its CPU time is counted at the end)
            self.run.ahead_unused += 1
            return None
        try:
            labels, _cpu = fut.result()
        except Exception as exc:  # the worker failed: the mapper segments it itself
            log.debug("depth segmentation ahead failed (%s): segmented on the mapper's thread", exc)
            return None
        self.run.ahead_used += 1
        return depth, labels

    def close(self, cpu_before: float) -> None:
        """Wait for what is still running on the worker (the next run starts on an idle one); its CPU time."""
        self.worker.drain()
        self.run.ahead_cpu_s += self.worker.cpu_s - cpu_before


def segment_ahead(mapper: PanopticMapper, frame: Any) -> tuple[Any, np.ndarray, Any]:
    """Start the depth segmentation of `frame`, a label frame integrated later (a keyframe waiting for its
    masks), on the worker process; `ahead_segments` gives it to `mapper.integrate` (the mapper node)."""
    depth, intr, area = mapper.label_depth(frame)
    return segmentation_worker().submit(depth, intr, mapper.config.depth_segmentation, area), depth, mapper.config


def ahead_segments(ahead: tuple[Any, np.ndarray, Any] | None, mapper: PanopticMapper, needed: bool = True
                   ) -> tuple[np.ndarray, np.ndarray] | None:
    """`integrate`'s `depth_segments` from `segment_ahead` (waits for it); None when not `needed`, failed, or
    started for another map (one loaded since, with its own config)."""
    if ahead is None or not needed or ahead[2] is not mapper.config:
        return None
    fut, depth, _cfg = ahead
    try:
        labels, _cpu = fut.result()
    except Exception as exc:  # the worker failed: the mapper segments the frame itself
        log.debug("depth segmentation ahead failed (%s): segmented on the mapper's thread", exc)
        return None
    return depth, labels


def frames_to_read(available: int, data_config: DataInputConfig) -> int:
    """How many of ``available`` frames `--start`/`--stride`/`--max-frames` select (the progress total)."""
    n = len(range(max(data_config.start, 0), available, max(data_config.stride, 1)))
    return min(n, data_config.max_frames) if data_config.max_frames else n


def map_recording(
    source: str | Path,
    segmenter: Any,
    mapper_config: MapperConfig | None = None,
    data_config: DataInputConfig | None = None,
    progress: bool = True,
    mapper: PanopticMapper | None = None,
    recentre_beyond_m: float = RECENTRE_BEYOND_M,
    class_table: ClassTable | None = None,
    gravity: GravityConfig | None = None,
    checkpointer: Checkpointer | None = None,
    resume: Checkpoint | None = None,
    stop: Callable[[], bool] | None = None,
    segment_ahead: int | None = None,
) -> tuple[PanopticMapper, MappingRun]:
    """Integrate every posed frame of `source`; segment keyframes only (when gating is enabled).

    Without a segmenter (None, or the `none` backend, which never labels anything) every frame takes
    the mapper's geometry-only path: TSDF integration alone, no depth segmentation or label work.

    A frame the mapper fails on is logged, counted (`run.failed_frames`) and skipped. A recording
    whose first pose lies farther than `recentre_beyond_m` from the origin is mapped relative to that
    pose (`mapper.origin_offset`; 0 disables). Raises DatasetError, saying why and what to do, when
    no frame could be mapped. class_table: the table the segmenter's class ids come from (default
    config/classes.yaml). gravity (default ``data_config.gravity``): how the input's up is found; a
    fresh map is gravity aligned (``resolve_gravity``), a resumed one keeps its alignment.

    Fault tolerance: `checkpointer` writes a checkpoint whenever one is due (and when the run is
    stopped); `resume` (a checkpoint of this same recording) continues that run: its map, its
    counts, and the recording from the first frame it had not read. `stop()` is asked after every
    frame; when it says true the run checkpoints and returns early with `run.interrupted` set.
    """
    from tqdm import tqdm

    if segmenter is not None and getattr(segmenter, "name", None) == "none":
        segmenter = None  # returns no masks, ever: no label can be fused
    geometry_only = segmenter is None
    run = MappingRun()
    skip = 0
    if resume is not None:
        mapper = resume.mapper
        run.restore(resume.progress, resume.arrays)
        run.resumed_generation = resume.generation
        skip = run.frames_read
    mapper = mapper or PanopticMapper(mapper_config, class_metas(class_table))
    if checkpointer is not None:
        checkpointer.start(mapper.frames_integrated)
    t_start = time.perf_counter()
    data_config = data_config or DataInputConfig()
    gcfg = gravity or data_config.gravity
    refiner: GravityEstimator | None = None
    if not mapper.frames_integrated and not mapper.gravity:
        transform, info, refiner = _resolve_gravity(source, data_config, gcfg)
        mapper.set_alignment(transform, info)
        log.info("%s", info["note"])
    refine_n = gcfg.refine_every_n if refiner is not None else 0
    window_reads = gcfg.window_frames * gcfg.stride  # frames the window already covered
    refine_added, refine_s = 0, 0.0
    last_stamp: int | None = (resume.progress.get("last_timestamp_ns") if resume is not None else None)

    def checkpoint() -> None:
        if checkpointer is None or not checkpointer.config.enabled:
            return
        arrays = {"poses": np.asarray(run.poses, np.float64).reshape(-1, 4, 4)}
        checkpointer.save(mapper, run.progress(source, last_stamp), arrays)
        run.checkpoints += 1
        run.checkpoint_s += checkpointer.last_cost_s

    with open_dataset(source, data_config) as loader:
        total = frames_to_read(len(loader), data_config) if hasattr(loader, "__len__") else None
        frames: Iterator[Any] = iter(loader)
        n_ahead = SEGMENT_AHEAD if segment_ahead is None else segment_ahead
        ahead = None
        if not geometry_only and n_ahead > 0:
            frames = ahead = _SegmentAhead(frames, mapper, n_ahead, segmentation_worker(), run)
            worker_cpu = ahead.worker.cpu_s
        bar = tqdm(total=total, desc="mapping", unit="frame", disable=not progress)
        read = 0
        while True:
            if stop is not None and stop():
                run.interrupted = True
                break
            t0 = time.perf_counter()
            try:
                frame = next(frames)
            except StopIteration:
                break
            read += 1
            if read <= skip:  # consumed by the run this one resumes
                bar.update(1)
                if read == skip and last_stamp is not None and frame.timestamp_ns != last_stamp:
                    log.warning("frame %d of %s is not the one the checkpoint stopped after (t=%.3f s, not "
                                "%.3f s): is this the same recording?", read, source, frame.timestamp_ns * 1e-9,
                                last_stamp * 1e-9)
                continue
            run.frames_read = read
            last_stamp = frame.timestamp_ns
            run.read_s += time.perf_counter() - t0
            if frame.pose is None:  # require_pose=False loaders: nothing to integrate
                continue
            if not run.frames and not run.failed_frames:
                _choose_origin(mapper, frame.pose, recentre_beyond_m)
            if mapper.is_static(frame):
                run.static_frames += 1
                bar.update(1)
                continue
            masks = None
            if geometry_only:
                if mapper.is_keyframe(frame):  # counted only (reported as keyframes)
                    mapper.mark_keyframe(frame)
            elif mapper.is_keyframe(frame):
                mapper.mark_keyframe(frame)
                t1 = time.perf_counter()
                seg = segmenter.segment_frame(frame)
                run.segmentation_s += time.perf_counter() - t1
                run.segmentation_calls += 1
                masks = masks_from_segmentation(seg)
            if ahead is not None:
                ahead.start()
            t2 = time.perf_counter()
            stats = _integrate_or_skip(mapper, frame, masks, run, geometry_only, ahead)
            run.mapper_s += time.perf_counter() - t2
            bar.update(1)
            if stats is None:
                continue
            for k, v in stats.timings_ms.items():
                run.stage_ms[k] = run.stage_ms.get(k, 0.0) + v
                run.stage_frames[k] = run.stage_frames.get(k, 0) + 1
            run.frames += 1
            run.poses.append(mapper.local_pose(frame.pose))
            if refiner is not None and refine_n and read > window_reads and run.frames % refine_n == 0:
                t3 = time.perf_counter()
                refiner.add_frame(frame.depth, frame.intrinsics, frame.pose)
                refine_added += 1
                refine_s += time.perf_counter() - t3
            log.debug("frame %d of the recording integrated", read)
            if checkpointer is not None and checkpointer.due(mapper.frames_integrated):
                checkpoint()
        bar.close()
        if ahead is not None:
            ahead.close(worker_cpu)
        if run.interrupted:
            checkpoint()
        elif read < skip:
            log.warning("%s has %d frames, the checkpoint had read %d: a different recording?", source, read, skip)
        run.skipped = {k: v for k, v in loader.skips.as_dict().items() if v}
        if run.failed_frames:
            run.skipped["mapper_failed"] = run.failed_frames
        run.truncated = bool(getattr(loader, "truncated", False))
        if not run.frames and not run.interrupted:
            if run.failed_frames:
                first = max(run.failures.items(), key=lambda kv: kv[1])[0]
                raise MappingFailed(f"{source}: all {run.failed_frames} frames failed in the mapper "
                                    f"(most often: {first}); run with -v for each frame's error")
            raise DatasetError(explain_empty(loader, source))
    if refiner is not None and refine_added:
        _refine_gravity(mapper, refiner, gcfg, refine_added, refine_s)
    run.origin_offset_m = [float(v) for v in mapper.origin_offset]
    run.keyframes = mapper.keyframes
    run.wall_s = time.perf_counter() - t_start
    return mapper, run


def write_map_outputs(out: str | Path, mapper: PanopticMapper, run: MappingRun,
                      extra: dict[str, Any] | None = None) -> tuple[list[Entity], dict[str, Any]]:
    """entities.json + meshes, map.npz/map.json (resumable), summary.json (pictures: the tool layer)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    ents = mapper.entities()
    extract_s = time.perf_counter() - t0
    save_entities(ents, out)
    mapper.save(out)
    refined = mapper.gravity.get("refined", {})
    suggestion = out / "gravity_refined.txt"
    if refined.get("suggest_file"):
        np.savetxt(suggestion, np.asarray(refined["alignment"]), fmt="%.9f",
                   header=f"input world -> z up, estimated over {refined['frames']} frames "
                          f"({refined['residual_deg']:.2f} deg from the alignment this map used)")
    elif suggestion.exists():
        suggestion.unlink()  # from an earlier run into the same folder: not this map's
    per_class: dict[str, int] = {}
    for e in ents:
        per_class[e.class_name] = per_class.get(e.class_name, 0) + 1
    summary = {
        "run": run.summary(), "mode": mapper.config.mode, "entities": len(ents),
        "panoptic_entities": sum(1 for e in ents if e.class_id != BACKGROUND),
        "origin_offset_m": [float(v) for v in mapper.origin_offset],
        "gravity": mapper.gravity, "gravity_alignment": mapper.alignment.tolist(),
        "depth_range_m": [mapper.config.tsdf.min_depth_m, mapper.config.tsdf.max_depth_m],
        "entities_per_class": dict(sorted(per_class.items())), "extract_s": round(extract_s, 3),
        "map_blocks": mapper.tsdf.num_blocks, "map_memory_mb": round(mapper.tsdf.memory_bytes() / 2**20, 1),
        "global_segments": mapper.counts.next_label - 1, **(extra or {}),
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=1), encoding="utf-8")
    return ents, summary
