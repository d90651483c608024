"""`scene-recon generate`: a synthetic RGB-D recording with full ground truth."""

from __future__ import annotations

import argparse

from scene_recon.commands.common import print_json


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "generate",
        help="generate a synthetic scene as a ROS 2 bag with ground truth",
        description="Build a furnished room from the CAD library, fly a handheld-like camera through it, "
        "render noisy RGB-D frames and write them as a ROS 2 bag at PATH (a folder; a .mcap/.db3 suffix picks "
        "the storage) with the ground truth (entities, contact graph, URDF, meshes, overview picture) in "
        "PATH_groundtruth/ beside it. Deterministic for a seed.",
    )
    p.add_argument("--out", required=True, metavar="PATH", help="bag folder to write (must not exist)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--objects", type=int, default=20, help="number of objects besides the room (default 20)")
    p.add_argument("--frames", type=int, default=300, help="number of frames (default 300)")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate (default 30)")
    p.add_argument("--storage", choices=["mcap", "db3"], default=None, help="bag storage (default mcap)")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--noise-free", action="store_true", help="exact depth (no sensor noise model)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from scene_recon.synthetic.generate import GenerateConfig, generate_recording

    cfg = GenerateConfig(objects=args.objects, frames=args.frames, fps=args.fps, seed=args.seed,
                         storage=args.storage or "mcap")
    if args.width != 640 or args.height != 480:
        scale = args.width / 640.0
        cam = cfg.sensor.camera
        cam.width, cam.height = args.width, args.height
        cam.fx, cam.fy = cam.fx * scale, cam.fy * scale
        cam.cx, cam.cy = (args.width - 1) / 2, (args.height - 1) / 2
    if args.noise_free:
        cfg.sensor.depth_noise.noise_free = True
    summary = generate_recording(args.out, cfg, progress=not args.json)
    if args.json:
        print_json(summary)
    else:
        print(format_summary(summary))
    return 0


def format_summary(s: dict) -> str:
    classes = ", ".join(f"{k} x{v}" for k, v in s["classes"].items())
    t = s["timings_s"]
    lines = [
        f"bag:          {s['bag']} ({s['storage']}, {s['frames']} frames, {s['resolution'][0]}x{s['resolution'][1]})",
        f"ground truth: {s['ground_truth']} (scene.json, urdf/scene.urdf, meshes/, overview.png)",
        f"room:         {s['room_size_m'][0]:.2f} x {s['room_size_m'][1]:.2f} m, {s['room_size_m'][2]:.2f} m high",
        f"entities:     {s['entities']} ({s['objects']} objects): {classes}",
        f"contact graph: {s['support_edges']} support edges, {s['proximal_edges']} proximal pairs",
        f"time:         {s['total_s']:.1f} s (scene {t['scene_s']:.1f}, trajectory {t['trajectory_s']:.1f}, "
        f"render+write {t['render_and_write_s']:.1f}, ground truth {t['ground_truth_s']:.1f})",
    ]
    if s["never_seen"]:
        lines.append(f"never seen by the camera: {', '.join(s['never_seen'])}")
    return "\n".join(lines)
