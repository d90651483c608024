"""Fit quality of correct against wrong CAD fits on suite scenes: the data behind stage 4's acceptance gate.

For every object node of a suite scene (ground-truth entities, and the scene mapped with the oracle
when ``--maps DIR`` holds ``DIR/<scene>/entities.json``), every fully fitted candidate of
``replace_object`` (the gate off) is scored against the ground truth (``cad_metrics.evaluate_object``:
pose success = translation <= 10 cm, yaw <= 15 deg, size <= 15 %) and its fit figures are written
one row per candidate: the paper's AE (``ae_points``), the two-sided AE, the coverages, the observed
box diagonal, and whether it was the one selected. ``--summary`` prints the distributions of correct
and wrong fits and what a gate (``--ae-rel``, ``--ae-min``, ``--ae-max``, ``--coverage``) keeps.

    .venv/bin/python tools/real_data/cad_gate_data.py --scenes bench-small bench-kitchen \\
        --maps /work/realdata/gate/maps --out /work/realdata/gate/fits.json
    .venv/bin/python tools/real_data/cad_gate_data.py --summary /work/realdata/gate/fits.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))


def collect(scenes: list[str], maps: Path | None) -> list[dict[str, Any]]:
    from cad_replacement.cad.library import CadLibrary
    from cad_replacement.matching import candidate_classes
    from cad_replacement.observation import ObservationError
    from cad_replacement.replace_config import CadReplacementConfig
    from cad_replacement.replace_object import replace_object
    from cad_replacement.replacer import LAYOUT, CadReplacer
    from recon_core.entity import load_entities
    from scene_graph.builder import ContactGraphBuilder
    from scene_graph.config import load_scene_graph_config
    from scene_recon.evaluation.cad_metrics import evaluate_object
    from scene_recon.synthetic.scene import GroundTruthScene, entities_from_ground_truth
    from scene_recon.synthetic.suite import suite_scene

    cfg = CadReplacementConfig(accept_gate=False, workers=1)
    library = CadLibrary()
    rows: list[dict[str, Any]] = []
    for name in scenes:
        _bag, gt_dir = suite_scene(name)
        gt = GroundTruthScene.load(gt_dir)
        gt_objects = [e for e in gt.entities if e.model_seed is not None]
        settings = [("gt", entities_from_ground_truth(gt))]
        if maps is not None and (maps / name / "entities.json").is_file():
            settings.append(("mapped", load_entities(maps / name)))
        for setting, ents in settings:
            builder = ContactGraphBuilder(load_scene_graph_config())
            builder.update(ents)
            graph, nodes = builder.build(name=name), builder.node_entities()
            replacer = CadReplacer(library, cfg)
            walls = [p.plane for n in graph.nodes.values() if n.category == LAYOUT and n.class_name == "wall"
                     for p in n.planes if abs(p.plane.normal[2]) < 0.3]
            obstacles = [n.box for n in graph.nodes.values() if n.box is not None and n.id != graph.root_id]
            for nid, node in graph.nodes.items():
                if nid == graph.root_id or node.category == LAYOUT or nid not in nodes or nodes[nid].is_empty:
                    continue
                try:
                    obs = replacer._observation(node, nodes[nid], graph, walls, obstacles)
                except ObservationError:
                    continue
                ok = set(candidate_classes(node.class_name))
                assert node.box is not None
                near = [(float(np.linalg.norm(np.asarray(e.box.center) - node.box.center)), e) for e in gt_objects
                        if e.class_name in ok]
                near = [(d, e) for d, e in near if d <= 0.5]
                target = min(near, key=lambda it: it[0])[1] if near else None
                rep = replace_object(obs, library, cfg, cache=replacer.cache)
                diag = float(np.linalg.norm(obs.gravity_box.size))
                for rank, cand in enumerate(c for c in rep.candidates if c.stage == "full"):
                    success = None
                    if target is not None:
                        one = dataclasses.replace(rep, chosen=cand, model=replacer.cache.get(cand.match.entry).model)
                        gt_model = gt.model_of(target)
                        assert gt_model is not None
                        ev = evaluate_object(one, gt_model, target.pose, target.joint_values)
                        success = bool(ev.pose_success)
                    rows.append({
                        "scene": name, "setting": setting, "node": node.name, "class": node.class_name,
                        "gt_class": target.class_name if target is not None else None,
                        "cand_class": cand.class_name, "cad_id": cand.key, "rank": rank, "chosen": rank == 0,
                        "diag": diag, "size": [float(v) for v in obs.gravity_box.size],
                        "ae": cand.ae.ae, "ae_points": cand.ae.ae_points, "ae_model": cand.ae.ae_model,
                        "coverage": _num(cand.ae.coverage), "view_coverage": _num(cand.ae.view_coverage),
                        "success": success})
                print(f"{name} {setting} {node.name}: {len(rep.candidates)} candidates", flush=True)
    return rows


def _num(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def summary(rows: list[dict[str, Any]], ae_rel: float, ae_min: float, ae_max: float, coverage: float) -> None:
    """Distributions of correct vs wrong fits and what the given gate keeps."""
    def pct(v: list[float], q: float) -> str:
        return f"{1000 * np.percentile(v, q):5.1f}" if v else "    -"

    for setting in sorted({r["setting"] for r in rows}):
        for chosen_only in (True, False):
            sel = [r for r in rows if r["setting"] == setting and r["success"] is not None
                   and (r["chosen"] or not chosen_only)]
            good = [r for r in sel if r["success"]]
            bad = [r for r in sel if not r["success"]]
            print(f"{setting} {'chosen' if chosen_only else 'all full fits'}: {len(good)} correct, {len(bad)} wrong")
            for key in ("ae_points", "ae", "ae_model"):
                g = [r[key] for r in good]
                b = [r[key] for r in bad]
                print(f"  {key:10s} mm correct p50 {pct(g, 50)} p90 {pct(g, 90)} p95 {pct(g, 95)} max {pct(g, 100)}"
                      f" | wrong p10 {pct(b, 10)} p50 {pct(b, 50)}")
            for key in ("view_coverage", "coverage"):
                g = [r[key] for r in good if r[key] is not None]
                b = [r[key] for r in bad if r[key] is not None]
                q = lambda v, p: f"{np.percentile(v, p):.2f}" if v else "-"  # noqa: E731
                print(f"  {key:13s} correct p5 {q(g, 5)} p10 {q(g, 10)} p50 {q(g, 50)} | wrong p50 {q(b, 50)}"
                      f" p90 {q(b, 90)}")

            def keep(r: dict[str, Any]) -> bool:
                limit = float(np.clip(ae_rel * r["diag"], ae_min, ae_max))
                cov = r["view_coverage"]
                return r["ae_points"] <= limit and (cov is None or cov >= coverage)

            print(f"  gate rel {ae_rel} min {ae_min} max {ae_max} cov {coverage}: keeps "
                  f"{sum(map(keep, good))}/{len(good)} correct, {sum(map(keep, bad))}/{len(bad)} wrong")
        rej = [r for r in rows if r["setting"] == setting and r["chosen"] and r["success"]
               and not (r["ae_points"] <= float(np.clip(ae_rel * r["diag"], ae_min, ae_max))
                        and (r["view_coverage"] is None or r["view_coverage"] >= coverage))]
        for r in rej:
            print(f"    rejected correct: {r['scene']} {r['node']} {r['cad_id']} diag {r['diag']:.2f} "
                  f"AE {1000 * r['ae_points']:.1f} mm cov {r['view_coverage']}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenes", nargs="+", default=["bench-small", "bench-kitchen"])
    p.add_argument("--maps", type=Path, help="folder of mapped scenes <DIR>/<scene>/entities.json")
    p.add_argument("--out", type=Path, help="write the rows here (JSON)")
    p.add_argument("--summary", type=Path, help="summarise rows written before (no fitting)")
    p.add_argument("--ae-rel", type=float, default=0.02)
    p.add_argument("--ae-min", type=float, default=0.02)
    p.add_argument("--ae-max", type=float, default=0.05)
    p.add_argument("--coverage", type=float, default=0.5)
    args = p.parse_args(argv)
    if args.summary:
        rows = json.loads(args.summary.read_text())
    else:
        rows = collect(args.scenes, args.maps)
        if args.out:
            args.out.write_text(json.dumps(rows, indent=0, allow_nan=False))
    summary(rows, args.ae_rel, args.ae_min, args.ae_max, args.coverage)
    return 0


if __name__ == "__main__":
    sys.exit(main())
