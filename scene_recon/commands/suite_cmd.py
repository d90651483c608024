"""`scene-recon suite`: the named benchmark scenes (generated on first use, then cached)."""

from __future__ import annotations

import argparse

from scene_recon.commands.common import print_json


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "suite",
        help="list or generate the benchmark suite scenes",
        description="Every evaluation runs on these named scenes. They are generated on demand into the cache "
        "($SCENE_RECON_CACHE, default ~/.cache/scene_recon) and reused while their definition is unchanged.",
    )
    p.add_argument("names", nargs="*", help="scenes to generate (default: list them)")
    p.add_argument("--all", action="store_true", help="generate every scene")
    p.add_argument("--regenerate", action="store_true", help="ignore the cache")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from scene_recon.synthetic.suite import SUITE, suite_scene

    names = list(SUITE) if args.all else args.names
    if not names:
        rows = [{"name": s.name, "objects": s.objects, "frames": s.frames, "seed": s.seed,
                 "description": s.description} for s in SUITE.values()]
        if args.json:
            print_json(rows)
        else:
            for r in rows:
                print(f"{r['name']:15s} {r['objects']:3d} objects {r['frames']:4d} frames  {r['description']}")
        return 0
    out = []
    for name in names:
        bag, gt = suite_scene(name, progress=not args.json, regenerate=args.regenerate)
        out.append({"name": name, "bag": str(bag), "ground_truth": str(gt)})
        if not args.json:
            print(f"{name}: {bag}  (ground truth: {gt})")
    if args.json:
        print_json(out)
    return 0
