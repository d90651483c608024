"""Stage 4 from ground-truth entities over the robustness protocol's scenes and more (issue 23, item 1).

For each scene (the four suite scenes, the protocol's generated scenes ``gen-*``, and further generated
rooms ``seed:<seed>:<objects>`` built on the fly, no rendering needed: ground-truth entities carry
their complete meshes) the contact graph of the exact entities goes through ``CadReplacer`` with the
physical check, in up to three settings on the same graph:

  in-library   our method, a library holding the scene's own models (plus 10 seeds per class)
  unseen       our method, the default library (10 seeds per class; the scenes' seeds are never in it)
  paper        the paper's method on the unseen library

Per scene and setting: pose success, front flips, hinge axes within 10 deg and joint values within
tolerance over the articulated parts' joints, and the per-object failures (yaw error, size error,
chosen model) so a regression names its object. Physics is not simulated here (``bench_cad.py`` does).

    .venv/bin/python benchmarks/bench_cad_protocol.py [--scenes bench-small gen-4242 seed:11:20 ...]
        [--settings in-library unseen paper] [--json out.json]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from cad_replacement.cad.library import CadLibrary
from cad_replacement.physical_check import PhysicalCheck
from cad_replacement.replace_config import CadReplacementConfig
from cad_replacement.replacer import CadReplacer
from cad_replacement.seeded_library import SeededLibrary
from scene_graph.builder import ContactGraphBuilder
from scene_graph.config import load_scene_graph_config
from scene_recon.bench.robustness import GENERATED
from scene_recon.evaluation.scene_eval import evaluate_scene
from scene_recon.synthetic.scene import GroundTruthScene, build_scene, entities_from_ground_truth
from scene_recon.synthetic.suite import SUITE, scene_paths

#: The protocol's scenes (suite + generated) and, by default, four more generated rooms (20 objects each).
DEFAULT_SCENES = (*SUITE, *GENERATED, "seed:11:20", "seed:23:20", "seed:31:20", "seed:47:20")


def load_scene(name: str) -> GroundTruthScene:
    """Ground truth of a suite / protocol scene (cached recording) or of ``seed:<seed>:<objects>``."""
    if name.startswith("seed:"):
        _, seed, objects = name.split(":")
        return build_scene(int(objects), int(seed), name=name.replace(":", "-"))
    definition = SUITE.get(name) or GENERATED.get(name)
    if definition is None:
        raise SystemExit(f"unknown scene {name!r}")
    _bag, gt_dir = scene_paths(definition, progress=False)
    return GroundTruthScene.load(gt_dir)


def joint_detail(scene: Any, gt: GroundTruthScene, names: set[str]) -> dict[str, list[dict[str, Any]]]:
    """Per object of ``names``: its ground-truth joints paired with the placed model's as ``evaluate_object``
    pairs them (map-frame origins), each with the axis angle (deg) and both values (rad / m; the fitted one
    signed along the ground-truth axis, as the evaluation compares them)."""
    from scene_recon.evaluation.cad_metrics import _joint_frames

    out: dict[str, list[dict[str, Any]]] = {}
    placed = {o.name: o for o in scene}
    for e in gt.entities:
        obj, gt_model = placed.get(e.name), gt.model_of(e) if e.name in names else None
        if obj is None or gt_model is None or not gt_model.movable_joints:
            continue
        gtj = _joint_frames(gt_model, e.pose, e.joint_values)
        estj = _joint_frames(obj.model, obj.pose, obj.joint_values)
        gk, ek = list(gtj), list(estj)
        cost = np.array([[float(np.linalg.norm(gtj[g][1] - estj[k][1])) + 100.0 * (gtj[g][0] != estj[k][0])
                          for k in ek] for g in gk]).reshape(len(gk), len(ek))
        pairs = dict(zip(*linear_sum_assignment(cost), strict=True)) if cost.size else {}
        rows = []
        for i, gname in enumerate(gk):
            g = gtj[gname]
            row: dict[str, Any] = {"joint": gname, "type": g[0], "expected": round(g[3], 3)}
            if i in pairs:
                est = estj[ek[pairs[i]]]
                dot = float(g[2] @ est[2])
                row.update(paired=ek[pairs[i]], fitted=round(est[3] * (1.0 if dot >= 0.0 else -1.0), 3),
                           origin_gap=round(float(np.linalg.norm(g[1] - est[1])), 3),
                           axis_deg=round(float(np.degrees(np.arccos(min(abs(dot), 1.0)))), 1))
            rows.append(row)
        out[e.name] = rows
    return out


def run(gt: GroundTruthScene, library: CadLibrary, method: str) -> dict[str, Any]:
    builder = ContactGraphBuilder(load_scene_graph_config())
    builder.update(entities_from_ground_truth(gt))
    graph, nodes = builder.build(name=gt.name), builder.node_entities()
    config = CadReplacementConfig(method=method, workers=1)
    t0, c0 = time.perf_counter(), time.process_time()
    with CadReplacer(library, config, physical_check=PhysicalCheck(method=method)) as replacer:
        result = replacer.replace(graph, nodes)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    with contextlib.redirect_stdout(io.StringIO()):
        figures = evaluate_scene(result.scene, {r.name: r.to_dict() for r in result.records}, gt, library, None)
    cad = sum(1 for r in result.records if r.kind == "cad")
    per = figures["per_object"]
    seen = {o["name"] for o in per}
    reasons = {r.name: r.reason or r.message for r in result.records}
    unmatched = [f"{e.name}: {reasons.get(e.name) or 'placed elsewhere'}" for e in gt.entities
                 if e.model_seed is not None and e.name not in seen]
    joints = sum(o["joints_total"] for o in per)
    wrong = {o["name"] for o in per if o["axis_ok"] < o["joints_total"] or o["value_ok"] < o["joints_total"]}
    detail = joint_detail(result.scene, gt, wrong)
    return {
        "objects": len(per), "ground_truth_objects": figures["ground_truth_objects"],
        "pose_success": figures["objects"].get("pose_success"),
        "front_flips": sum(1 for o in per if o["front_flip"]),
        "joints": joints, "axis_ok": sum(o["axis_ok"] for o in per), "value_ok": sum(o["value_ok"] for o in per),
        "seconds": seconds, "per_object_s": seconds / max(cad, 1), "per_object_cpu_s": cpu / max(cad, 1),
        "unmatched": unmatched,
        "failures": [{k: o[k] for k in ("name", "class_name", "chosen", "symmetry", "translation_error",
                                        "yaw_error_deg", "size_error", "front_flip", "joints_total", "axis_ok",
                                        "value_ok")}
                     for o in per if not o["pose_success"] or o["axis_ok"] < o["joints_total"]
                     or o["value_ok"] < o["joints_total"]],
        "joint_detail": detail,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", nargs="+", default=list(DEFAULT_SCENES))
    parser.add_argument("--settings", nargs="+", default=["in-library", "unseen", "paper"],
                        choices=["in-library", "unseen", "paper"])
    parser.add_argument("--json", type=Path, help="write every row here")
    parser.add_argument("--quiet", action="store_true", help="no per-object failure lines")
    args = parser.parse_args(argv)
    unseen = CadLibrary(seeds_per_class=10)
    rows: list[dict[str, Any]] = []
    for name in args.scenes:
        gt = load_scene(name)
        seeds: dict[str, list[int]] = {}
        for e in gt.entities:
            if e.model_seed is not None:
                seeds.setdefault(e.class_name, []).append(int(e.model_seed))
        for setting in args.settings:
            library = SeededLibrary(extra_seeds=seeds) if setting == "in-library" else unseen
            row = run(gt, library, "paper" if setting == "paper" else "ours")
            row.update(scene=name, setting=setting)
            rows.append(row)
            axis = f"{row['axis_ok']}/{row['joints']}"
            print(f"{name:14s} {setting:10s} pose {100 * (row['pose_success'] or 0):5.1f} % "
                  f"({row['objects']}/{row['ground_truth_objects']} matched) flips {row['front_flips']} "
                  f"hinge axes {axis} values {row['value_ok']}/{row['joints']} "
                  f"{row['per_object_s'] * 1000:.0f} ms/object ({row['per_object_cpu_s'] * 1000:.0f} ms CPU)",
                  flush=True)
            if not args.quiet:
                for u in row["unmatched"]:
                    print(f"    not matched: {u}", flush=True)
                for f in row["failures"]:
                    print(f"    {f['name']:22s} {f['chosen']:52s} t {100 * (f['translation_error'] or 0):5.1f} cm "
                          f"yaw {f['yaw_error_deg'] or 0:5.1f} size {f['size_error'] or 0:.2f} sym {f['symmetry']} "
                          f"flip {f['front_flip']} axes {f['axis_ok']}/{f['joints_total']} "
                          f"values {f['value_ok']}/{f['joints_total']}", flush=True)
                    for j in row["joint_detail"].get(f["name"], []):
                        print(f"        {j['joint']:12s} {j['type']:9s} expected {j['expected']:6.3f} "
                              f"fitted {j.get('fitted', float('nan')):6.3f} "
                              f"axis {j.get('axis_deg', float('nan')):5.1f} deg "
                              f"origin gap {100 * j.get('origin_gap', float('nan')):5.1f} cm", flush=True)
    print("\nsetting     pose success mean / min   flips  hinge axes  joint values  ms/object (CPU)")
    for setting in args.settings:
        sel = [r for r in rows if r["setting"] == setting]
        if not sel:
            continue
        pose = [r["pose_success"] or 0.0 for r in sel]
        joints = sum(r["joints"] for r in sel)
        print(f"{setting:10s}  {100 * np.mean(pose):5.1f} % / {100 * np.min(pose):5.1f} %   "
              f"{sum(r['front_flips'] for r in sel):5d}  "
              f"{100 * sum(r['axis_ok'] for r in sel) / max(joints, 1):5.1f} %     "
              f"{100 * sum(r['value_ok'] for r in sel) / max(joints, 1):5.1f} %      "
              f"{1000 * np.mean([r['per_object_s'] for r in sel]):.0f} "
              f"({1000 * np.mean([r['per_object_cpu_s'] for r in sel]):.0f})")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
