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
