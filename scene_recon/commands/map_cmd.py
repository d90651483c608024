"""`scene-recon map`: build the volumetric panoptic map of a recording."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from scene_recon.commands.common import add_data_options, data_config_from_args, print_json


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "map",
        help="build the panoptic map of a recording (stage 2)",
        description="Segment keyframes with a 2D panoptic backend, fuse them with depth segments, integrate a "
        "labelled TSDF and extract panoptic entities (paper Sec. 3). Writes entities.json + meshes/, a resumable "
        "map (map.npz/map.json), summary.json and, when the map has surface, panoptic_map.png into --out. "
        "Exit status: 0 done; 2 error (nothing written; e.g. no frame with a pose: the message says why); "
        "3 written but empty (no entity).",
    )
    p.add_argument("source", help="bag or frame folder")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--segmenter", choices=["oracle", "onnx", "none"], default="oracle",
                   help="2D panoptic backend (default oracle: needs a generated scene's ground truth)")
    p.add_argument("--noise", default="default", help="oracle noise level: clean | default | hard")
    p.add_argument("--ground-truth", help="ground-truth folder for the oracle (default: beside the bag)")
    p.add_argument("--model-config", help="ONNX model config YAML (config/segmentation/*.yaml)")
    p.add_argument("--mode", choices=["full", "baseline"], default="full",
                   help="full = the paper's method; baseline = Voxblox++-style fusion")
    p.add_argument("--config", help="mapper config YAML (default config/mapper.yaml)")
    p.add_argument("--voxel-size", type=float, help="TSDF voxel size in metres")
    p.add_argument("--max-depth", type=float, metavar="M",
                   help="ignore depth readings beyond M metres (default tsdf.max_depth_m of config/mapper.yaml: 4.0)")
    p.add_argument("--min-depth", type=float, metavar="M",
                   help="ignore depth readings nearer than M metres (default tsdf.min_depth_m: 0.1)")
    p.add_argument("--no-keyframes", action="store_true", help="segment every frame")
    p.add_argument("--resume", help="continue from a map saved in this folder")
    p.add_argument("--seed", type=int, default=0, help="oracle noise seed")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_data_options(p)
    p.set_defaults(func=run)


def build_segmenter(args: argparse.Namespace):
    from panoptic_mapping.segmentation.config import SegmentationConfig
    from panoptic_mapping.segmentation.factory import make_segmenter
    from scene_recon.synthetic.generate import ground_truth_path

    if args.segmenter == "none":
        return None
    cfg = SegmentationConfig(backend=args.segmenter)
    if args.segmenter == "oracle":
        gt = args.ground_truth or str(ground_truth_path(Path(args.source)))
        cfg.oracle.ground_truth = gt
        cfg.oracle.level = args.noise
        cfg.oracle.seed = args.seed
    elif args.segmenter == "onnx":
        if not args.model_config:
            raise FileNotFoundError("--segmenter onnx needs --model-config (see config/segmentation/)")
        cfg.onnx.model_config = args.model_config
    return make_segmenter(cfg)


def mapper_config_from_args(args: argparse.Namespace):
    from panoptic_mapping.config import MapperConfig
    from recon_core.config import CONFIG_DIR, load_config

    overrides = {"mode": args.mode}
    if args.voxel_size:
        overrides["tsdf.voxel_size_m"] = args.voxel_size
    if getattr(args, "max_depth", None) is not None:
        overrides["tsdf.max_depth_m"] = args.max_depth
    if getattr(args, "min_depth", None) is not None:
        overrides["tsdf.min_depth_m"] = args.min_depth
    if args.no_keyframes:
        overrides["keyframes.enabled"] = False
    path = args.config or (CONFIG_DIR / "mapper.yaml" if (CONFIG_DIR / "mapper.yaml").is_file() else None)
    return load_config(MapperConfig, path, overrides)


#: Exit status of a run that wrote its outputs but found nothing in them.
EXIT_EMPTY = 3


def run(args: argparse.Namespace) -> int:
    from panoptic_mapping.mapper import PanopticMapper
    from panoptic_mapping.pipeline import map_recording, write_map_outputs
    from scene_recon.synthetic.overview import render_map_picture

    data_cfg = data_config_from_args(args)
    if args.segmenter == "oracle":
        data_cfg.topics.labels = data_cfg.topics.labels or "/ground_truth/panoptic_labels"
    segmenter = build_segmenter(args)
    mapper = PanopticMapper.load(args.resume) if args.resume else None
    mapper, run_stats = map_recording(args.source, segmenter, mapper_config_from_args(args), data_cfg,
                                      progress=not args.json, mapper=mapper)
    ents, summary = write_map_outputs(args.out, mapper, run_stats,
                                      extra={"segmenter": args.segmenter, "noise": args.noise,
                                             "source": str(args.source)})
    out = Path(args.out)
    written = ["entities.json", "meshes/", "map.npz", "map.json", "summary.json"]
    try:
        if render_map_picture(ents, run_stats.poses, out / "panoptic_map.png"):
            written.append("panoptic_map.png")
    except OSError as exc:
        logging.getLogger(__name__).warning("no map picture: %s", exc)
    summary["files"] = written
    (out / "summary.json").write_text(json.dumps(summary, indent=1), encoding="utf-8")
    problem = empty_result(summary, args.segmenter)
    if args.json:
        print_json(summary)
    else:
        print_report(summary, ents, args.out, written)
    if problem:
        print(f"scene-recon map: {problem}", file=sys.stderr)
        return EXIT_EMPTY
    return 0


def empty_result(summary: dict, segmenter: str) -> str:
    """Why a written map is empty, and what to do ("" when it is not)."""
    r = summary["run"]
    if summary["entities"] == 0:
        lo, hi = summary.get("depth_range_m", ["?", "?"])
        return (f"the map of {r['frames']} frames has no surface: check the depth range ({lo}-{hi} m, "
                "--min-depth/--max-depth), the depth scale and the camera poses")
    if segmenter != "none" and summary.get("panoptic_entities", 0) == 0:
        return (f"{r['frames']} frames mapped ({r['segmentation_calls']} segmented) but the segmenter "
                f"'{segmenter}' found no object: the map holds unlabelled surface only (entity 'unknown'). "
                "Check the segmenter (--segmenter, --model-config) on these images")
    return ""


def print_report(summary: dict, ents: list, out: str, written: list[str]) -> None:
    r = summary["run"]
    print(f"mapped {r['frames']} frames ({r['keyframes']} keyframes, {r['segmentation_calls']} segmentation calls) "
          f"in {r['wall_s']:.1f} s; mapper alone {r['mapper_fps']:.1f} frames/s")
    if r.get("stage_ms"):
        print("per frame: " + ", ".join(f"{k} {v:.1f} ms" for k, v in r["stage_ms"].items()))
    skipped = r.get("skipped", {})
    if skipped:
        print("skipped: " + ", ".join(f"{k}={v}" for k, v in skipped.items()))
    if r.get("failed_frames"):
        worst = max(r["failures"].items(), key=lambda kv: kv[1])[0]
        print(f"warning: {r['failed_frames']} frames failed in the mapper and were skipped (most often: {worst})")
    if r.get("truncated"):
        print("warning: the recording is truncated; the frames before the cut were mapped")
    if any(summary.get("origin_offset_m", [0, 0, 0])):
        off = summary["origin_offset_m"]
        print(f"map recentred: its origin is at ({off[0]:.0f}, {off[1]:.0f}, {off[2]:.0f}) m of the input map frame "
              "(origin_offset_m in map.json / summary.json; add it to map back)")
    print(f"map: {summary['map_blocks']} voxel blocks, {summary['map_memory_mb']} MB, "
          f"{summary['global_segments']} global segments")
    print(f"{'id':>5s} {'class':12s} {'instance':>8s} {'conf':>5s} {'vertices':>8s}")
    for e in sorted(ents, key=lambda e: (e.class_name, e.id)):
        print(f"{e.id:5d} {e.class_name:12s} {e.instance_id:8d} {e.confidence:5.2f} {len(e.vertices):8d}")
    print(f"wrote {out}/: " + ", ".join(written))
