"""The named suites of `scene-recon benchmark`: what runs, with progress, into one report folder.

quick (< 3 min on a 2-core machine; CI runs it): `bench-small` end to end with each preset, the
  paper's CAD method and the baseline mapper on the balanced preset; time against accuracy with
  its Pareto front, and the unchanged-scene skip (zero CAD work on an unchanged graph).
full (< 30 min): the presets on every suite scene; one-knob sweeps per stage (voxel size, frame
  stride, keyframe gating, label propagation, image downscale, depth-segmentation resolution,
  RANSAC iterations, CAD top-k and LM evaluations, CAD method) with per-stage and end-to-end Pareto
  plots; perturbation curves (segmentation noise, depth noise, pose drift, CAD scale); skip
  measurements (empty room, static camera, unchanged scene); scaling (per-frame time and map memory
  over a long sequence, end-to-end time against object count, segmentation latency on onnxruntime,
  a computed projection to a multi-room building and to nodes on several hosts over DDS).

Runs that differ only in a later stage reuse the map (and graph) of an earlier run with the same
settings (`pipeline.StageCache`; the row says `shared`), and bench-small's sweeps and curves run right
after its presets, so its balanced map is computed once. Every section records its own wall and CPU
seconds (`cost_s`), the suite its total wall and CPU time (this process and its children) and the
load average before and after.
"""

from __future__ import annotations

import os
import platform
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from recon_core.config import load_preset
from scene_recon.bench.pipeline import RunSpec, StageCache, accuracy_score, pareto_front, run_pipeline
from scene_recon.bench.report import plot_pareto, plot_series, write_report

PRESETS = ("fast", "balanced", "accurate")
SUITES = ("quick", "full")
#: The scene whose balanced run's map and scene give the message sizes of the DDS projection (one room).
PROJECTION_SCENE = "bench-kitchen"

#: One-knob sweeps of the full suite: (stage, section, dotted key, values); the balanced preset is the base
#: (the config defaults for the keyframe knobs: balanced turns keyframe gating off).
SWEEPS: list[tuple[str, str, str, list[Any]]] = [
    ("mapping", "mapper", "tsdf.voxel_size_m", [0.015, 0.02, 0.03, 0.04]),
    ("mapping", "data", "stride", [1, 2, 3]),
    ("mapping", "mapper", "keyframes.min_translation_m", [0.05, 0.15, 0.4]),
    ("mapping", "mapper", "keyframes.label_every_n_frames", [0, 1, 3]),
    ("mapping", "mapper", "downsample", [1, 2]),
    ("mapping", "mapper", "depth_segmentation.normal_step", [1, 2, 4]),
    ("graph", "scene_graph", "planes.ransac_iterations", [50, 200, 800]),
    ("cad", "cad", "top_k", [3, 6, 20]),
    ("cad", "cad", "align_max_nfev", [10, 30, 60]),
]

Progress = Callable[[str], None]


def machine() -> dict[str, Any]:
    return {"python": platform.python_version(), "machine": platform.machine(), "cpus": os.cpu_count(),
            "load_avg": [round(x, 2) for x in os.getloadavg()]}


class SuiteRunner:
    """Runs configurations with progress lines, keeps every row, shares one CAD library."""

    def __init__(self, out: Path, progress: Progress = print) -> None:
        from cad_replacement.cad.library import CadLibrary

        self.out = out
        self.work = out / "work"
        self.progress = progress
        self.library = CadLibrary(seeds_per_class=10)
        self.rows: list[dict[str, Any]] = []
        self.cache = StageCache()
        self.kept: list[Path] = []
        self.t0 = time.perf_counter()

    def timed(self, build: Callable[[], list[dict[str, Any]]]) -> list[dict[str, Any]]:
        """Sections built by `build`, each given the wall and CPU seconds the call took (`cost_s`; one
        call building several sections: shared among them, listed on the first)."""
        c0, t0 = time.process_time(), time.perf_counter()
        sections = build()
        if sections:
            sections[0]["cost_s"] = {"wall": round(time.perf_counter() - t0, 1),
                                     "cpu": round(time.process_time() - c0, 1),
                                     "sections": len(sections)}
        return sections

    def run(self, scene: str, spec: RunSpec, keep: bool = True, keep_files: bool = False) -> dict[str, Any]:
        from scene_recon.synthetic.suite import suite_scene

        bag, gt = suite_scene(scene, progress=False)
        return self.run_on(scene, bag, gt, spec, keep, keep_files=keep_files)

    def run_on(self, scene: str, bag: Path, gt: Path, spec: RunSpec, keep: bool = True, library: Any = None,
               keep_files: bool = False) -> dict[str, Any]:
        self.progress(f"[{time.perf_counter() - self.t0:6.0f} s] {scene}: {spec.label} ...")
        folder = self.work / scene / spec.label.replace("/", "_").replace(" ", "_")
        row = run_pipeline(bag, gt, folder, spec, library or self.library, cache=self.cache)
        if keep_files:  # map/ and scene/ stay until the suite ends (the message sizes read them)
            row["folder"] = str(folder)
            self.kept.append(folder)
        else:
            shutil.rmtree(folder, ignore_errors=True)  # keep the report folder small
        row["scene"] = scene
        t = row["times_s"]
        self.progress(f"         total {t['total']:.1f} s{' (' + row['shared'] + ' shared)' if row['shared'] else ''} "
                      f"(map {t['map']:.1f}, graph {t['graph']:.2f}, replace "
                      f"{t['replace']:.1f}) | PQ {row['pq']:.1f}, box mAP {row['box_mAP']:.2f}, GED "
                      f"{row['ged_ratio']:.3f}, pose success {row['pose_success']}, score {accuracy_score(row):.3f}")
        if keep:
            self.rows.append(row)
        return row


def preset_spec(name: str, label: str | None = None, **kw: Any) -> RunSpec:
    return RunSpec(label or name, preset=load_preset(name), **kw)


def _preset_section(runner: SuiteRunner, scenes: list[str], plots_dir: Path) -> list[dict[str, Any]]:
    sections = []
    for scene in scenes:
        sections += runner.timed(lambda scene=scene: _preset_scene(runner, scene, plots_dir))
    if len(scenes) > 1:
        sections.append(_across_scenes(sections, plots_dir))
    return sections


def _preset_scene(runner: SuiteRunner, scene: str, plots_dir: Path) -> list[dict[str, Any]]:
    rows = [runner.run(scene, preset_spec(p), keep_files=scene == PROJECTION_SCENE and p == "balanced")
            for p in PRESETS]
    # the paper's method on the balanced map and graph (shared: the same settings up to stage 4)
    rows.append(runner.run(scene, preset_spec("balanced", "balanced + paper CAD method", method="paper")))
    rows.append(runner.run(scene, preset_spec("balanced", "balanced + baseline mapper", mode="baseline")))
    by = {r["label"]: r for r in rows}
    fast, acc, bal = by["fast"], by["accurate"], by["balanced"]
    front = pareto_front([by[p] for p in PRESETS], "total")  # among the presets (the others: references)
    front_cpu = pareto_front([by[p] for p in PRESETS], "total", cpu=True)
    speed = acc["times_s"]["total"] / max(fast["times_s"]["total"], 1e-9)
    speed_cpu = acc["cpu_s"]["total"] / max(fast["cpu_s"]["total"], 1e-9)
    paper = by["balanced + paper CAD method"]
    lines = [
        f"fast is {speed:.2f}x faster than accurate end to end in wall time ({fast['times_s']['total']:.1f} s "
        f"vs {acc['times_s']['total']:.1f} s), {speed_cpu:.2f}x in CPU time; accuracy score "
        f"{accuracy_score(fast):.3f} vs {accuracy_score(acc):.3f} (PQ {fast['pq']:.1f} vs {acc['pq']:.1f}, "
        f"box mAP {fast['box_mAP']:.2f} vs "
        f"{acc['box_mAP']:.2f}, GED {fast['ged_ratio']:.3f} vs {acc['ged_ratio']:.3f}, pose success "
        f"{fast['pose_success']} vs {acc['pose_success']})",
        f"Pareto front of the presets (wall time vs score): {', '.join(front)}; (CPU time vs score): "
        f"{', '.join(front_cpu)}; balanced is {'ON' if 'balanced' in front_cpu else 'NOT on'} the CPU-time front",
        f"stage 4, paper's method vs ours on the balanced graph: {paper['times_s']['replace']:.1f} s vs "
        f"{bal['times_s']['replace']:.1f} s, pose success {paper['pose_success']} vs {bal['pose_success']}",
        "CAD objects re-matched when the unchanged graph is replaced again: "
        + ", ".join(f"{r['label']} {r['unchanged_rematched']} ({r['times_s']['replace_unchanged']:.2f} s)"
                    for r in rows),
    ]
    plot = plot_pareto(rows, plots_dir / f"pareto_{scene}.png", f"{scene}: end to end, CPU time vs accuracy",
                       cpu=True)
    return [{"title": f"Presets end to end on {scene}", "rows": rows, "lines": lines,
             "plots": [str(plot)] if plot else [],
             "text": "Each preset of config/presets/ end to end (oracle segmentation, default noise); "
                     "score = mean of PQ/100, box mAP, 1 - GED ratio and CAD pose success. The paper's CAD "
                     "method runs on the balanced run's map and graph (shared: same settings up to stage 4).",
             "summary": {"fast_vs_accurate_speedup": round(speed, 3), "pareto_front_cpu": front_cpu,
                         "fast_vs_accurate_speedup_cpu": round(speed_cpu, 3), "pareto_front": front,
                         "balanced_on_front": "balanced" in front_cpu}}]


def _across_scenes(sections: list[dict[str, Any]], plots_dir: Path) -> dict[str, Any]:
    """The presets (and references) averaged over the scenes: mean times, mean figures, the front."""
    labels = [r["label"] for r in sections[0]["rows"]]
    rows = []
    for label in labels:
        runs = [r for s in sections for r in s["rows"] if r["label"] == label]
        mean = {k: float(np.mean([r[k] for r in runs])) for k in ("pq", "box_mAP", "ged_ratio")}
        poses = [r["pose_success"] for r in runs if r.get("pose_success") is not None]
        stills = [r["stillness"] for r in runs if r.get("stillness") is not None]
        aes = [r["ae_median_m"] for r in runs if r.get("ae_median_m") is not None]
        rows.append({**runs[0], "scene": f"mean of {len(runs)}", **mean,
                     "pose_success": float(np.mean(poses)) if poses else None,
                     "stillness": float(np.mean(stills)) if stills else None,
                     "ae_median_m": float(np.median(aes)) if aes else None,
                     "times_s": {k: float(np.mean([r["times_s"][k] for r in runs])) for k in runs[0]["times_s"]},
                     "cpu_s": {k: float(np.mean([r["cpu_s"][k] for r in runs])) for k in runs[0]["cpu_s"]}})
    by = {r["label"]: r for r in rows}
    presets = [by[p] for p in PRESETS]
    front, front_cpu = pareto_front(presets, "total"), pareto_front(presets, "total", cpu=True)
    fast, acc = by["fast"], by["accurate"]
    plot = plot_pareto(rows, plots_dir / "pareto_suite.png", "suite mean: end to end, CPU time vs accuracy",
                       cpu=True)
    lines = [f"fast vs accurate: {acc['times_s']['total'] / fast['times_s']['total']:.2f}x faster in wall time, "
             f"{acc['cpu_s']['total'] / fast['cpu_s']['total']:.2f}x in CPU time; score {accuracy_score(fast):.3f} "
             f"vs {accuracy_score(acc):.3f}",
             f"Pareto front of the presets: wall time {', '.join(front)}; CPU time {', '.join(front_cpu)}"]
    return {"title": "Presets across the suite (means)", "rows": rows, "lines": lines,
            "plots": [str(plot)] if plot else [], "text": "Means over the suite scenes of the rows above.",
            "summary": {"pareto_front": front, "pareto_front_cpu": front_cpu,
                        "balanced_on_front": "balanced" in front_cpu}}


def _sweep_sections(runner: SuiteRunner, scene: str, plots_dir: Path,
                    sweeps: list[tuple[str, str, str, list[Any]]] | None = None) -> list[dict[str, Any]]:
    sections = []
    for stage, section, key, values in sweeps or SWEEPS:
        rows = []
        # the keyframe knobs act only with keyframe gating on: swept on the config defaults, not on balanced
        base = None if key.startswith("keyframes.") else "balanced"
        for v in values:
            label = f"{key}={v}"
            spec = (preset_spec(base, label, extra={section: {key: v}}) if base
                    else RunSpec(label, extra={section: {key: v}}))
            rows.append(runner.run(scene, spec))
        time_key = {"mapping": "map", "graph": "graph", "cad": "replace"}[stage]
        plots = [p for p in (plot_pareto(rows, plots_dir / f"sweep_{key}.png", f"{scene}: {key} ({stage} CPU time)",
                                         time_key, cpu=True),
                             plot_pareto(rows, plots_dir / f"sweep_{key}_total.png", f"{scene}: {key} (end to end)",
                                         cpu=True))
                 if p]
        shared = [r["label"] for r in rows if r.get("shared")]
        sections.append({"title": f"Sweep {key} ({stage})", "rows": rows, "plots": [str(p) for p in plots],
                         "text": f"{base or 'config defaults'} with {key} varied; Pareto front on {time_key} CPU time: "
                                 f"{', '.join(pareto_front(rows, time_key, cpu=True))}"
                                 + (f" (map{' and graph' if stage == 'cad' else ''} shared with the run of the same "
                                    f"settings: {', '.join(shared)})" if shared else "")})
    return sections


def _curve_section(rows: list[dict[str, Any]], xs: list[float], key: str, title: str, xlabel: str, text: str,
                   plots_dir: Path, figures: tuple[str, ...] = ("score", "PQ", "box mAP", "GED", "pose"),
                   ) -> dict[str, Any]:
    """One degradation curve: accuracy figures against the perturbation level."""
    get = {"score": lambda r: accuracy_score(r), "PQ": lambda r: r["pq"] / 100, "box mAP": lambda r: r["box_mAP"],
           "GED": lambda r: r["ged_ratio"], "pose": lambda r: r.get("pose_success") or 0.0}
    names = {"score": "score", "PQ": "PQ / 100", "box mAP": "box mAP", "GED": "GED ratio", "pose": "CAD pose success"}
    plot = plot_series({names[f]: (xs, [get[f](r) for r in rows]) for f in figures}, plots_dir / f"perturb_{key}.png",
                       title, xlabel, "accuracy")
    lines = [f"{xlabel} " + ", ".join(f"{x:g}" for x in xs) + ": " + "; ".join(
        f"{names[f]} " + " / ".join(f"{get[f](r):.3f}" for r in rows) for f in figures)]
    return {"title": f"Perturbation: {title}", "rows": rows, "plots": [str(plot)] if plot else [], "text": text,
            "lines": lines, "curve": {"x": xs, **{names[f]: [round(get[f](r), 4) for r in rows] for f in figures}}}


def _perturbation_sections(runner: SuiteRunner, scene: str, plots_dir: Path) -> list[dict[str, Any]]:
    """Graceful degradation on `scene` with the balanced preset: segmentation noise (the oracle's levels),
    extra depth noise, pose drift, CAD models at the wrong scale (scene_recon/bench/perturb.py). Each
    curve's unperturbed point is the balanced run of the same frames (its map is shared)."""
    from scene_recon.bench.perturb import CAD_SCALE, DEPTH_NOISE, POSE_DRIFT, ScaledLibrary, perturbed_recording

    sections = []
    rows = [runner.run(scene, preset_spec("balanced", f"noise {level}", noise=level))
            for level in ("clean", "default", "hard")]
    sections.append(_curve_section(
        rows, [0, 1, 2], "segmentation_noise", f"segmentation noise ({scene})", "oracle noise level",
        "The balanced preset with the oracle's noise levels clean (0), default (1) and hard (2) "
        "(config/segmentation.yaml: misses, spurious blobs, class confusion, over/under-segmentation, boundary "
        "noise): accuracy should fall gradually, not off a cliff.", plots_dir))
    for kind, levels, what, text in (
            ("depth_noise", DEPTH_NOISE, "extra depth noise (x sensor sigma)",
             "Extra zero-mean Gaussian depth noise of k times the sensor model's axial sigma(z) (Kinect-v1 class, "
             "6 mm at 2 m) on top of the recording's own noise; same frames, labels and settings."),
            ("pose_drift", POSE_DRIFT, "pose drift (x default odometry error)",
             "The mapper's camera poses carry k times the default odometry error (random-walk drift 5 mm/sqrt(s) "
             "and 0.1 deg/sqrt(s) yaw, per-frame jitter 2 mm / 0.1 deg); 0 = true poses.")):
        rows = []
        for level in levels:
            bag, gt = perturbed_recording(*_scene_paths(scene), kind, level)
            rows.append(runner.run_on(scene if level == 0 else f"{scene} {kind} {level:g}", bag, gt,
                                      preset_spec("balanced", f"{kind} {level:g}")))
        sections.append(_curve_section(rows, list(levels), kind, f"{what} ({scene})", what, text, plots_dir))
    rows = []
    for factor in sorted(CAD_SCALE):
        library = runner.library if factor == 1.0 else ScaledLibrary(runner.library, factor)
        rows.append(runner.run(scene, preset_spec("balanced", f"CAD scale {factor:g}")) if factor == 1.0 else
                    runner.run_on(scene, *_scene_paths(scene), preset_spec("balanced", f"CAD scale {factor:g}"),
                                  library=library))
    sections.append(_curve_section(
        rows, sorted(CAD_SCALE), "cad_scale", f"CAD models at the wrong scale ({scene})", "CAD model scale factor",
        "Every model of the CAD library s times its size (so the objects are 1/s of their models): stage 4 must "
        "recover the scale; map and graph are the balanced run's (shared). Pose success needs the fitted size "
        "within its tolerance.", plots_dir, ("score", "pose")))
    return sections


def _scene_paths(scene: str) -> tuple[Path, Path]:
    from scene_recon.synthetic.suite import suite_scene

    return suite_scene(scene, progress=False)


def _skip_and_scaling(runner: SuiteRunner, plots_dir: Path, long_frames: int) -> list[dict[str, Any]]:
    from scene_recon.bench.scaling import empty_room, object_count_scaling, per_frame_cost, static_camera

    def empty() -> list[dict[str, Any]]:
        row = empty_room(runner)
        return [{"title": "Skip: empty room", "rows": [row], "text":
                 "A generated room without objects: no CAD work (objects replaced by CAD: "
                 f"{row['cad_objects']}), stage 4 time {row['times_s']['replace']:.2f} s."}]

    def static() -> list[dict[str, Any]]:
        st = static_camera(runner)
        return [{"title": "Skip: static camera", "lines": st["lines"], "text": st["text"], "data": st}]

    def per_frame() -> list[dict[str, Any]]:
        pf = per_frame_cost(runner, long_frames)
        plot = plot_series({"per-frame CPU time (ms), 50-frame mean": (pf["frame_index"], pf["frame_cpu_ms_smooth"]),
                            "per-frame wall time (ms), 50-frame mean": (pf["frame_index"], pf["frame_ms_smooth"])},
                           plots_dir / "per_frame_time.png", f"per-frame cost over {long_frames} frames", "frame", "ms")
        plot2 = plot_series({"map memory (MB)": (pf["frame_index"], pf["memory_mb"])}, plots_dir / "map_memory.png",
                            f"map memory over {long_frames} frames", "frame", "MB")
        return [{"title": f"Scaling: per-frame cost over {long_frames} frames", "lines": pf["lines"],
                 "text": pf["text"], "plots": [str(p) for p in (plot, plot2) if p],
                 "data": {k: v for k, v in pf.items() if k not in ("frame_index", "frame_ms", "frame_cpu_ms",
                                                                  "frame_ms_smooth", "frame_cpu_ms_smooth",
                                                                  "memory_mb", "label_frame")}}]

    def objects() -> list[dict[str, Any]]:
        oc = object_count_scaling(runner)
        plot = plot_series({"end to end (s)": (oc["objects"], oc["total_s"]), "map (s)": (oc["objects"], oc["map_s"]),
                            "replace (s)": (oc["objects"], oc["replace_s"])}, plots_dir / "object_count.png",
                           "end-to-end time against object count", "objects", "s")
        return [{"title": "Scaling: end-to-end time against object count", "rows": oc["rows"],
                 "lines": oc["lines"], "plots": [str(plot)] if plot else [], "text": oc["text"]}]

    return [s for build in (empty, static, per_frame, objects) for s in runner.timed(build)]


def _projection_sections(runner: SuiteRunner, preset_rows: dict[str, dict[str, Any]],
                         per_frame: dict[str, Any] | None) -> list[dict[str, Any]]:
    """Segmentation latency on onnxruntime (CPU; CUDA where offered) and the multi-room / multi-host
    projection from the measured message sizes of PROJECTION_SCENE's balanced run."""
    from panoptic_mapping.dataio import DataInputConfig
    from panoptic_mapping.dataio.registry import open_dataset
    from recon_core.config import CONFIG_DIR, load_config
    from scene_recon.bench.projection import dds_projection, message_sizes, segmentation_latency
    from scene_recon.synthetic.suite import SUITE, suite_scene

    runner.progress(f"[{time.perf_counter() - runner.t0:6.0f} s] segmentation latency (onnxruntime) ...")
    bag, _ = suite_scene("bench-small", progress=False)
    data = load_config(DataInputConfig, CONFIG_DIR / "data.yaml", {"max_frames": 5})
    with open_dataset(bag, data) as loader:
        frames = list(loader)
    lat = segmentation_latency(frames)
    lines = []
    for device, d in lat["devices"].items():
        if d["available"]:
            lines.append(f"{device.upper()} execution provider: {d['frame_ms_median']:.1f} ms per 640x480 frame "
                         f"(median of 20; {d['frame_cpu_ms_median']:.1f} ms CPU time), of which the network "
                         f"{d['network_ms_median']:.1f} ms for {lat['gmacs']:.2f} GMAC: {d['gmac_per_s']:.1f} GMAC/s "
                         f"on {lat['threads']} cores")
        else:
            lines.append(f"{device.upper()} execution provider: not available here ({d['note']})")
    cpu = lat["devices"].get("cpu", {})
    if cpu.get("available"):
        rest = cpu["frame_ms_median"] - cpu["network_ms_median"]
        lines.append(f"at the measured CPU throughput a network of N GMAC takes about N / {cpu['gmac_per_s']:.1f} s "
                     f"per frame plus {rest:.0f} ms of pre- and post-processing (e.g. 4 GMAC: "
                     f"{4000 / cpu['gmac_per_s'] + rest:.0f} ms)")
    sections = [{"title": "Scaling: segmentation latency (onnxruntime)", "lines": lines, "data": lat,
                 "text": f"The `onnx` backend end to end (letterbox, network, argmax, panoptic masks) on a "
                         f"{lat['input']}x{lat['input']} semantic network built in-process (5 convolutions, random "
                         "weights: no pretrained weights exist here; the cost of a convolution does not depend on "
                         "them), and the network alone, on each execution provider onnxruntime offers."}]
    bal = preset_rows.get("balanced")
    if bal is None or "folder" not in bal:
        return sections
    folder = Path(bal["folder"])
    sizes = message_sizes(folder / "map", folder / "scene" / "scene.urdf")
    if "error" in sizes:
        sections.append({"title": "Scaling: multi-room building and nodes on several hosts (DDS)",
                         "text": f"message sizes could not be measured: {sizes['error']}"})
        return sections
    duration_s = SUITE[PROJECTION_SCENE].frames / 30.0
    room = {"map_mb": bal["map_memory_mb"], "objects": bal["cad_objects"], "replace_s": bal["times_s"]["replace"],
            "segmentation_hz": bal["segmentation_calls"] / duration_s, "urdf_updates": 1}
    proj = dds_projection(sizes, room)
    defaults_hz = None
    if per_frame and per_frame.get("segmentation_calls"):
        defaults_hz = per_frame["segmentation_calls"] / (per_frame["frames"] / 30.0)
    lines = [f"measured message sizes (CDR bytes): color {sizes['color']}, depth {sizes['depth']}, label image "
             f"{sizes['labels']}, entity array of {sizes['entities']} entities {sizes['entities_with_meshes']} with "
             f"meshes / {sizes['entities_without_meshes']} without, URDF {sizes['urdf']}",
             f"one room = {PROJECTION_SCENE}, balanced: map {room['map_mb']:.1f} MB, {room['objects']} CAD objects, "
             f"stage 4 {room['replace_s']:.1f} s, {room['segmentation_hz']:.1f} segmentation calls per second of "
             "recording" + (f" (config defaults with keyframe gating: {defaults_hz:.1f}/s on the long sequence)"
                            if defaults_hz else "")]
    lines += [f"link {r['link']}: {r['MB_per_s']:.2f} MB/s = {r['Mbit_per_s']:.1f} Mbit/s ({r['basis']})"
              for r in proj["links"]]
    lines += [f"{b['rooms']} room(s): map {b['map_memory_mb']:.0f} MB, {b['objects']} CAD objects, entity array "
              f"{b['entity_array_mb']:.1f} MB ({b['entity_stream_mbit_s']:.0f} Mbit/s at one array per 2 s, "
              f"{b['entity_array_ms_at_1gbit']:.0f} ms per array on 1 Gbit/s), stage 4 from scratch "
              f"{b['stage4_full_s']:.0f} s, URDF {b['urdf_kb']:.0f} kB" for b in proj["building"]]
    sections.append({"title": "Scaling: multi-room building and nodes on several hosts (DDS)", "lines": lines,
                     "data": {"sizes": sizes, "room": room, **proj},
                     "text": "Computed, not measured end to end: per link between hosts, the measured serialized "
                             "message sizes (`python -m ros_nodes.message_sizes`, the nodes' own conversions, on "
                             f"{PROJECTION_SCENE}'s balanced map and scene) times their rates (camera 30 Hz; "
                             "segmentation calls per second of recording as measured; the mapper publishes the entity "
                             "array at most every 2 s, `publish_period_s`); per building, one measured room scaled "
                             "linearly with the number of rooms (per-frame cost stays flat, see above; map memory, "
                             "entity array and stage-4 work grow with the rooms mapped)."})
    return sections


def run_suite(name: str, out: Path, progress: Progress = print, long_frames: int = 2000) -> dict[str, Path]:
    """Run suite `name` into `out` (results.json, report.md, report.html, *.png); returns the files."""
    if name not in SUITES:
        raise ValueError(f"unknown suite {name!r}; known: {', '.join(SUITES)}")
    out.mkdir(parents=True, exist_ok=True)
    load_before = [round(x, 2) for x in os.getloadavg()]
    children0 = os.times()
    runner = SuiteRunner(out, progress)
    c0 = time.process_time()
    # warm-up (not reported): CAD feature caches and raycasting scenes, first imports, the scene's generation
    runner.run("bench-small", preset_spec("fast", "warm-up"), keep=False)
    runner.cache = StageCache()  # no run shares the warm-up's map: its time holds the cold start
    sections: list[dict[str, Any]] = []
    if name == "quick":
        sections += _preset_section(runner, ["bench-small"], out)
    else:
        from scene_recon.synthetic.suite import SUITE

        scenes = list(SUITE)
        # bench-small first, then its sweeps and curves while its balanced map is in the stage cache
        small = runner.timed(lambda: _preset_scene(runner, scenes[0], out))
        sweeps = [s for sweep in SWEEPS for s in runner.timed(lambda sweep=sweep: _sweep_sections(
            runner, scenes[0], out, [sweep]))]
        curves = runner.timed(lambda: _perturbation_sections(runner, scenes[0], out))
        others = [s for scene in scenes[1:]
                  for s in runner.timed(lambda scene=scene: _preset_scene(runner, scene, out))]
        presets = small + others
        sections += [*presets, _across_scenes(presets, out), *sweeps, *curves]
        skips = _skip_and_scaling(runner, out, long_frames)
        sections += skips
        per_frame = next((s.get("data") for s in skips if s["title"].startswith("Scaling: per-frame")), None)
        kitchen = next((s for s in presets if s["title"].endswith(PROJECTION_SCENE)), None)
        rows = {r["label"]: r for r in kitchen["rows"]} if kitchen else {}
        sections += runner.timed(lambda: _projection_sections(runner, rows, per_frame))
    shutil.rmtree(runner.work, ignore_errors=True)
    wall = time.perf_counter() - runner.t0
    cpu = time.process_time() - c0
    children = os.times()
    child_cpu = (children.children_user - children0.children_user) + (children.children_system
                                                                        - children0.children_system)
    progress(f"suite {name} done in {wall:.0f} s wall, {cpu + child_cpu:.0f} s CPU (load average before "
             f"{load_before}, after {[round(x, 2) for x in os.getloadavg()]})")
    costs = [{"title": s["title"], **s["cost_s"]} for s in sections if "cost_s" in s]
    return write_report(out, name, {"machine": machine(), "suite_wall_s": round(wall, 1),
                                    "suite_cpu_s": round(cpu + child_cpu, 1), "suite_child_cpu_s": round(child_cpu, 1),
                                    "load_avg_before": load_before, "section_costs": costs,
                                    "stage_cache_hits": dict(runner.cache.hits), "sections": sections,
                                    "mean_score": float(np.mean([accuracy_score(r) for r in runner.rows]))})
