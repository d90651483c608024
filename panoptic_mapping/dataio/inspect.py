"""What a bag or frame folder holds: topics, counts, rates, resolution, duration, pose coverage, and
how many frames would be mapped, with the reasons the others would be skipped."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from panoptic_mapping.dataio.bag import IMAGE_TYPE, INFO_TYPE, RosbagLoader
from panoptic_mapping.dataio.config import DataInputConfig
from panoptic_mapping.dataio.diagnose import explain_empty, pose_hint
from panoptic_mapping.dataio.folders import _read_image
from panoptic_mapping.dataio.registry import detect_format, open_dataset
from panoptic_mapping.dataio.transforms import TransformLookupError
from recon_core.frame import DatasetError


def _rate(times_ns: list[int]) -> float:
    if len(times_ns) < 2:
        return 0.0
    span = (max(times_ns) - min(times_ns)) * 1e-9
    return (len(times_ns) - 1) / span if span > 0 else 0.0


def inspect_dataset(path: str | Path, config: DataInputConfig | None = None, quick: bool = False) -> dict[str, Any]:
    """Summary of `path` as plain data (printed by `scene-recon inspect`, `--json` for machines).

    Every frame is decoded once (as `scene-recon map` would read it) to count the frames that would
    be mapped and why the others would not; `quick` only pairs and poses them (bags) or lists them
    (folders).
    """
    config = config or DataInputConfig()
    fmt = detect_format(path)
    if fmt == "rosbag2":
        return _inspect_bag(Path(path), config, quick)
    return _inspect_folder(Path(path), config, fmt, quick)


def _full_pass(loader: Any) -> int:
    """Iterate `loader` (pose not required), return the frames that have a pose; skip counters fill up."""
    usable = 0
    for frame in loader:
        usable += frame.pose is not None
    return usable


def _reasons(loader: Any) -> dict[str, int]:
    return dict(loader.skips.reasons.most_common(10))


def _inspect_bag(path: Path, config: DataInputConfig, quick: bool) -> dict[str, Any]:
    # Topic selection may fail (e.g. no depth): still report the topics, then the error.
    try:
        loader = RosbagLoader(path, config)
    except DatasetError as exc:
        from rosbags.highlevel import AnyReader

        try:
            with AnyReader([path]) as reader:
                topics = [{"topic": c.topic, "type": c.msgtype, "count": c.msgcount} for c in reader.connections]
        except Exception:
            raise exc from None
        return {"path": str(path), "format": "rosbag2", "topics": topics, "error": str(exc)}
    with loader:
        reader = loader._reader
        log_times: dict[str, list[int]] = {c.topic: [] for c in reader.connections}
        first: dict[str, Any] = {}
        try:
            for conn, t, raw in reader.messages():
                log_times[conn.topic].append(t)
                if conn.topic not in first and conn.msgtype in (IMAGE_TYPE, INFO_TYPE):
                    first[conn.topic] = reader.deserialize(raw, conn.msgtype)
        except Exception as exc:  # count what comes before the damage
            loader._mark_truncated(f"breaks off ({exc})")
        topics = []
        for c in sorted(reader.connections, key=lambda c: c.topic):
            entry: dict[str, Any] = {
                "topic": c.topic, "type": c.msgtype, "count": len(log_times[c.topic]),
                "rate_hz": round(_rate(log_times[c.topic]), 3),
            }
            msg = first.get(c.topic)
            if msg is not None:
                entry["width"], entry["height"] = int(msg.width), int(msg.height)
                if c.msgtype == IMAGE_TYPE:
                    entry["encoding"] = msg.encoding
            role = next((r for r, t in loader.topics.items() if t == c.topic), None)
            if role:
                entry["role"] = role
            topics.append(entry)
        camera_frame = config.camera_frame or (first[loader.topics["color"]].header.frame_id
                                               if loader.topics["color"] in first else "")
        if quick:
            stamps = [stamp for stamp, _c, _d, _l in loader.iter_pairs()]
            pairs, posed = len(stamps), 0
            for stamp in stamps:
                try:
                    loader.pose_at(camera_frame, stamp)
                    posed += 1
                except TransformLookupError:
                    loader.skips.no_pose += 1
            usable = posed
        else:
            loader.config = dataclasses.replace(config, require_pose=False, start=0, stride=1, max_frames=0)
            usable = _full_pass(loader)
            pairs = loader.pairs
            posed = pairs - loader.skips.no_pose
        starts = [min(v) for v in log_times.values() if v]
        ends = [max(v) for v in log_times.values() if v]
        color = first.get(loader.topics["color"])
        depth = first.get(loader.topics["depth"])
        info: dict[str, Any] = {
            "path": str(path),
            "format": "rosbag2",
            "storage": "mcap" if path.suffix == ".mcap" or (path.is_dir() and any(path.glob("*.mcap"))) else "sqlite3",
            "duration_s": round((max(ends) - min(starts)) * 1e-9, 3) if starts else 0.0,
            "start_time_s": round(min(starts) * 1e-9, 6) if starts else 0.0,
            "messages": sum(len(v) for v in log_times.values()),
            "topics": topics,
            "selected_topics": {k: v for k, v in loader.topics.items() if v},
            "resolution": [int(color.width), int(color.height)] if color is not None else None,
            "frames": pairs,
            "frame_rate_hz": round(pairs / max((max(ends) - min(starts)) * 1e-9, 1e-9), 3) if pairs > 1 else 0.0,
            "camera_frame": camera_frame,
            "map_frame": config.map_frame,
            "tf_frames": sorted(loader.tf.frames),
            "tf_roots": loader.tf.roots(),
            "posed_frames": posed,
            "pose_coverage": round(posed / pairs, 4) if pairs else 0.0,
            "usable_frames": usable,
            "checked": "pairing and poses only" if quick else "every frame decoded",
            "skipped": loader.skips.as_dict(),
            "skip_reasons": _reasons(loader),
            "truncated": loader.truncated,
        }
        if depth is not None and color is not None and (depth.width, depth.height) != (color.width, color.height):
            info["depth_resolution"] = [int(depth.width), int(depth.height)]
            info["resampled_frames"] = loader.resampled_frames
        if loader.truncated:
            info["damage"] = list(loader.damage)
        if posed < pairs:
            info["pose_hint"] = loader.pose_hint(camera_frame)
        if not usable:
            info["why_no_frames"] = explain_empty(loader)
        return info


#: Median depths of an indoor RGB-D view (m) outside which the folder's depth unit is probably wrong.
PLAUSIBLE_MEDIAN_DEPTH_M = (0.25, 8.0)


def _depth_unit_check(raw: np.ndarray, units_per_m: float) -> dict[str, Any]:
    """The first frame's median valid depth in metres, and a warning when it is implausible for an indoor
    camera: a folder in millimetres read at TUM's 5000 units/m puts the scene 5x too close without a
    word (a real TUM-layout desk recording, docs/REAL_DATA_TUM.md)."""
    valid = raw[np.isfinite(raw) & (raw > 0)] if raw.dtype.kind == "f" else raw[raw > 0]
    if valid.size == 0 or units_per_m <= 0:
        return {}
    median_m = float(np.median(valid)) / units_per_m
    out: dict[str, Any] = {"depth_median_m": round(median_m, 3)}
    lo, hi = PLAUSIBLE_MEDIAN_DEPTH_M
    if not lo <= median_m <= hi:
        guesses = [u for u in (1000.0, 5000.0, 10000.0) if u != units_per_m
                   and lo <= float(np.median(valid)) / u <= hi]
        out["depth_warning"] = (f"median depth of the first frame is {median_m:.2f} m at {units_per_m:g} depth units "
                                f"per metre, implausible for an indoor camera"
                                + (f": if the depth images are in other units, give --depth-scale {guesses[0]:g}"
                                   if guesses else ""))
    return out


def _inspect_folder(path: Path, config: DataInputConfig, fmt: str, quick: bool) -> dict[str, Any]:
    loader = open_dataset(path, config)
    entries = loader.entries
    stamps = np.array([e[0] for e in entries], dtype=np.int64)
    posed = sum(1 for e in entries if e[3] is not None)
    first = _read_image(entries[0][1], depth=False) if entries else None
    first_depth = _read_image(entries[0][2], depth=True) if entries else None
    duration = (stamps[-1] - stamps[0]) * 1e-9 if len(stamps) > 1 else 0.0
    if quick:
        usable = posed
        loader.skips.no_pose = len(entries) - posed
    else:
        loader.config = dataclasses.replace(config, require_pose=False, start=0, stride=1, max_frames=0)
        usable = _full_pass(loader)
    info: dict[str, Any] = {
        "path": str(path),
        "format": fmt,
        "frames": len(entries),
        "resolution": [int(first.shape[1]), int(first.shape[0])] if first is not None else None,
        "duration_s": round(float(duration), 3),
        "frame_rate_hz": round((len(stamps) - 1) / duration, 3) if duration > 0 else 0.0,
        "intrinsics": list(loader._k),
        "intrinsics_source": loader.intrinsics_source,
        "depth_scale": loader.depth_scale,
        "posed_frames": posed,
        "pose_coverage": round(posed / len(entries), 4) if entries else 0.0,
        "usable_frames": usable,
        "checked": "listing only" if quick else "every frame decoded",
        "skipped": loader.skips.as_dict(),
        "skip_reasons": _reasons(loader),
    }
    if loader._k_depth is not None:
        info["depth_intrinsics"] = list(loader._k_depth)
    if first_depth is not None:
        info.update(_depth_unit_check(first_depth, float(loader.depth_scale)))
    if first_depth is not None and first is not None and first_depth.shape[:2] != first.shape[:2]:
        info["depth_resolution"] = [int(first_depth.shape[1]), int(first_depth.shape[0])]
        info["resampled_frames"] = loader.resampled_frames
    if posed < len(entries):
        info["pose_hint"] = pose_hint(loader)
    if not usable:
        info["why_no_frames"] = explain_empty(loader)
    return info
