"""`scene-recon eval-scene DIR GROUND_TRUTH`: score a replaced scene against a generated scene's ground truth."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from scene_recon.commands.common import print_json


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "eval-scene",
        help="score a replaced scene (CAD poses, articulation, interpenetration, support gaps, physics)",
        description="Compare the folder written by `scene-recon replace` with a ground-truth folder: per object "
        "pose success (translation <= 10 cm, yaw <= 15 deg up to symmetry, size <= 15 %%), front flips, "
        "Alignment Error, joint types/axes/values; interpenetration and support gaps; and (unless --no-physics) "
        "the exported scene simulated 2 s in PyBullet and MuJoCo (movable objects that stay within 2 cm).",
    )
    p.add_argument("scene", help="folder written by `scene-recon replace` (replacement.json, scene.urdf, ...)")
    p.add_argument("ground_truth", help="ground-truth folder (<bag>_groundtruth with scene.json)")
    p.add_argument("--seeds-per-class", type=int, default=10, metavar="N",
                   help="the library the scene was replaced with (default: 10)")
    p.add_argument("--cad-dir", metavar="DIR", help="imported CAD assets used by the replacement")
    p.add_argument("--no-physics", action="store_true", help="skip the PyBullet/MuJoCo check")
    p.add_argument("--json", action="store_true", help="print every figure as JSON")
    p.add_argument("--force", action="store_true",
                   help="score even when the replaced scene and the ground truth come from different generated scenes "
                   "(refused otherwise: exit 2); a warning says so")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from cad_replacement.cad.library import CadLibrary
    from recon_core.contact_graph import ContactGraph
    from scene_recon.commands.scene_identity import check_same_scene, scene_folder_identity
    from scene_recon.evaluation.scene_eval import evaluate_scene, scene_from_folder
    from scene_recon.synthetic.scene import GroundTruthScene

    check_same_scene(f"the replaced scene {args.scene}", scene_folder_identity(args.scene), args.ground_truth,
                     args.force, "eval-scene")
    library = CadLibrary(root=args.cad_dir, seeds_per_class=args.seeds_per_class)
    scene, records = scene_from_folder(args.scene, library)
    gt = GroundTruthScene.load(Path(args.ground_truth))
    graph_file = Path(args.scene) / "contact_graph.json"
    graph = ContactGraph.load(graph_file) if graph_file.is_file() else None
    figures = evaluate_scene(scene, records, gt, library, None if args.no_physics else args.scene, graph)
    if args.json:
        print_json(figures)
        return 0
    o = figures["objects"]
    print(f"matched {figures['matched']} of {figures['ground_truth_objects']} ground-truth objects "
          f"({figures['replaced_objects']} replaced)")
    if o.get("objects"):
        ae_med, ae_p90 = o["ae_median"], o["ae_p90"]
        print(f"pose success {100 * o['pose_success']:.1f} %, front flips {100 * o['front_flips']:.1f} %, "
              f"AE median {1000 * ae_med if ae_med is not None else float('nan'):.1f} mm / p90 "
              f"{1000 * ae_p90 if ae_p90 is not None else float('nan'):.1f} mm, "
              f"articulation type/count {100 * o['articulation_type_count_ok']:.1f} %")
    print(f"max interpenetration {100 * figures['max_interpenetration_m']:.1f} cm "
          f"({figures['interpenetrating_pairs_over_1cm']} pairs over 1 cm); support gap max "
          f"{1000 * (figures['support_gap_max_m'] or 0.0):.1f} mm")
    if "ged_after" in figures:
        b, a = figures["ged_before"], figures["ged_after"]
        print(f"contact graph GED against the ground truth: {b['total']} before, {a['total']} after replacement "
              f"(wrong supports {b['wrong_support']} -> {a['wrong_support']})")
    for engine, rep in figures.get("physics", {}).items():
        still = rep.get("still_fraction")
        drifts = [d for d in (rep.get("displacement") or {}).values() if d is not None and math.isfinite(d)]
        moved = max(drifts, default=None)
        print(f"{engine}: {'loaded' if rep.get('loaded') else 'NOT loaded'}, still "
              + (f"{100 * still:.1f} %" if still is not None else "-")
              + (f" of the movable objects (largest drift {100 * moved:.1f} cm)" if moved is not None else ""))
        for error in rep.get("errors", [])[:3]:
            print(f"  {engine} error: {error}")
    return 0
