"""One configuration end to end (scene_recon.bench) on a tiny generated scene: times, figures, skips."""

from __future__ import annotations

import math

import pytest

from recon_core.config import load_preset
from scene_recon.bench.pipeline import RunSpec, run_pipeline
from scene_recon.bench.scaling import _frame_times, extra_scene


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv("SCENE_RECON_CACHE", str(tmp_path_factory.mktemp("cache")))
    yield extra_scene("tiny", 3, 12, 5)
    mp.undo()


def test_a_preset_end_to_end_is_timed_scored_and_skips_an_unchanged_scene(tiny, tmp_path):
    bag, gt = tiny
    row = run_pipeline(bag, gt, tmp_path / "run", RunSpec("fast", preset=load_preset("fast"), physics=False))
    assert row["frames"] == 6  # the fast preset reads every 2nd of the 12 frames
    for key in ("map", "graph", "replace", "total"):
        assert row["times_s"][key] > 0 and row["cpu_s"][key] >= 0
    assert row["times_s"]["total"] >= row["times_s"]["map"] + row["times_s"]["graph"] + row["times_s"]["replace"]
    assert 0 <= row["pq"] <= 100 and 0 <= row["box_mAP"] <= 1 and row["ged_ratio"] >= 0
    assert row["pose_success"] is None or 0 <= row["pose_success"] <= 1
    assert row["unchanged_rematched"] == 0  # the same graph again: no CAD work
    assert all(math.isfinite(v) for v in row["times_s"].values())


def test_per_frame_times_and_memory_for_every_frame(tiny):
    bag, gt = tiny
    res = _frame_times(bag, gt, preset_name=None)  # the config defaults: every frame
    assert _frame_times(bag, gt, preset_name="balanced")["frames"] == 6  # every 2nd frame
    assert res["frames"] == 12 and len(res["frame_ms"]) == 12 and len(res["memory_mb"]) == 12
    assert all(ms > 0 for ms in res["frame_ms"]) and res["memory_mb"][-1] >= res["memory_mb"][0] > 0


def test_a_shared_map_gives_the_same_figures_and_carries_its_cost(tiny, tmp_path):
    from scene_recon.bench.pipeline import StageCache

    bag, gt = tiny
    cache = StageCache()
    spec = RunSpec("balanced", preset=load_preset("balanced"), physics=False)
    fresh = run_pipeline(bag, gt, tmp_path / "a", spec, cache=cache)
    paper = run_pipeline(bag, gt, tmp_path / "b", RunSpec("paper", preset=load_preset("balanced"), method="paper",
                                                          physics=False), cache=cache)
    again = run_pipeline(bag, gt, tmp_path / "c", spec, cache=cache)
    assert fresh["shared"] is None and paper["shared"] == again["shared"] == "map+graph"
    assert cache.hits == {"map": 2, "graph": 2}
    for key in ("pq", "box_mAP", "ged_ratio", "pose_success", "entities", "cad_objects"):
        assert again[key] == fresh[key], key  # the cached scene is not changed by the runs that reuse it
    assert again["times_s"]["map"] == fresh["times_s"]["map"] and again["cpu_s"]["map"] == fresh["cpu_s"]["map"]
    other = run_pipeline(bag, gt, tmp_path / "d", RunSpec("ransac", preset=load_preset("balanced"), physics=False,
                                                          extra={"scene_graph": {"planes.ransac_iterations": 50}}),
                         cache=cache)
    assert other["shared"] == "map"


def test_perturbed_recordings_and_scaled_library(tiny, tmp_path):
    from cad_replacement.cad.library import CadLibrary
    from scene_recon.bench.perturb import ScaledLibrary, perturbed_recording
    from scene_recon.bench.scaling import _frames_of

    bag, gt = tiny
    assert perturbed_recording(bag, gt, "depth_noise", 0) == (bag, gt)
    base = _frames_of(bag)
    for kind in ("depth_noise", "pose_drift"):
        pbag, pgt = perturbed_recording(bag, gt, kind, 2.0)
        assert pgt == gt and pbag != bag and perturbed_recording(bag, gt, kind, 2.0) == (pbag, pgt)  # cached
        frames = _frames_of(pbag)
        assert len(frames) == len(base)
        moved = [float(abs(a.pose[:3, 3] - b.pose[:3, 3]).max()) for a, b in zip(frames, base, strict=True)]
        changed = [float(abs(a.depth - b.depth).max()) for a, b in zip(frames, base, strict=True)]
        if kind == "pose_drift":
            assert max(moved) > 0.001 and max(changed) == 0
        else:
            assert max(moved) < 1e-6 and max(changed) > 0.002
        assert all((a.extras["labels"] == b.extras["labels"]).all() for a, b in zip(frames, base, strict=True))
    lib = CadLibrary(seeds_per_class=1)
    scaled = ScaledLibrary(lib, 1.5)
    entry, feats = lib.candidates("chair")[0]
    assert scaled.candidates("chair")[0][1].box_size == pytest.approx(1.5 * feats.box_size)
    assert scaled.digest(entry) != lib.digest(entry) and scaled.entries() == lib.entries()


def test_per_frame_cpu_times_and_label_frames(tiny):
    bag, gt = tiny
    res = _frame_times(bag, gt, preset_name=None)
    assert len(res["frame_cpu_ms"]) == len(res["label_frame"]) == 12
    assert res["label_frame"][0] and sum(res["label_frame"]) >= res["segmentation_calls"]  # keyframes fuse labels
    assert all(ms >= 0 for ms in res["frame_cpu_ms"])


def test_segmentation_latency_and_dds_projection(tiny, tmp_path):
    from scene_recon.bench.projection import dds_projection, latency_model, message_sizes, segmentation_latency
    from scene_recon.bench.scaling import _frames_of

    model, gmacs = latency_model(size=64, classes=5)
    assert model and 0 < gmacs < 0.1
    lat = segmentation_latency(_frames_of(tiny[0], max_frames=2), repeats=2)
    assert lat["devices"]["cpu"]["available"] and lat["devices"]["cpu"]["frame_ms_median"] > 0
    assert "cuda" in lat["devices"]  # measured, or said to be unavailable
    bag, gt = tiny
    row = run_pipeline(bag, gt, tmp_path / "run", RunSpec("fast", preset=load_preset("fast"), physics=False))
    sizes = message_sizes(tmp_path / "run" / "map", tmp_path / "run" / "scene" / "scene.urdf")
    assert sizes["color"] > 640 * 480 * 3 and sizes["depth"] > 640 * 480 * 2 and sizes["labels"] > 640 * 480 * 4
    assert sizes["entities_with_meshes"] > sizes["entities_without_meshes"] > 0 and sizes["urdf"] > 0
    proj = dds_projection(sizes, {"map_mb": row["map_memory_mb"], "objects": 3, "replace_s": 1.0,
                                  "segmentation_hz": 15.0, "urdf_updates": 1}, rooms=(1, 10))
    camera = proj["links"][0]
    assert camera["MB_per_s"] == pytest.approx(30 * (sizes["color"] + sizes["depth"]) / 1e6, rel=1e-3)
    one, ten = proj["building"]
    assert ten["map_memory_mb"] == pytest.approx(10 * one["map_memory_mb"], rel=0.02) and ten["objects"] == 30
