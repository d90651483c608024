"""`scene-recon graph -> replace -> eval-scene` on a generated scene's ground truth: the stage-4 CLI."""

from __future__ import annotations

import json

import yourdfpy

from scene_recon.cli import main
from scene_recon.synthetic.scene import build_scene


def test_replace_writes_a_loadable_scene_folder_and_eval_scene_scores_it(tmp_path, capsys):
    scene = build_scene(8, 5)
    gt_dir = tmp_path / "room_groundtruth"
    scene.save(gt_dir)
    assert main(["graph", str(gt_dir), "--out", str(tmp_path / "graph")]) == 0
    out = tmp_path / "scene"
    assert main(["replace", str(tmp_path / "graph"), "--out", str(out), "--seeds-per-class", "3"]) == 0
    text = capsys.readouterr().out
    assert "before_after.png" in text
    for name in ("scene.urdf", "static.urdf", "scene.xml", "scene.glb", "joint_states.json", "replacement.json",
                 "before_after.png", "contact_graph.json"):
        assert (out / name).is_file(), name
    urdf = yourdfpy.URDF.load(str(out / "scene.urdf"), load_meshes=False)
    assert urdf.validate() and urdf.base_link == "map"
    detail = json.loads((out / "replacement.json").read_text())
    cad = [o for o in detail["objects_detail"] if o["kind"] == "cad"]
    assert cad and all(o["candidates"] and o["cad_id"] for o in cad)
    assert main(["eval-scene", str(out), str(gt_dir), "--seeds-per-class", "3", "--json"]) == 0
    figures = json.loads(capsys.readouterr().out)
    # every object is accounted for: CAD-placed and matched, or kept as its observed mesh by the stage-4
    # gate (this 3-model library explains some objects too poorly), never lost
    fallbacks = sum(1 for o in detail["objects_detail"] if o["kind"] == "observed_mesh" and o["candidates"])
    assert figures["matched"] + fallbacks == figures["ground_truth_objects"] > 0 and figures["matched"] > 0
    assert figures["objects"]["pose_success"] >= 0.75
    assert figures["max_interpenetration_m"] <= 0.01
    # The support tree is kept. (The GED total is not asserted: this library does not hold the
    # scene's own models, and its cabinet's drawer is 4.9 cm lower than the scene's, so book_1's CAD
    # box overlaps its true box by IoU 0.10, at the matching threshold; bench_cad measures the GED
    # unchanged with the scene's models in the library.)
    assert figures["ged_after"]["wrong_support"] == 0 and figures["ged_before"]["total"] == 0
    for engine in ("pybullet", "mujoco"):
        assert figures["physics"][engine]["loaded"]
        # the plumbing: both engines load the folder and the scene mostly stands still (the suite-wide
        # stillness rate is measured by benchmarks/bench_cad.py)
        assert figures["physics"][engine]["still_fraction"] >= 0.8, figures["physics"][engine]


def test_replace_says_what_to_run_first(tmp_path, capsys):
    assert main(["replace", str(tmp_path / "nowhere"), "--out", str(tmp_path / "scene")]) == 2
    assert "scene-recon graph" in capsys.readouterr().err


def test_replace_writes_the_same_scene_folder_with_the_caches_a_previous_run_left(tmp_path, monkeypatch):
    """Issue 23 item 4: a second run of the same graph reads its results, models and geometry from the caches
    the first left (no fit, no model built) and writes the same scene folder, byte for byte (the summary's
    timings aside)."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    scene = build_scene(14, 5)  # at least ``parallel_min_objects`` (12): the workers and their stores
    gt_dir = tmp_path / "room_groundtruth"
    scene.save(gt_dir)
    assert main(["graph", str(gt_dir), "--out", str(tmp_path / "graph"), "--no-picture"]) == 0
    outs = [tmp_path / "cold", tmp_path / "warm"]
    for out in outs:
        assert main(["replace", str(tmp_path / "graph"), "--out", str(out), "--seeds-per-class", "3"]) == 0
    assert list((tmp_path / "cache" / "scene_recon" / "cad_models").glob("*.npz"))
    files = [sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file()) for out in outs]
    assert files[0] == files[1] and len(files[0]) > 20
    for rel in files[0]:
        if rel.name != "replacement.json":
            assert (outs[0] / rel).read_bytes() == (outs[1] / rel).read_bytes(), rel

    def strip(value):
        if isinstance(value, dict):
            return {k: strip(v) for k, v in value.items() if k not in ("timings", "wall_s", "phases_s", "urdf")}
        return [strip(v) for v in value] if isinstance(value, list) else value

    cold, warm = (json.loads((out / "replacement.json").read_text()) for out in outs)
    assert strip(cold) == strip(warm)
    restored = [o for o in warm["objects_detail"] if o["candidates"]]
    assert restored and all("restored_s" in o["timings"] for o in restored)
