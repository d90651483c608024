"""The full suite's orchestration (sections, shared stages, curves, projection) with the runs replaced by a
stand-in: every section is built and written, in seconds (the real runs are the benchmark's, not a test's)."""

from __future__ import annotations

import json

import pytest

import scene_recon.bench.scaling as scaling
import scene_recon.bench.suites as suites


def _fake_row(bag, gt, out, spec, library=None, cache=None) -> dict:
    seed = sum(map(ord, spec.label)) % 7
    times = {"map": 2.0 + seed, "graph": 0.2, "replace": 1.0, "export": 0.1, "total": 3.3 + seed, "segmentation": 0.1,
             "mapper": 1.5, "replace_unchanged": 0.01}
    return {"label": spec.label, "preset": spec.preset.name if spec.preset else None, "method": spec.method,
            "mode": spec.mode, "extra": spec.extra, "shared": None, "eval_s": 0.1, "eval_cpu_s": 0.1,
            "times_s": times, "cpu_s": {k: times[k] for k in ("map", "graph", "replace", "total")},
            "frames": 10, "keyframes": 10, "segmentation_calls": 10, "map_memory_mb": 5.0, "entities": 9,
            "stage_ms": {}, "pq": 80.0 - seed, "map_mAP": 90.0, "ged_ratio": 0.05, "box_mAP": 0.6, "pose_success": 0.5,
            "ae_median_m": 0.01, "cad_objects": 4, "matched_objects": 4, "stillness": 1.0, "unchanged_rematched": 0}


def _fake_frames(bag, gt, frames=None, max_frames=0, preset_name="balanced") -> dict:
    n = len(frames) if frames is not None else 1200
    return {"frame_ms": [10.0] * n, "frame_cpu_ms": [9.0] * n, "label_frame": [i % 3 == 0 for i in range(n)],
            "memory_mb": [1.0 + i / n for i in range(n)], "segmentation_calls": n // 10, "frames": n}


def test_full_suite_sections_with_stand_in_runs(tmp_path, monkeypatch):
    monkeypatch.setattr(suites, "run_pipeline", _fake_row)
    monkeypatch.setattr(scaling, "_frame_times", _fake_frames)
    monkeypatch.setattr(scaling, "extra_scene", lambda *a: (tmp_path / "bag", tmp_path / "gt"))
    monkeypatch.setattr(scaling, "static_camera", lambda runner: {"text": "t", "lines": ["l"]})
    monkeypatch.setattr("scene_recon.bench.perturb.perturbed_recording",
                        lambda bag, gt, kind, level: (tmp_path / f"{kind}{level}", gt))
    monkeypatch.setattr("scene_recon.bench.projection.segmentation_latency", lambda frames: {
        "gmacs": 1.0, "input": 640, "threads": 2, "available_providers": ["CPUExecutionProvider"], "devices": {
            "cpu": {"available": True, "frame_ms_median": 50.0, "frame_cpu_ms_median": 45.0, "network_ms_median": 30.0,
                    "gmac_per_s": 33.3},
            "cuda": {"available": False, "note": "not offered"}}})
    monkeypatch.setattr("scene_recon.bench.projection.message_sizes", lambda m, u: {
        "color": 921672, "depth": 614472, "labels": 1228872, "entities_with_meshes": 4_000_000,
        "entities_without_meshes": 2000, "entities": 20, "urdf": 30000})
    files = suites.run_suite("full", tmp_path / "out", progress=lambda line: None, long_frames=1200)
    data = json.loads(files["json"].read_text())
    titles = [s["title"] for s in data["sections"]]
    scenes = ("bench-small", "bench-kitchen", "bench-office", "bench-clutter")
    assert titles[:5] == [f"Presets end to end on {s}" for s in scenes] + ["Presets across the suite (means)"]
    for want in ("Perturbation: segmentation noise", "Perturbation: extra depth noise", "Perturbation: pose drift",
                 "Perturbation: CAD models at the wrong scale", "Scaling: per-frame cost over 1200 frames",
                 "Scaling: segmentation latency (onnxruntime)", "Scaling: multi-room building and nodes on several"):
        assert any(t.startswith(want) for t in titles), want
    curves = [s for s in data["sections"] if s["title"].startswith("Perturbation")]
    assert all(len(s["curve"]["x"]) >= 3 for s in curves)
    per_frame = next(s for s in data["sections"] if s["title"].startswith("Scaling: per-frame"))
    assert per_frame["data"]["ratio_last_first_cpu"] == pytest.approx(1.0)
    dds = next(s for s in data["sections"] if s["title"].startswith("Scaling: multi-room"))
    assert dds["data"]["links"][0]["Mbit_per_s"] == pytest.approx(8 * 30 * (921672 + 614472) / 1e6, abs=0.1)
    latency = next(s for s in data["sections"] if s["title"].startswith("Scaling: segmentation latency"))
    assert any("CUDA execution provider: not available" in line for line in latency["lines"])
    assert data["suite_cpu_s"] >= 0 and data["section_costs"] and "load_avg_before" in data
    assert "## Perturbation: pose drift" in files["markdown"].read_text()
