"""Evaluate the contact-graph builder on generated scenes: GED (Table 5) and box mAP (Table 4).

Two settings, as in the paper's cg_map column plus an honest variant:
* complete: every ground-truth entity with its complete mesh (the paper's cg_map);
* observed: every mesh cut down to the faces the scene's recording saw (``observed.py``),
  optionally with the TSDF contact band; scored against the full ground truth (unseen entities
  are missing detections) and against the ground truth restricted to the seen entities (how well
  the graph is inferred from what was seen).

    .venv/bin/python -m scene_recon.evaluation.graph_evaluation [--seeds 20] [--recordings 4] \
        [--out out/scene_graph_eval]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from scene_graph.builder import build_contact_graph
from scene_graph.config import SceneGraphConfig, load_scene_graph_config
from scene_recon.evaluation.graph_ground_truth import ground_truth_graph, restrict_graph
from scene_recon.evaluation.graph_metrics import evaluate_graph
from scene_recon.evaluation.observed import ObservationConfig, camera_views, observed_entities
from scene_recon.synthetic.scene import GroundTruthScene, build_scene, entities_from_ground_truth

SUITE = ("bench-small", "bench-kitchen", "bench-office", "bench-clutter")


def _summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    gt = sum(r["ged"]["gt_nodes"] for r in rows)
    tot = sum(r["ged"]["total"] for r in rows)
    out = {"scenes": len(rows), "gt_nodes": gt, "ged_total": tot, "ged_ratio": tot / gt if gt else 0.0,
           "tree_edit_distance": sum(r["ged"]["tree_edit_distance"] for r in rows)}
    for k in ("wrong_support", "missing", "wrong_detection"):
        out[k] = sum(r["ged"][k] for r in rows)
    for k in ("box_map_refined", "box_map_unrefined"):
        out[k] = sum(r[k]["mAP"] for r in rows) / len(rows) if rows else 0.0
    return out


def _row(name: str, pred, gt, cfg: SceneGraphConfig) -> dict[str, Any]:
    r = evaluate_graph(pred, gt, cfg.match)
    r["scene"] = name
    r["build_s"] = pred.stats.get("total_s", 0.0)
    return r


def recordings(count: int, root: Path) -> list[tuple[Path, Path]]:
    """Extra generated recordings (20 objects, 150 frames, seeds 0..count-1), cached under ``root``."""
    from scene_recon.synthetic.generate import GenerateConfig, generate_recording, ground_truth_path

    out = []
    for seed in range(count):
        bag = root / f"room-seed{seed}"
        gt = ground_truth_path(bag)
        if not (gt / "generation.json").is_file():
            generate_recording(bag, GenerateConfig(objects=20, frames=150, seed=seed), progress=False)
        out.append((bag, gt))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=20, help="build_scene(20, seed) scenes for the complete setting")
    ap.add_argument("--recordings", type=int, default=4, help="extra generated recordings for the observed setting")
    ap.add_argument("--bands", type=float, nargs="+", default=[0.0, 0.03], help="TSDF contact bands (m)")
    ap.add_argument("--noise", type=float, default=0.005,
                    help="vertex noise (m) of an extra observed run (with the last band); 0 skips it")
    ap.add_argument("--out", default="out/scene_graph_eval")
    ap.add_argument("--config", help="builder config (default: config/scene_graph.yaml)")
    args = ap.parse_args(argv)
    from scene_recon.synthetic.suite import cache_root, suite_scene

    cfg = load_scene_graph_config(args.config)
    sources = [suite_scene(n, progress=False) for n in SUITE]
    sources += recordings(args.recordings, cache_root().parent / "scene_graph_eval")
    scenes = [(bag, GroundTruthScene.load(gt)) for bag, gt in sources]
    report: dict[str, Any] = {"complete": {}, "observed": {}}

    rows = []
    for _, s in scenes:
        rows.append(_row(s.name, build_contact_graph(entities_from_ground_truth(s), cfg, name=s.name),
                         ground_truth_graph(s), cfg))
    for seed in range(args.seeds):
        s = build_scene(20, seed, name=f"build_scene-20-{seed}")
        rows.append(_row(s.name, build_contact_graph(entities_from_ground_truth(s), cfg, name=s.name),
                         ground_truth_graph(s), cfg))
    report["complete"] = {"summary": _summary(rows), "rows": rows}
    print(f"complete meshes (cg_map): {json.dumps(report['complete']['summary'])}")

    variants = [(band, 0.0) for band in args.bands]
    if args.noise > 0.0:
        variants.append((args.bands[-1], args.noise))
    for band, noise in variants:
        obs_cfg = ObservationConfig(contact_band=band, vertex_noise=noise)
        full_rows, seen_rows = [], []
        for bag, s in scenes:
            ents, _ = observed_entities(s, camera_views(bag, obs_cfg), obs_cfg)
            graph = build_contact_graph(ents, cfg, name=s.name)
            gt = ground_truth_graph(s)
            full_rows.append(_row(s.name, graph, gt, cfg))
            seen_rows.append(_row(s.name, graph, restrict_graph(gt, {e.id for e in ents}), cfg))
        key = f"band_{band:.3f}_noise_{noise:.3f}"
        report["observed"][key] = {"vs_full_gt": {"summary": _summary(full_rows), "rows": full_rows},
                                   "vs_seen_gt": {"summary": _summary(seen_rows), "rows": seen_rows}}
        print(f"observed ({key}) vs full GT: {json.dumps(_summary(full_rows))}")
        print(f"observed ({key}) vs seen GT: {json.dumps(_summary(seen_rows))}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "evaluation.json").write_text(json.dumps(report, indent=1, default=float), encoding="utf-8")
    print(f"wrote {out / 'evaluation.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
