"""`scene-recon run SOURCE --out DIR`: map -> contact graph -> CAD replacement in one go."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from scene_recon.commands.common import add_data_options, add_preset_option, data_options_argv, preset_argv

#: Exit status when a step finished but left nothing for the next one (as `map`'s).
EXIT_EMPTY = 3


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "run",
        help="the whole pipeline on a recording: map, contact graph, CAD replacement -> interactive scene",
        description="Run stages 2-4 on a recording (bag or frame folder): `map` into OUT/map, `graph` into "
        "OUT/graph, `replace` into OUT/scene (scene.urdf, scene.xml, scene.glb, joint_states.json, "
        "replacement.json). Each step is the subcommand of the same name and prints its own progress. "
        "Stops with a non-zero status, saying why, when a step fails or the map holds no object.",
    )
    p.add_argument("source", help="ROS 2 bag (.mcap/.db3/folder) or frame folder")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--segmenter", choices=("auto", "oracle", "onnx", "none"), default="auto",
                   help="auto (default): onnx when --model/--model-config is given, else the oracle when the "
                   "recording has ground truth beside it, else none")
    p.add_argument("--model", metavar="ONNX", help="exported detector/segmenter for `map` (see `map --help`)")
    p.add_argument("--model-config", help="ONNX model config YAML for `map`")
    p.add_argument("--classes", metavar="YAML", help="class table for `map` (default config/classes.yaml)")
    p.add_argument("--max-depth", type=float, metavar="M", help="map: ignore depth readings beyond M metres")
    p.add_argument("--min-depth", type=float, metavar="M", help="map: ignore depth readings nearer than M metres")
    p.add_argument("--gravity", metavar="auto|z|FILE",
                   help="map: up of the input's world frame (auto: estimated from depth; z; a 4x4 file), "
                   "see `map --help`")
    p.add_argument("--method", choices=("ours", "paper"), default="ours", help="CAD replacement method")
    p.add_argument("--seeds-per-class", type=int, default=10, metavar="N",
                   help="procedural CAD models per class (articulated classes and shelves: 2x, to cover their layouts)")
    add_preset_option(p)
    add_data_options(p)
    p.set_defaults(func=run)


def _map_argv(args: argparse.Namespace, segmenter: str, out: Path) -> list[str]:
    argv = ["map", str(args.source), "--out", str(out / "map"), "--segmenter", segmenter]
    for opt, name in (("--model", args.model), ("--model-config", args.model_config), ("--classes", args.classes)):
        if name:
            argv += [opt, str(name)]
    for opt, value in (("--max-depth", args.max_depth), ("--min-depth", args.min_depth),
                       ("--gravity", getattr(args, "gravity", None))):
        if value is not None:
            argv += [opt, str(value)]
    return argv + preset_argv(args) + data_options_argv(args)


def _no_objects(out: Path, segmenter: str, auto: bool) -> str:
    """Why the map gives the later steps nothing to work on ("" when it has objects)."""
    try:
        summary = json.loads((out / "map" / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return f"{out / 'map' / 'summary.json'} is missing or unreadable"
    if summary.get("panoptic_entities", summary.get("entities", 0)):
        return ""
    if segmenter == "none":
        why = ("no ground truth lies beside the recording, so no segmenter ran ('auto' chose 'none')" if auto
               else "--segmenter none labels nothing")
        return (f"the map holds unlabelled surface only: {why}. Pass --model your_detector.onnx (or "
                "--segmenter onnx --model-config config/segmentation/<model>.yaml) to detect objects")
    return f"the segmenter '{segmenter}' found no object in {summary['run']['frames']} mapped frames"


def run(args: argparse.Namespace) -> int:
    from scene_recon.cli import main
    from scene_recon.commands.map_cmd import choose_segmenter

    out = Path(args.out)
    segmenter, _ = choose_segmenter(argparse.Namespace(segmenter=args.segmenter, source=args.source,
                                                       model=args.model, model_config=args.model_config))
    steps = [
        ("map (stage 2)", _map_argv(args, segmenter, out)),
        ("contact graph (stage 3)", ["graph", str(out / "map"), "--out", str(out / "graph"), *preset_argv(args)]),
        ("CAD replacement (stage 4)", ["replace", str(out / "graph"), "--out", str(out / "scene"),
                                       "--method", args.method, "--seeds-per-class", str(args.seeds_per_class),
                                       *preset_argv(args)]),
    ]
    for k, (title, argv) in enumerate(steps, 1):
        print(f"\n== [{k}/{len(steps)}] {title}\n$ scene-recon {' '.join(argv)}", flush=True)
        code = main(argv)
        if code:
            print(f"run stopped: step '{title}' failed with exit code {code}", file=sys.stderr)
            return code
        if k == 1 and (why := _no_objects(out, segmenter, args.segmenter == "auto")):
            print(f"run stopped after the map: {why}; the map is in {out / 'map'}", file=sys.stderr)
            return EXIT_EMPTY
    urdf, xml = out / "scene" / "scene.urdf", out / "scene" / "scene.xml"
    if not urdf.is_file():
        print(f"run stopped: the replacement wrote no {urdf}", file=sys.stderr)
        return 2
    print(f"\ninteractive scene: {urdf}" + (f" (MuJoCo: {xml})" if xml.is_file() else ""))
    return 0
