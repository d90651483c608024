"""`scene-recon eval-graph PRED GROUNDTRUTH`: GED (Table 5) and oriented-box mAP (Table 4)."""

from __future__ import annotations

import argparse

from scene_recon.commands.common import print_json


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "eval-graph",
        help="compare a contact graph with a scene's ground truth (GED, box mAP)",
        description="Match the predicted nodes to the ground-truth nodes (class + 3D box overlap, Hungarian), then "
        "print the graph edit distance as in the paper's Table 5 (total = 2 x wrong support + missing + wrong "
        "detection), the exact tree edit distance under that matching, and the oriented 3D box mAP@0.5 of the "
        "refined and the unrefined boxes (Table 4); then the same restricted to what the recording saw (ground-truth "
        "entities with enough visible pixels; predictions matched to unseen entities are left out too).",
    )
    p.add_argument("prediction", help="contact_graph.json written by 'scene-recon graph'")
    p.add_argument("groundtruth", help="ground-truth folder (scene.json)")
    p.add_argument("--config", metavar="YAML", help="builder config with the match settings (default: "
                   "config/scene_graph.yaml)")
    p.add_argument("--seen-min-pixels", type=int, metavar="N",
                   help="seen-only figures: a ground-truth entity counts as seen from N visible pixels over the "
                   "recording (default: match.seen_min_pixels of the config)")
    p.add_argument("--json", action="store_true", help="print the figures as JSON")
    p.add_argument("--force", action="store_true",
                   help="score even when the graph and the ground truth come from different generated scenes "
                   "(refused otherwise: exit 2); a warning says so")
    p.set_defaults(func=run)


def _print(result: dict, indent: str = "") -> None:
    g = result["ged"]
    print(f"{indent}ground-truth nodes: {g['gt_nodes']}   predicted nodes: {g['pred_nodes']}")
    print(f"{indent}GED total: {g['total']}  ({100 * g['ratio']:.1f}% of ground-truth nodes)   "
          f"exact tree edit distance: {g['tree_edit_distance']}")
    print(f"{indent}  wrong support:   {g['wrong_support']}  (x2 operations)  {', '.join(g['wrong_support_nodes'])}")
    print(f"{indent}  missing:         {g['missing']}  {', '.join(g['missing_nodes'])}")
    print(f"{indent}  wrong detection: {g['wrong_detection']}  {', '.join(g['extra_nodes'])}")
    for key, label in (("box_map_refined", "refined"), ("box_map_unrefined", "unrefined")):
        m = result[key]
        per = ", ".join(f"{c} {100 * v:.0f}" for c, v in m["per_class"].items())
        print(f"{indent}box mAP@{m['iou_threshold']:.1f} ({label}): {100 * m['mAP']:.1f}   [{per}]")


def run(args: argparse.Namespace) -> int:
    from recon_core.contact_graph import ContactGraph, GraphError
    from scene_graph.config import load_scene_graph_config
    from scene_recon.evaluation.graph_ground_truth import ground_truth_graph, seen_entity_ids
    from scene_recon.evaluation.graph_metrics import evaluate_graph
    from scene_recon.synthetic.scene import GroundTruthScene

    cfg = load_scene_graph_config(args.config)
    if args.seen_min_pixels is not None:
        cfg.match.seen_min_pixels = args.seen_min_pixels
    from scene_recon.commands.scene_identity import check_same_scene, graph_identity

    check_same_scene(f"the graph {args.prediction}", graph_identity(args.prediction), args.groundtruth,
                     args.force, "eval-graph")
    try:
        pred = ContactGraph.load(args.prediction)
    except (OSError, GraphError) as exc:
        raise FileNotFoundError(f"cannot read the predicted graph: {exc}") from exc
    try:
        scene = GroundTruthScene.load(args.groundtruth)
    except (OSError, ValueError, KeyError) as exc:
        raise FileNotFoundError(f"cannot read the ground truth {args.groundtruth}: {exc}") from exc
    seen = seen_entity_ids(scene, cfg.match.seen_min_pixels)
    result = evaluate_graph(pred, ground_truth_graph(scene), cfg.match, seen)
    if args.json:
        print_json(result)
        return 0
    _print(result)
    if seen is None:
        print("seen-only: not available (the ground truth records no visible_pixels)")
        return 0
    r = result["seen_only"]
    print(f"seen only (ground-truth entities with >= {cfg.match.seen_min_pixels} visible pixels over the recording):")
    print(f"  unseen, left out: {', '.join(r['unseen_gt_nodes']) or '-'}")
    if r["void_predictions"]:
        print(f"  predictions matched to unseen entities, left out: {', '.join(r['void_predictions'])}")
    _print(r, "  ")
    return 0
