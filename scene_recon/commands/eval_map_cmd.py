"""`scene-recon eval-map MAPDIR GROUNDTRUTH`: 3D panoptic quality and instance mAP of a mapped scene."""

from __future__ import annotations

import argparse
import sys
from dataclasses import fields
from pathlib import Path

from scene_recon.commands.common import print_json
from scene_recon.commands.scene_identity import check_same_scene, map_identity
from scene_recon.evaluation.map_metrics import PAPER_CLASSES, MetricsConfig, PanopticMetrics, evaluate_panoptic_map

#: Protocol options of the command line: (flag, MetricsConfig field, type, help).
_PROTOCOL_OPTIONS = (
    ("--sample-spacing", "sample_spacing", float, "m between ground-truth surface samples"),
    ("--contact-distance", "contact_distance", float, "m; GT points blocked this close by another entity are hidden"),
    ("--observed-distance", "observed_distance", float, "m; GT points farther from the map were never observed"),
    ("--transfer-distance", "transfer_distance", float, "m; a GT point takes the nearest predicted label within this"),
    ("--min-gt-points", "min_gt_points", int, "GT entities with fewer observed points are ignored (not misses)"),
    ("--iou-threshold", "iou_threshold", float, "a match needs IoU strictly above this"),
)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "eval-map",
        help="3D panoptic quality (PQ/SQ/RQ) and instance mAP@0.5 of a mapped scene",
        description="Compare a mapped scene (entities.json + meshes, written by `scene-recon map`) with the "
        "ground truth of a generated scene: per-class PQ, SQ, RQ (paper Eq. 15), TP/FP/FN and instance AP, "
        "and their class averages (all / stuff / things, mAP). Labels are transferred to the observed "
        "ground-truth surface; see panoptic_mapping/metrics.py for the protocol. Values are percentages.",
    )
    p.add_argument("map", metavar="MAPDIR", help="mapped scene folder (entities.json + meshes/)")
    p.add_argument("ground_truth", metavar="GROUNDTRUTH",
                   help="ground-truth folder (<bag>_groundtruth with scene.json) or the generated bag beside it")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.add_argument("--force", action="store_true",
                   help="score even when the map and the ground truth come from different generated scenes "
                   "(refused otherwise: exit 2); a warning says so")
    p.add_argument("--classes", nargs="+", metavar="CLASS",
                   help="evaluate only these classes; 'paper' = the paper's 10 classes "
                   f"({', '.join(PAPER_CLASSES)})")
    g = p.add_argument_group("protocol (defaults: scene_recon.evaluation.map_metrics.MetricsConfig)")
    for flag, name, kind, text in _PROTOCOL_OPTIONS:
        g.add_argument(flag, type=kind, dest=name, metavar="X", help=f"{text} (default: {_default(name)})")
    p.set_defaults(func=run)


def _default(name: str) -> object:
    return next(f.default for f in fields(MetricsConfig) if f.name == name)


def resolve_ground_truth(path: str | Path) -> Path:
    """The ground-truth folder: `path` itself, or the `<bag>_groundtruth` folder beside a generated bag."""
    from scene_recon.synthetic.generate import ground_truth_path

    path = Path(path)
    if path.is_file() and path.name == "scene.json":
        return path.parent
    if (path / "scene.json").is_file():
        return path
    beside = ground_truth_path(path)
    if (beside / "scene.json").is_file():
        return beside
    what = "does not exist" if not path.exists() else "holds no scene.json"
    raise FileNotFoundError(f"{path} {what}: expected a ground-truth folder with scene.json (written by "
                            f"`scene-recon generate` as <bag>_groundtruth) or a generated bag beside one "
                            f"({beside} not found)")


def resolve_classes(names: list[str] | None) -> tuple[str, ...] | None:
    """Class names to evaluate ('paper' expands to the paper's 10); unknown names are an error."""
    if not names:
        return None
    from recon_core.classes import load_class_table

    expanded = [c for n in names for c in (PAPER_CLASSES if n == "paper" else (n,))]
    known = {c.name for c in load_class_table()}
    unknown = [n for n in expanded if n not in known]
    if unknown:
        raise ValueError(f"unknown class(es) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
    return tuple(dict.fromkeys(expanded))


def run(args: argparse.Namespace) -> int:
    from recon_core.entity import load_entities
    from scene_recon.synthetic.scene import GroundTruthScene

    map_dir = Path(args.map)
    if not map_dir.exists():
        raise FileNotFoundError(f"map folder {map_dir} does not exist: expected the output of `scene-recon map`")
    gt_dir = resolve_ground_truth(args.ground_truth)
    check_same_scene(f"the map {map_dir}", map_identity(map_dir), gt_dir, args.force, "eval-map")
    try:
        classes = resolve_classes(args.classes)
        overrides = {name: getattr(args, name) for _, name, _, _ in _PROTOCOL_OPTIONS
                     if getattr(args, name, None) is not None}
        config = MetricsConfig(**overrides)
        predictions = load_entities(map_dir)
        scene = GroundTruthScene.load(gt_dir)
    except ValueError as exc:  # bad class names or options, unsupported file formats
        print(f"scene-recon eval-map: error: {exc}", file=sys.stderr)
        return 2
    result = evaluate_panoptic_map(predictions, scene.entities, config, classes)
    if args.json:
        print_json({"map": str(map_dir), "ground_truth": str(gt_dir), **result.to_dict()})
    else:
        print(format_table(result, map_dir, gt_dir))
    return 0


def _fmt(x: float | None) -> str:
    return f"{x:6.1f}" if x is not None else f"{'-':>6s}"


def format_table(result: PanopticMetrics, map_dir: Path, gt_dir: Path) -> str:
    """Per-class table (PQ SQ RQ TP FP FN AP) and the class averages, like the paper's Tables 1-3."""
    c = result.counts
    lines = [
        f"map: {map_dir} ({c['pred_entities']} entities)",
        f"ground truth: {gt_dir} ({c['gt_entities']} entities, {c['gt_entities_seen']} observed, "
        f"{c['gt_entities_unobserved']} never observed: ignored)",
        f"{'class':14s} {'PQ':>6s} {'SQ':>6s} {'RQ':>6s} {'TP':>4s} {'FP':>4s} {'FN':>4s} {'AP':>6s}",
    ]
    rows = sorted(result.per_class.values(), key=lambda r: (r.is_thing, r.class_id))
    for r in rows:
        kind = "" if r.is_thing else " *"
        lines.append(f"{r.class_name + kind:14s} {_fmt(r.pq)} {_fmt(r.sq)} {_fmt(r.rq)} "
                     f"{r.tp:4d} {r.fp:4d} {r.fn:4d} {_fmt(r.ap)}")
    lines.append("-" * 56)
    for name, pq, sq, rq in (("all", result.pq, result.sq, result.rq),
                             ("stuff", result.pq_stuff, result.sq_stuff, result.rq_stuff),
                             ("things", result.pq_things, result.sq_things, result.rq_things)):
        lines.append(f"{name:14s} {_fmt(pq)} {_fmt(sq)} {_fmt(rq)}")
    lines.append(f"mAP@{result.config.iou_threshold:g}: {result.map:.1f}   (* = stuff class; values in percent, "
                 "averaged over classes)")
    lines.append(f"points: {c['sampled_points']} sampled, {c['contact_points']} hidden by contact, "
                 f"{c['observed_points']} observed; {result.elapsed_s:.2f} s")
    return "\n".join(lines)
