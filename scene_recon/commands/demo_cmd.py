"""`scene-recon demo`: the main job end to end on the embedded default scene (no download)."""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from .common import print_json


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="run the pipeline end to end on a generated default scene",
        description="Generate the default synthetic scene (seed 0, 20 objects, 300 frames), read it back "
        "through the data layer and report what it holds. Later pipeline stages run here as they land.",
    )
    p.add_argument("--out", default="out/demo", help="output folder (replaced if it exists; default out/demo)")
    p.add_argument("--objects", type=int, default=20)
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from panoptic_mapping.dataio.inspect import inspect_dataset
    from scene_recon.synthetic.generate import GenerateConfig, generate_recording

    from .generate_cmd import format_summary
    from .inspect_cmd import format_summary as format_inspect

    out = Path(args.out)
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    summary = generate_recording(out / "scene", GenerateConfig(objects=args.objects, frames=args.frames,
                                                               seed=args.seed), progress=not args.json)
    info = inspect_dataset(summary["bag"])
    if args.json:
        print_json({"generate": summary, "inspect": info})
        return 0
    print("== 1. synthetic scene")
    print(format_summary(summary))
    print("\n== 2. the recording, read back through the data layer")
    print(format_inspect(info))
    print(f"\nlook at: {Path(summary['ground_truth']) / 'overview.png'}")
    return 0
