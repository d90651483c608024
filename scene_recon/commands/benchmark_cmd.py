"""`scene-recon benchmark --suite quick|full --out DIR`: run time against accuracy, end to end."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "benchmark",
        help="benchmark the pipeline end to end (presets, sweeps, skips, scaling) into a report folder",
        description="Run a benchmark suite on generated scenes and write results.json, plots (*.png), report.md "
        "and report.html into --out. quick (< 3 min on 2 cores; CI runs it): each preset of config/presets/ end "
        "to end on bench-small, plus the paper's CAD method and the baseline mapper, time against accuracy (PQ, "
        "box mAP, GED, CAD pose success, stillness) with the Pareto front. full (< 30 min): the presets on every "
        "suite scene, one-knob sweeps per stage with Pareto plots, perturbation curves (segmentation noise, depth "
        "noise, pose drift, CAD scale), the skip measurements (empty room, static camera, unchanged scene) and "
        "scaling (per-frame cost over a long sequence, time against object count, segmentation latency on "
        "onnxruntime, a computed multi-room / multi-host DDS projection).",
    )
    p.add_argument("--suite", choices=("quick", "full", "robustness", "robustness-quick"), default="quick",
                   help="quick/full: presets, sweeps, skips, scaling; robustness: the protocol every accuracy figure "
                   "comes from (suite + generated scenes, several oracle noise draws each, full mapper against the "
                   "baseline, mean / std / worst draw); robustness-quick: its CI subset (2 scenes x 3 draws)")
    p.add_argument("--draws", type=int, metavar="N", help="robustness: noise draws per scene (default 3)")
    p.add_argument("--scenes", nargs="+", metavar="NAME",
                   help="robustness: only these scenes (suite scenes bench-*, the protocol's generated gen-*, or "
                        "gen-SEED[-OBJECTS] for a held-out generated room, e.g. gen-1234-14)")
    p.add_argument("--paper-birth", action="store_true",
                   help="robustness: also run the full mapper with the paper's birth rule for thing entities "
                   "(every detection is born, no fragment merging), side by side on the same draws")
    p.add_argument("--single-resolution", action="store_true",
                   help="robustness: also run the full mapper with the paper's single-resolution map (small things "
                   "on the room's TSDF, no free-space core: fine_surface and free_space off), side by side on the "
                   "same draws")
    p.add_argument("--variant", nargs="+", action="append", metavar="TOKEN", default=[],
                   help="robustness: also run LABEL [mode=full|baseline] SECTION.KEY=VALUE ... side by side on the "
                   "same draws (repeatable; sections mapper, data, scene_graph, cad; e.g. --variant label-keyframes "
                   "mapper.keyframes.label_every_n_frames=0)")
    p.add_argument("--out", required=True, help="report folder (created; files in it are replaced)")
    p.add_argument("--long-frames", type=int, default=2000, metavar="N",
                   help="full suite: frames of the long sequence for the per-frame cost (default 2000)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from scene_recon.bench.suites import run_suite

    def progress(line: str) -> None:
        print(line, flush=True)

    if args.suite.startswith("robustness"):
        return _robustness(args, progress)
    if args.variant or args.paper_birth or args.single_resolution:
        from recon_core.errors import ConfigError

        raise ConfigError("--variant, --paper-birth and --single-resolution belong to --suite robustness (or "
                          "robustness-quick); the quick and full suites sweep their own knobs")

    files = run_suite(args.suite, Path(args.out), progress, long_frames=args.long_frames)
    for kind, path in files.items():
        print(f"{kind}: {path}")
    sys.stdout.flush()
    return 0


def _robustness(args: argparse.Namespace, progress) -> int:
    from recon_core.errors import ConfigError
    from scene_recon.bench.robustness import (
        parse_variant,
        protocol_spec,
        run_protocol,
        summary_lines,
        write_protocol_report,
    )

    if args.draws is not None and args.draws < 1:
        raise ConfigError(f"--draws must be at least 1, got {args.draws}")
    extra = tuple(parse_variant(tokens) for tokens in args.variant)
    try:
        spec = protocol_spec("quick" if args.suite == "robustness-quick" else "full", args.draws, args.scenes,
                             paper_birth=args.paper_birth, single_resolution=args.single_resolution,
                             extra_variants=extra)
    except ValueError as exc:
        raise ConfigError(str(exc)) from exc
    results = run_protocol(spec, Path(args.out), progress)
    files = write_protocol_report(results, Path(args.out))
    print("\nsummary (mean ± std over scenes and draws, worst draw):")
    for line in summary_lines(results):
        print(f"  {line}")
    for kind, path in files.items():
        print(f"{kind}: {path}")
    sys.stdout.flush()
    return 0
