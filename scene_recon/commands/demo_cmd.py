"""`scene-recon demo`: the main job end to end on the embedded default scene (no download)."""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from scene_recon.commands.common import add_preset_option, preset_argv


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="run the pipeline end to end on a generated default scene",
        description="Generate the default synthetic scene (seed 0, 20 objects, 300 frames), read it back through "
        "the data layer, map it (oracle segmentation at `default` noise), build its contact graph, replace its objects "
        "by CAD models (an interactive URDF/MJCF scene) and score map, graph and scene against the ground truth. "
        "Every step is the subcommand of the same name.",
    )
    p.add_argument("--out", default="out/demo", help="output folder (replaced if it exists; default out/demo)")
    p.add_argument("--objects", type=int, default=20)
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--seed", type=int, default=0)
    add_preset_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from scene_recon.cli import main

    preset = preset_argv(args)
    out = Path(args.out)
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    bag, gt = out / "scene", out / "scene_groundtruth"
    steps = [
        ("1. generate a synthetic scene", ["generate", "--out", str(bag), "--seed", str(args.seed),
                                           "--objects", str(args.objects), "--frames", str(args.frames)]),
        ("2. read the recording back through the data layer", ["inspect", str(bag)]),
        ("3. panoptic mapping (oracle segmentation, default noise)",
         ["map", str(bag), "--out", str(out / "map"), "--segmenter", "oracle", "--noise", "default", *preset]),
        ("4. map quality against the ground truth", ["eval-map", str(out / "map"), str(gt)]),
        ("5. contact graph of the mapped entities", ["graph", str(out / "map"), "--out", str(out / "graph"), *preset]),
        ("6. contact graph against the ground truth",
         ["eval-graph", str(out / "graph" / "contact_graph.json"), str(gt)]),
        ("7. CAD replacement: the interactive scene (URDF + MJCF)",
         ["replace", str(out / "graph"), "--out", str(out / "scene"), *preset]),
        ("8. interactive scene against the ground truth (poses, articulation, physics)",
         ["eval-scene", str(out / "scene"), str(gt)]),
    ]
    for title, argv in steps:
        print(f"\n== {title}\n$ scene-recon {' '.join(argv)}", flush=True)
        code = main(argv)
        if code:
            print(f"demo stopped: step '{title}' failed with exit code {code}")
            return code
    picture = out / "scene" / "before_after.png"
    print(f"\nlook at: {gt / 'overview.png'}, {out / 'map' / 'panoptic_map.png'}, "
          f"{out / 'graph' / 'contact_graph.png'}, {picture}; load {out / 'scene' / 'scene.urdf'} in RViz or "
          f"{out / 'scene' / 'scene.xml'} in MuJoCo")
    return 0
