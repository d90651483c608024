"""The named suites of `scene-recon benchmark`: what runs, with progress, into one report folder.

quick (< 3 min on a 2-core machine; CI runs it): `bench-small` end to end with each preset, the
  paper's CAD method and the baseline mapper on the balanced preset; time against accuracy with
  its Pareto front, and the unchanged-scene skip (zero CAD work on an unchanged graph).
full (< 30 min): the presets on every suite scene; one-knob sweeps per stage (voxel size, frame
  stride, keyframe gating, label propagation, image downscale, depth-segmentation resolution,
  RANSAC iterations, CAD top-k and LM evaluations, CAD method) with per-stage and end-to-end Pareto
  plots; skip measurements (empty room, static camera, unchanged scene); scaling (per-frame time and
  map memory over a long sequence, end-to-end time against object count).
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
from scene_recon.bench.pipeline import RunSpec, accuracy_score, pareto_front, run_pipeline
from scene_recon.bench.report import plot_pareto, plot_series, write_report

PRESETS = ("fast", "balanced", "accurate")
SUITES = ("quick", "full")

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
        self.t0 = time.perf_counter()

    def run(self, scene: str, spec: RunSpec, keep: bool = True) -> dict[str, Any]:
        from scene_recon.synthetic.suite import suite_scene

        bag, gt = suite_scene(scene, progress=False)
        return self.run_on(scene, bag, gt, spec, keep)

    def run_on(self, scene: str, bag: Path, gt: Path, spec: RunSpec, keep: bool = True) -> dict[str, Any]:
        self.progress(f"[{time.perf_counter() - self.t0:6.0f} s] {scene}: {spec.label} ...")
        folder = self.work / scene / spec.label.replace("/", "_").replace(" ", "_")
        row = run_pipeline(bag, gt, folder, spec, self.library)
        shutil.rmtree(folder, ignore_errors=True)  # keep the report folder small
        row["scene"] = scene
        t = row["times_s"]
        self.progress(f"         total {t['total']:.1f} s (map {t['map']:.1f}, graph {t['graph']:.2f}, replace "
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
        rows = [runner.run(scene, preset_spec(p)) for p in PRESETS]
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
        sections.append({"title": f"Presets end to end on {scene}", "rows": rows, "lines": lines,
                         "plots": [str(plot)] if plot else [],
                         "text": "Each preset of config/presets/ end to end (oracle segmentation, default noise); "
                                 "score = mean of PQ/100, box mAP, 1 - GED ratio and CAD pose success.",
                         "summary": {"fast_vs_accurate_speedup": round(speed, 3), "pareto_front_cpu": front_cpu,
                                     "fast_vs_accurate_speedup_cpu": round(speed_cpu, 3), "pareto_front": front,
                                     "balanced_on_front": "balanced" in front_cpu}})
    if len(scenes) > 1:
        sections.append(_across_scenes([s for s in sections if s["title"].startswith("Presets end to end")], plots_dir))
    return sections


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


def _sweep_sections(runner: SuiteRunner, scene: str, plots_dir: Path) -> list[dict[str, Any]]:
    sections = []
    for stage, section, key, values in SWEEPS:
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
        sections.append({"title": f"Sweep {key} ({stage})", "rows": rows, "plots": [str(p) for p in plots],
                         "text": f"{base or 'config defaults'} with {key} varied; Pareto front on {time_key} CPU time: "
                                 f"{', '.join(pareto_front(rows, time_key, cpu=True))}"})
    return sections


def _perturbation_section(runner: SuiteRunner, scene: str, plots_dir: Path) -> dict[str, Any]:
    """Graceful degradation: the balanced preset under the oracle's segmentation noise levels."""
    rows = [runner.run(scene, preset_spec("balanced", f"noise {level}", noise=level))
            for level in ("clean", "default", "hard")]
    plot = plot_series({"score": ([0, 1, 2], [accuracy_score(r) for r in rows]),
                        "PQ / 100": ([0, 1, 2], [r["pq"] / 100 for r in rows])},
                       plots_dir / "noise_levels.png",
                       f"{scene}: segmentation noise clean (0) / default (1) / hard (2)", "oracle noise level",
                       "accuracy")
    return {"title": "Perturbation: segmentation noise", "rows": rows, "plots": [str(plot)] if plot else [],
            "text": "The balanced preset with the oracle's noise levels clean, default and hard "
                    "(config/segmentation.yaml): accuracy should fall gradually, not off a cliff."}


def _skip_and_scaling(runner: SuiteRunner, plots_dir: Path, long_frames: int) -> list[dict[str, Any]]:
    from scene_recon.bench.scaling import empty_room, object_count_scaling, per_frame_cost, static_camera

    sections = []
    row = empty_room(runner)
    sections.append({"title": "Skip: empty room", "rows": [row], "text":
                     "A generated room without objects: no CAD work (objects replaced by CAD: "
                     f"{row['cad_objects']}), stage 4 time {row['times_s']['replace']:.2f} s."})
    st = static_camera(runner)
    sections.append({"title": "Skip: static camera", "lines": st["lines"], "text": st["text"], "data": st})
    pf = per_frame_cost(runner, long_frames)
    plot = plot_series({"per-frame time (ms)": (pf["frame_index"], pf["frame_ms"])}, plots_dir / "per_frame_time.png",
                       f"per-frame cost over {long_frames} frames", "frame", "ms")
    plot2 = plot_series({"map memory (MB)": (pf["frame_index"], pf["memory_mb"])}, plots_dir / "map_memory.png",
                        f"map memory over {long_frames} frames", "frame", "MB")
    sections.append({"title": f"Scaling: per-frame cost over {long_frames} frames", "lines": pf["lines"],
                     "text": pf["text"], "plots": [str(p) for p in (plot, plot2) if p],
                     "data": {k: v for k, v in pf.items() if k not in ("frame_index", "frame_ms", "memory_mb")}})
    oc = object_count_scaling(runner)
    plot = plot_series({"end to end (s)": (oc["objects"], oc["total_s"]), "map (s)": (oc["objects"], oc["map_s"]),
                        "replace (s)": (oc["objects"], oc["replace_s"])}, plots_dir / "object_count.png",
                       "end-to-end time against object count", "objects", "s")
    sections.append({"title": "Scaling: end-to-end time against object count", "rows": oc["rows"],
                     "lines": oc["lines"], "plots": [str(plot)] if plot else [], "text": oc["text"]})
    return sections


def run_suite(name: str, out: Path, progress: Progress = print, long_frames: int = 2000) -> dict[str, Path]:
    """Run suite `name` into `out` (results.json, report.md, report.html, *.png); returns the files."""
    if name not in SUITES:
        raise ValueError(f"unknown suite {name!r}; known: {', '.join(SUITES)}")
    out.mkdir(parents=True, exist_ok=True)
    runner = SuiteRunner(out, progress)
    # warm-up (not reported): CAD feature caches and raycasting scenes, first imports, the scene's generation
    runner.run("bench-small", preset_spec("fast", "warm-up"), keep=False)
    sections: list[dict[str, Any]] = []
    if name == "quick":
        sections += _preset_section(runner, ["bench-small"], out)
    else:
        from scene_recon.synthetic.suite import SUITE

        sections += _preset_section(runner, list(SUITE), out)
        sections += _sweep_sections(runner, "bench-small", out)
        sections.append(_perturbation_section(runner, "bench-kitchen", out))
        sections += _skip_and_scaling(runner, out, long_frames)
    shutil.rmtree(runner.work, ignore_errors=True)
    wall = time.perf_counter() - runner.t0
    progress(f"suite {name} done in {wall:.0f} s")
    return write_report(out, name, {"machine": machine(), "suite_wall_s": round(wall, 1), "sections": sections,
                                    "mean_score": float(np.mean([accuracy_score(r) for r in runner.rows]))})
