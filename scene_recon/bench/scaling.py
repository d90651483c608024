"""Skip and scaling measurements of the full suite: an empty room, a static camera, the per-frame cost
over a long sequence (flat as the map grows?), end-to-end time against object count.

Extra scenes are generated once into the suite cache (``$SCENE_RECON_CACHE/suite/extra-*``), like the
named suite scenes, and reused while their definition is unchanged.
"""

from __future__ import annotations

import itertools
import os
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from scene_recon.bench.pipeline import RunSpec

#: Generation definitions of the extra scenes: (objects, frames, seed).
EMPTY = (0, 60, 707)
OBJECT_COUNTS = (5, 20, 40, 80)
COUNT_FRAMES = 60


def extra_scene(name: str, objects: int, frames: int, seed: int) -> tuple[Path, Path]:
    """(bag, ground truth) of a generated scene cached under the suite cache."""
    from scene_recon.synthetic.generate import GenerateConfig, generate_recording, ground_truth_path
    from scene_recon.synthetic.suite import cache_root

    bag = cache_root() / f"extra-{name}-o{objects}-f{frames}-s{seed}" / name
    gt = ground_truth_path(bag)
    if not (gt / "generation.json").is_file():
        generate_recording(bag, GenerateConfig(objects=objects, frames=frames, seed=seed), progress=False)
    return bag, gt


def _frames_of(bag: Path, max_frames: int = 0) -> list[Any]:
    """The frames of a recording (with its ground-truth labels), read into memory."""
    from panoptic_mapping.dataio import DataInputConfig
    from panoptic_mapping.dataio.registry import open_dataset
    from recon_core.config import CONFIG_DIR, load_config

    data = load_config(DataInputConfig, CONFIG_DIR / "data.yaml",
                       {"topics.labels": "/ground_truth/panoptic_labels", "max_frames": max_frames})
    with open_dataset(bag, data) as loader:
        return list(loader)


def _balanced(label: str, **kw: Any) -> RunSpec:
    from recon_core.config import load_preset

    return RunSpec(label, preset=load_preset("balanced"), **kw)


def empty_room(runner: Any) -> dict[str, Any]:
    bag, gt = extra_scene("empty", *EMPTY)
    return runner.run_on("extra-empty", bag, gt, _balanced("empty room"))


def _frame_times(bag: Path, gt: Path, frames: list[Any] | None = None, max_frames: int = 0,
                 preset_name: str | None = "balanced") -> dict[str, Any]:
    """Map a recording (or a list of frames: a stream given in memory) with a preset's mapper (None: the
    config files' defaults) and the oracle; per-frame wall time (reading excluded for lists) and map
    memory after each frame."""
    from panoptic_mapping.config import MapperConfig
    from panoptic_mapping.mapper import PanopticMapper
    from panoptic_mapping.pipeline import masks_from_segmentation
    from panoptic_mapping.segmentation.config import SegmentationConfig
    from panoptic_mapping.segmentation.factory import make_segmenter
    from recon_core.config import CONFIG_DIR, load_config, load_preset, preset_overrides

    preset = load_preset(preset_name)
    cfg = load_config(MapperConfig, CONFIG_DIR / "mapper.yaml",
                      preset_overrides(preset, "mapper", {"checkpoint.enabled": False}))
    seg_cfg = SegmentationConfig(backend="oracle")
    seg_cfg.oracle.ground_truth, seg_cfg.oracle.level, seg_cfg.oracle.seed = str(gt), "default", 0
    segmenter = make_segmenter(seg_cfg)
    if frames is None:
        from panoptic_mapping.dataio import DataInputConfig
        from panoptic_mapping.pipeline import map_recording

        marks: list[float] = []
        cpu_marks: list[float] = []
        mems: list[float] = []
        state: list[tuple[int, int]] = []  # (keyframes, frames integrated) before each frame
        mapper = PanopticMapper(cfg)

        def stop() -> bool:  # called before every frame: the time between two calls is one frame's cost
            marks.append(time.perf_counter())
            cpu_marks.append(time.process_time())
            mems.append(mapper.tsdf.memory_bytes() / 1e6)
            state.append((mapper.keyframes, mapper.frames_integrated))
            return False

        data = load_config(DataInputConfig, CONFIG_DIR / "data.yaml",
                           preset_overrides(preset, "data", {"topics.labels": "/ground_truth/panoptic_labels",
                                                             "max_frames": max_frames}))
        _, run = map_recording(bag, segmenter, cfg, data, progress=False, mapper=mapper, stop=stop)
        ms = list(np.diff(marks) * 1000.0)
        n_label = cfg.keyframes.label_every_n_frames
        # frame i fused labels: it was a keyframe (segmented) or a label-propagation frame (see fuses_labels)
        label = [bool(k1 > k0 or (n_label > 0 and f0 % n_label == 0))
                 for (k0, f0), (k1, _) in itertools.pairwise(state)]
        return {"frame_ms": ms, "frame_cpu_ms": list(np.diff(cpu_marks) * 1000.0), "label_frame": label,
                "memory_mb": mems[1:], "segmentation_calls": run.segmentation_calls, "frames": run.frames}
    mapper = PanopticMapper(cfg)
    ms, cpu_ms, mems, calls = [], [], [], 0
    for frame in frames:
        t0, c0 = time.perf_counter(), time.process_time()
        masks = None
        static = mapper.is_static(frame)  # as map_recording does: a still camera's frame is skipped whole
        if not static and mapper.is_keyframe(frame):
            mapper.mark_keyframe(frame)
            masks = masks_from_segmentation(segmenter.segment_frame(frame))
            calls += 1
        if not static:
            mapper.integrate(frame, masks)
        ms.append((time.perf_counter() - t0) * 1000.0)
        cpu_ms.append((time.process_time() - c0) * 1000.0)
        mems.append(mapper.tsdf.memory_bytes() / 1e6)
    return {"frame_ms": ms, "frame_cpu_ms": cpu_ms, "memory_mb": mems, "segmentation_calls": calls,
            "frames": len(frames)}


def static_camera(runner: Any, n: int = 60) -> dict[str, Any]:
    """The first `n` frames of bench-small against its first frame repeated `n` times (same stamps)."""
    from panoptic_mapping.dataio import DataInputConfig
    from panoptic_mapping.dataio.registry import open_dataset
    from recon_core.config import CONFIG_DIR, load_config
    from scene_recon.synthetic.suite import suite_scene

    bag, gt = suite_scene("bench-small", progress=False)
    runner.progress("         static camera vs moving camera ...")
    data = load_config(DataInputConfig, CONFIG_DIR / "data.yaml", {"topics.labels": "/ground_truth/panoptic_labels"})
    with open_dataset(bag, data) as loader:
        moving = []
        for f in loader:
            moving.append(f)
            if len(moving) >= n:
                break
    static = [replace(moving[0], timestamp_ns=f.timestamp_ns) for f in moving]
    lines, data = [], {}
    for preset in (None, "balanced"):
        name = preset or "defaults (keyframe gating on)"
        mv, st = _frame_times(bag, gt, moving, preset_name=preset), _frame_times(bag, gt, static, preset_name=preset)
        mv_ms, st_ms = float(np.mean(mv["frame_ms"])), float(np.mean(st["frame_ms"]))
        mv_cpu, st_cpu = float(np.mean(mv["frame_cpu_ms"])), float(np.mean(st["frame_cpu_ms"]))
        lines += [f"{name}, moving camera: {mv_ms:.1f} ms/frame ({mv_cpu:.1f} ms CPU), {mv['segmentation_calls']} "
                  f"segmentation calls, map {mv['memory_mb'][-1]:.1f} MB",
                  f"{name}, static camera: {st_ms:.1f} ms/frame ({st_cpu:.1f} ms CPU, {st_cpu / mv_cpu:.2f}x), "
                  f"{st['segmentation_calls']} segmentation calls, map {st['memory_mb'][-1]:.1f} MB"]
        data[name] = {"moving_ms": mv_ms, "static_ms": st_ms, "moving_cpu_ms": mv_cpu, "static_cpu_ms": st_cpu,
                      "moving_segmentation_calls": mv["segmentation_calls"],
                      "static_segmentation_calls": st["segmentation_calls"]}
    return {"text": f"{n} frames of bench-small against its first frame repeated {n} times (a camera standing "
                    "still), with the defaults (keyframe gating: only keyframes are segmented) and with the "
                    "balanced preset (which segments every frame it reads).", "lines": lines, **data}


def _smooth(x: np.ndarray, n: int = 50) -> list[float]:
    if len(x) < n:
        return [round(float(v), 2) for v in x]
    padded = np.pad(np.asarray(x, float), (n // 2, n - 1 - n // 2), mode="edge")  # no zero-padded ends
    c = np.convolve(padded, np.ones(n) / n, mode="valid")
    return [round(float(v), 2) for v in c]


def per_frame_cost(runner: Any, frames: int) -> dict[str, Any]:
    """Per-frame time and map memory over a long recording of one room (the camera walks one loop).

    The figure of merit is the per-frame CPU time of this process (all its threads): on a shared machine
    the wall time of a frame also holds the time other processes took the core (it moved the ratio from
    0.77 to 1.73 between two runs of the same frames), the CPU time does not. Both are reported, with the
    share of label-fusing frames (keyframes and label propagation: ~8x the cost of a geometry-only frame)
    in each window, since the mix, not the map, is what differs between two windows of a recording."""
    runner.progress(f"         long sequence: {frames} frames (generated once, then cached) ...")
    bag, gt = extra_scene("long", 12, frames, 808)
    load0 = [round(x, 2) for x in os.getloadavg()]
    res = _frame_times(bag, gt, preset_name=None)  # every frame read (no stride), keyframe gating as by default
    load1 = [round(x, 2) for x in os.getloadavg()]
    ms, cpu = np.asarray(res["frame_ms"]), np.asarray(res["frame_cpu_ms"])
    label = np.asarray(res["label_frame"], bool)
    k = min(500, len(ms) // 2)
    first, last = slice(0, k), slice(len(ms) - k, len(ms))

    def by_kind(window: slice) -> tuple[float, float, int]:
        c, lab = cpu[window], label[window]
        return (float(c[lab].mean()) if lab.any() else 0.0, float(c[~lab].mean()) if (~lab).any() else 0.0,
                int(lab.sum()))

    ratio_cpu = float(cpu[last].mean() / cpu[first].mean())
    ratio_wall = float(ms[last].mean() / ms[first].mean())
    lab_f, geo_f, n_lab_f = by_kind(first)
    lab_l, geo_l, n_lab_l = by_kind(last)
    within = "within" if abs(ratio_cpu - 1) <= 0.2 else "NOT within"
    lines = [f"{res['frames']} frames, CPU time per frame: first {k} {cpu[first].mean():.1f} ms, last {k} "
             f"{cpu[last].mean():.1f} ms: ratio {ratio_cpu:.2f} ({within} 20 %)",
             f"wall time per frame: first {k} {ms[first].mean():.1f} ms, last {k} {ms[last].mean():.1f} ms: ratio "
             f"{ratio_wall:.2f} (load average {load0} before, {load1} after: wall time includes other processes' "
             "share of the cores)",
             f"label-fusing frames (keyframes + label propagation): {n_lab_f} of the first {k} at {lab_f:.1f} ms CPU, "
             f"{n_lab_l} of the last {k} at {lab_l:.1f} ms ({lab_l / max(lab_f, 1e-9):.2f}x); geometry-only frames "
             f"{geo_f:.1f} vs {geo_l:.1f} ms ({geo_l / max(geo_f, 1e-9):.2f}x)",
             f"first 50 frames (warm-up, nothing excluded above): {cpu[:50].mean():.1f} ms CPU per frame",
             f"map memory {res['memory_mb'][k - 1]:.1f} MB after {k} frames, {res['memory_mb'][-1]:.1f} MB at the end; "
             f"{res['segmentation_calls']} segmentation calls"]
    return {"text": "Config defaults (every frame read, keyframes segmented), oracle segmentation included, on a "
                    f"{frames}-frame recording of one 12-object room (the camera walks one loop, so the last frames "
                    "revisit what the first saw while the map holds the whole room). Per-frame cost = CPU seconds of "
                    "the process per frame (see the wall-time line for why); no frame is excluded.",
            "lines": lines, "frame_index": list(range(len(ms))), "frame_ms": [round(float(x), 2) for x in ms],
            "frame_cpu_ms": [round(float(x), 2) for x in cpu], "frame_ms_smooth": _smooth(ms),
            "frame_cpu_ms_smooth": _smooth(cpu), "label_frame": [bool(x) for x in label],
            "memory_mb": [round(float(x), 2) for x in res["memory_mb"]], "first_cpu_ms": float(cpu[first].mean()),
            "last_cpu_ms": float(cpu[last].mean()), "ratio_last_first_cpu": ratio_cpu,
            "first_ms": float(ms[first].mean()), "last_ms": float(ms[last].mean()), "ratio_last_first": ratio_wall,
            "label_frames_first_last": [n_lab_f, n_lab_l], "label_frame_cpu_ms_first_last": [lab_f, lab_l],
            "geometry_frame_cpu_ms_first_last": [geo_f, geo_l], "load_avg_before_after": [load0, load1],
            "frames": res["frames"], "segmentation_calls": res["segmentation_calls"]}


def object_count_scaling(runner: Any) -> dict[str, Any]:
    rows = []
    for count in OBJECT_COUNTS:
        runner.progress(f"         {count} objects ({COUNT_FRAMES} frames) ...")
        bag, gt = extra_scene("objects", count, COUNT_FRAMES, 900 + count)
        rows.append(runner.run_on(f"extra-objects-{count}", bag, gt, _balanced(f"{count} objects", physics=False)))
    total = [r["times_s"]["total"] for r in rows]
    lines = [f"{c} objects: {r['times_s']['total']:.1f} s end to end (map {r['times_s']['map']:.1f}, graph "
             f"{r['times_s']['graph']:.2f}, replace {r['times_s']['replace']:.1f}; {r['cad_objects']} CAD objects)"
             for c, r in zip(OBJECT_COUNTS, rows, strict=True)]
    return {"text": f"Balanced preset on generated rooms of {COUNT_FRAMES} frames with 5-80 objects (physics "
                    "check off).", "rows": rows, "lines": lines, "objects": list(OBJECT_COUNTS), "total_s": total,
            "map_s": [r["times_s"]["map"] for r in rows], "replace_s": [r["times_s"]["replace"] for r in rows]}
