"""`scene-recon run SOURCE --out DIR`: map -> contact graph -> CAD replacement in one go."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "run",
        help="the whole pipeline on a recording: map, contact graph, CAD replacement -> interactive scene",
        description="Run stages 2-4 on a recording (bag or frame folder): `map` into OUT/map, `graph` into "
        "OUT/graph, `replace` into OUT/scene (scene.urdf, scene.xml, scene.glb, joint_states.json, "
        "replacement.json). Each step is the subcommand of the same name and prints its own progress.",
    )
    p.add_argument("source", help="ROS 2 bag (.mcap/.db3/folder) or frame folder")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--segmenter", choices=("auto", "oracle", "onnx", "none"), default="auto",
                   help="auto (default): onnx when --model/--model-config is given, else the oracle when the "
                   "recording has ground truth beside it, else none")
    p.add_argument("--model", metavar="ONNX", help="exported detector/segmenter for `map` (see `map --help`)")
    p.add_argument("--model-config", help="ONNX model config YAML for `map`")
    p.add_argument("--classes", metavar="YAML", help="class table for `map` (default config/classes.yaml)")
    p.add_argument("--method", choices=("ours", "paper"), default="ours", help="CAD replacement method")
    p.add_argument("--seeds-per-class", type=int, default=10, metavar="N", help="procedural CAD models per class")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from scene_recon.cli import main
    from scene_recon.commands.map_cmd import choose_segmenter

    out = Path(args.out)
    segmenter, _ = choose_segmenter(argparse.Namespace(segmenter=args.segmenter, source=args.source,
                                                       model=args.model, model_config=args.model_config))
    map_argv = ["map", str(args.source), "--out", str(out / "map"), "--segmenter", segmenter]
    for opt, value in (("--model", args.model), ("--model-config", args.model_config), ("--classes", args.classes)):
        if value:
            map_argv += [opt, str(value)]
    steps = [
        ("map (stage 2)", map_argv),
        ("contact graph (stage 3)", ["graph", str(out / "map"), "--out", str(out / "graph")]),
        ("CAD replacement (stage 4)", ["replace", str(out / "graph"), "--out", str(out / "scene"),
                                       "--method", args.method, "--seeds-per-class", str(args.seeds_per_class)]),
    ]
    for k, (title, argv) in enumerate(steps, 1):
        print(f"\n== [{k}/{len(steps)}] {title}\n$ scene-recon {' '.join(argv)}", flush=True)
        code = main(argv)
        if code:
            print(f"run stopped: step '{title}' failed with exit code {code}")
            return code
    print(f"\ninteractive scene: {out / 'scene' / 'scene.urdf'} (MuJoCo: {out / 'scene' / 'scene.xml'})")
    return 0
