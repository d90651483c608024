"""The robustness protocol (scene_recon.bench.robustness): statistics over draws, and one tiny run end to end."""

from __future__ import annotations

import json
import math

import pytest

from scene_recon.bench import robustness
from scene_recon.bench.pipeline import StageCache
from scene_recon.bench.robustness import (
    ProtocolSpec,
    Variant,
    aggregate,
    parse_variant,
    protocol_spec,
    run_protocol,
    stats,
    summary_lines,
    write_protocol_report,
)
from scene_recon.synthetic.suite import SuiteScene


def _row(scene, draw, mode, pq, pose, ae):
    return {"scene": scene, "draw": draw, "mode": mode, "pq": pq, "pq_things": pq, "box_mAP": 0.5,
            "ged_ratio": 0.1, "pose_success": pose, "ae_median_m": ae, "stillness": 1.0, "map_ms_per_frame": 10.0,
            "replace_s": 1.0}


def test_stats_name_the_worst_by_the_figures_direction():
    up = stats([0.8, 0.6, None, 0.9, float("nan")], higher_is_better=True)
    assert up == pytest.approx({"mean": 0.7666666, "std": 0.1247219, "worst": 0.6, "best": 0.9, "n": 3})
    down = stats([3.0, 5.0], higher_is_better=False)
    assert down["worst"] == 5.0 and down["best"] == 3.0
    assert stats([None], True) is None


def test_aggregate_reports_spread_worst_draw_worst_scene_and_paired_gains():
    rows = [_row("a", 0, "full", 90, 0.9, 0.004), _row("a", 1, "full", 70, 0.8, 0.006),
            _row("b", 0, "full", 85, 0.5, 0.010), _row("b", 1, "full", 87, 0.7, 0.002),
            _row("a", 0, "baseline", 80, 0.5, 0.005), _row("a", 1, "baseline", 75, 0.6, 0.005),
            _row("b", 0, "baseline", 60, 0.4, 0.005), _row("b", 1, "baseline", 70, None, 0.005)]
    gt = [{"scene": "a", "pose_success": 0.9, "ae_median_m": 0.003, "stillness": 1.0},
          {"scene": "b", "pose_success": 0.95, "ae_median_m": 0.002, "stillness": 1.0}]
    s = aggregate(rows, gt)
    full = s["modes"]["full"]
    assert full["overall"]["pq"]["mean"] == pytest.approx(83.0) and full["overall"]["pq"]["worst"] == 70
    assert full["worst_draw"]["pq"] == {"scene": "a", "draw": 1, "value": 70}
    assert full["worst_draw"]["ae_median_m"] == {"scene": "b", "draw": 0, "value": 0.010}  # lower is better
    assert full["worst_scene_mean"]["pose_success"] == {"scene": "b", "mean": pytest.approx(0.6)}
    assert full["per_scene"]["a"]["pq"]["std"] == pytest.approx(10.0)
    gains = s["paired"]["full - baseline"]
    assert gains["pq"]["mean"] == pytest.approx((10 - 5 + 25 + 17) / 4) and gains["pq"]["worst"] == -5
    assert gains["pose_success"]["n"] == 3  # a draw without a figure on one side is not paired
    assert s["gt_entities"]["overall"]["pose_success"]["worst"] == 0.9
    lines = summary_lines({"summary": s})
    assert any(line.startswith("full (4 runs): PQ 83.00") for line in lines)
    assert any("full - baseline PQ" in line and "+11.75" in line for line in lines)


def test_per_class_pose_counts_are_summed_over_runs_and_listed_worst_first():
    rows = [{**_row("a", 0, "full", 90, 0.5, 0.004),
             "pose_by_class": {"book": {"objects": 2, "successes": 0, "translation": 0, "yaw": 1, "size": 2},
                               "table": {"objects": 1, "successes": 1, "translation": 0, "yaw": 0, "size": 0}}},
            {**_row("b", 0, "full", 90, 0.5, 0.004),
             "pose_by_class": {"table": {"objects": 1, "successes": 0, "translation": 1, "yaw": 0, "size": 1}}},
            _row("b", 1, "full", 90, None, 0.004)]  # a run without CAD objects adds nothing
    counts = aggregate(rows, [])["modes"]["full"]["pose_by_class"]
    assert list(counts) == ["book", "table"]  # two failures before one
    assert counts["table"] == {"objects": 2, "successes": 1, "translation": 1, "yaw": 0, "size": 1}
    md = robustness.failure_table({"summary": aggregate(rows, [])})
    assert "| book | 2 | 0 | 0 | 1 | 2 |" in md and "| table | 2 | 1 | 1 | 0 | 1 |" in md


def test_protocol_specs_validate_their_scenes_draws_and_variants():
    quick = protocol_spec("quick")
    assert len(quick.draws) >= 3 and len(quick.scenes) >= 2
    assert any(s.startswith("gen-") for s in quick.scenes)  # a scene outside the benchmark suite
    full = protocol_spec("full", paper_birth=True)
    assert {v.label for v in full.variants} == {"full", "baseline", "full/paper-extraction"}
    single = protocol_spec("full", single_resolution=True)
    assert {v.label for v in single.variants} == {"full", "baseline", "full/single-resolution"}
    (variant,) = [v for v in single.variants if v.label == "full/single-resolution"]
    assert variant.extra == {"mapper": {"fine_surface.enabled": False, "free_space.enabled": False}}
    assert sum(s.startswith("bench-") for s in full.scenes) == 4 and sum(s.startswith("gen-") for s in full.scenes) >= 3
    with pytest.raises(ValueError, match="unknown scene"):
        ProtocolSpec(("nowhere",), (0, 1, 2))
    with pytest.raises(ValueError, match="unknown scene"):
        ProtocolSpec(("gen-12x",), (0,))


def test_a_held_out_room_is_named_by_its_seed_and_object_count():
    """gen-SEED[-OBJECTS]: a generated room the protocol does not hold, frames growing with its objects like the
    protocol's own rooms; the protocol's names keep their own definitions."""
    from scene_recon.bench.robustness import GENERATED, held_out_scene, scene_definition

    room = scene_definition("gen-1234-22")
    assert (room.name, room.seed, room.objects, room.frames) == ("gen-1234-22", 1234, 22, 168)
    assert held_out_scene("gen-99").objects == robustness.HELD_OUT_OBJECTS and held_out_scene("gen-99").frames == 120
    assert held_out_scene("gen-5-10").frames == 100 and held_out_scene("gen-5-40").frames == 300
    assert scene_definition("gen-4242") is GENERATED["gen-4242"]
    assert held_out_scene("bench-small") is None and held_out_scene("gen-") is None
    with pytest.raises(ValueError, match="4-40"):
        held_out_scene("gen-7-200")
    with pytest.raises(ValueError, match="unknown scene"):
        scene_definition("kitchen")
    assert ProtocolSpec(("gen-1234-14", "bench-small"), (0, 1)).scenes == ("gen-1234-14", "bench-small")
    with pytest.raises(ValueError, match="distinct"):
        ProtocolSpec(("bench-small",), (0, 0))
    with pytest.raises(ValueError):
        ProtocolSpec(("bench-small",), (0,), (Variant("x", "other"),))


def test_command_line_variants_are_typed_checked_against_the_schemas_and_run_beside_the_defaults():
    from recon_core.errors import ConfigError

    v = parse_variant(["label-keyframes", "mapper.keyframes.label_every_n_frames=0", "cad.front_ae_factor=0.25",
                       "mapper.fine_surface.enabled=true"])
    assert v == Variant("label-keyframes", "full", {"mapper": {"keyframes.label_every_n_frames": 0,
                                                                "fine_surface.enabled": True},
                                                     "cad": {"front_ae_factor": 0.25}})
    assert parse_variant(["plain-baseline", "mode=baseline"]) == Variant("plain-baseline", "baseline", {})
    spec = protocol_spec("full", extra_variants=(v,))
    assert [x.label for x in spec.variants] == ["full", "baseline", "label-keyframes"]
    with pytest.raises(ConfigError, match="label_evry"):  # a typo names itself before any run starts
        parse_variant(["typo", "mapper.keyframes.label_evry_n_frames=0"])
    with pytest.raises(ConfigError, match="sections"):
        parse_variant(["x", "mapping.tsdf.voxel_size_m=0.03"])
    with pytest.raises(ConfigError, match="label first"):
        parse_variant(["mapper.tsdf.voxel_size_m=0.03"])
    with pytest.raises(ConfigError, match="mode"):
        parse_variant(["x", "mode=fast"])
    with pytest.raises(ConfigError, match=r"SECTION\.KEY=VALUE"):
        parse_variant(["x", "mapper.tsdf.voxel_size_m"])


def test_the_noise_draw_is_part_of_a_maps_identity():
    from panoptic_mapping.config import MapperConfig
    from panoptic_mapping.dataio import DataInputConfig

    key = lambda draw: StageCache.map_key("bag", MapperConfig(), DataInputConfig(), "default", draw)  # noqa: E731
    assert key(0) != key(1) and key(1) == key(1)


@pytest.mark.slow
def test_a_tiny_protocol_end_to_end_writes_strict_json_a_table_and_a_plot(tmp_path, monkeypatch):
    monkeypatch.setenv("SCENE_RECON_CACHE", str(tmp_path / "cache"))
    monkeypatch.setitem(robustness.GENERATED, "gen-tiny", SuiteScene("gen-tiny", "tiny", 11, 3, 12))
    spec = ProtocolSpec(("gen-tiny",), (0, 1))
    lines: list[str] = []
    results = run_protocol(spec, tmp_path / "out", lines.append)
    assert [(r["draw"], r["mode"]) for r in results["rows"]] == [(0, "full"), (0, "baseline"), (1, "full"),
                                                                  (1, "baseline")]
    assert len(results["gt_rows"]) == 1 and results["gt_rows"][0]["scene"] == "gen-tiny"
    assert any("(4/4) gen-tiny draw 1 baseline" in line for line in lines)
    files = write_protocol_report(results, tmp_path / "out")
    text = files["json"].read_text(encoding="utf-8")

    def no_constants(name):
        raise ValueError(f"non-strict JSON constant {name}")

    data = json.loads(text, parse_constant=no_constants)
    assert data["summary"]["modes"]["full"]["runs"] == 2
    assert all(math.isfinite(r["map_ms_per_frame"]) and r["map_ms_per_frame"] > 0 for r in data["rows"])
    report = files["markdown"].read_text(encoding="utf-8")
    assert "| gen-tiny | full |" in report and "| gen-tiny | baseline |" in report
    # the per-class failure counts agree with the runs' own pose success
    for mode in ("full", "baseline"):
        counts = data["summary"]["modes"][mode]["pose_by_class"]
        placed = sum(c["objects"] for c in counts.values())
        correct = sum(c["successes"] for c in counts.values())
        runs = [r for r in data["rows"] if r["mode"] == mode]
        assert correct == sum(round(r["pose_success"] * r["matched_objects"]) for r in runs if r["matched_objects"])
        assert placed == sum(r["matched_objects"] or 0 for r in runs)
        assert placed > 0  # the tiny scene places CAD models in both variants
        for c in counts.values():
            assert all(c[k] <= c["objects"] - c["successes"] for k in ("translation", "yaw", "size"))
            assert c["objects"] == c["successes"] or max(c["translation"], c["yaw"], c["size"]) > 0
    assert "Why mapped CAD poses fail (full" in report and "| size > 15 % |" in report
    assert files["plot"].stat().st_size > 1000
    assert not (tmp_path / "out" / "work").exists()  # per-run folders are removed


def test_an_interrupted_protocol_continues_where_it_stopped(tmp_path, monkeypatch):
    """Results are journalled as they come; running the same protocol again computes only what is
    missing (a torn last line and another protocol's lines are ignored), and a finished run removes
    the journal."""
    from scene_recon.bench.robustness import JOURNAL_NAME, RunJournal

    calls: list[tuple[int, str]] = []

    def fake_pipeline(bag, gt, folder, spec, library, cache=None):
        calls.append((spec.noise_seed, spec.mode))
        return {"times_s": {"map": 1.0, "replace": 0.5}, "frames": 10, "pq": 80.0 + spec.noise_seed,
                "pq_things": 70.0, "box_mAP": 0.5, "ged_ratio": 0.1, "pose_success": 0.5, "pose_recall": 0.4,
                "ae_median_m": 0.01, "stillness": 1.0, "false_classes": []}

    monkeypatch.setattr(robustness, "run_pipeline", fake_pipeline)
    monkeypatch.setattr(robustness, "scene_paths", lambda scene, progress=False: (tmp_path / "bag", tmp_path / "gt"))
    spec = ProtocolSpec(("bench-small",), (0, 1), gt_entities=False)
    out = tmp_path / "out"
    out.mkdir()
    journal = RunJournal(out / JOURNAL_NAME, spec, {})
    journal.add(("run", "bench-small", 0, "full"), {**fake_pipeline(None, None, None, robustness.RunSpec(
        "x", noise_seed=0), None), "pq": 12.5, "scene": "bench-small", "draw": 0, "mode": "full",
        "map_ms_per_frame": 100.0, "replace_s": 0.5})
    calls.clear()
    with (out / JOURNAL_NAME).open("a") as f:
        f.write('{"identity": "another protocol", "key": ["run", "bench-small", 1, "full"], "row": {}}\n')
        f.write('{"identity": "torn')
    lines: list[str] = []
    results = run_protocol(spec, out, lines.append)
    assert sorted(calls) == [(0, "baseline"), (1, "baseline"), (1, "full")]  # the journalled run is kept
    assert results["resumed_results"] == 1 and any("resuming: 1 result" in line for line in lines)
    assert [r["pq"] for r in results["rows"] if r["mode"] == "full"] == [12.5, 81.0]
    assert not (out / JOURNAL_NAME).exists()
