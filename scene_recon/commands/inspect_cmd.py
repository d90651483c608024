"""`scene-recon inspect PATH`: what a bag or frame folder holds, and which frames would be mapped."""

from __future__ import annotations

import argparse

from panoptic_mapping.dataio.inspect import inspect_dataset
from scene_recon.commands.common import add_data_options, data_config_from_args, print_json

#: Exit status when the source holds no frame that `map` could use (as `map`'s empty result).
EXIT_EMPTY = 3


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "inspect",
        help="show what a bag or frame folder holds",
        description="Print the topics (type, count, rate, encoding, resolution), duration, synchronised "
        "color/depth frames and camera-pose coverage of a ROS 2 bag (.mcap/.db3) or of a TUM / "
        "7-Scenes / ScanNet frame folder, and how many frames `map` would use, with the number skipped "
        "per reason (no pose, no valid depth, unreadable or mismatched images, ...) and what to change. "
        "Exit status: 0; 2 unreadable source; 3 no frame would be mapped.",
    )
    p.add_argument("path", help="bag (.mcap/.db3 file or rosbag2 folder) or frame folder")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--quick", action="store_true",
                   help="pair and pose the frames without decoding them (faster; image problems are not counted)")
    add_data_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    info = inspect_dataset(args.path, data_config_from_args(args), quick=args.quick)
    if args.json:
        print_json(info)
    else:
        print(format_summary(info))
    if "error" in info:
        return 2
    return EXIT_EMPTY if info.get("usable_frames", 1) == 0 else 0


def format_summary(info: dict) -> str:
    lines = [f"{info['path']}  [{info['format']}{' / ' + info['storage'] if 'storage' in info else ''}]"]
    if "topics" in info:
        lines.append(f"{'topic':40s} {'type':32s} {'count':>6s} {'rate Hz':>8s}  details")
        for t in info["topics"]:
            details = []
            if "width" in t:
                details.append(f"{t['width']}x{t['height']}")
            if "encoding" in t:
                details.append(t["encoding"])
            if "role" in t:
                details.append(f"<- {t['role']}")
            lines.append(f"{t['topic']:40s} {t['type']:32s} {t['count']:6d} {t.get('rate_hz', 0):8.2f}  "
                         + " ".join(details))
    if "error" in info:
        lines.append(f"error: {info['error']}")
        return "\n".join(lines)
    if info.get("truncated"):
        damage = "; ".join(info.get("damage", []))
        lines.append(f"warning: truncated recording, the frames before the cut are read ({damage})")
    res = info.get("resolution")
    lines.append(
        f"frames: {info['frames']} synchronised color/depth pairs"
        + (f", {res[0]}x{res[1]}" if res else "")
        + f", {info['duration_s']:.2f} s, {info['frame_rate_hz']:.2f} Hz"
    )
    if "depth_resolution" in info:
        d = info["depth_resolution"]
        lines.append(f"depth: {d[0]}x{d[1]}, differs from color: color is resampled onto the depth grid")
    if "intrinsics" in info:
        k = info["intrinsics"]
        lines.append(f"intrinsics: fx={k[0]:g} fy={k[1]:g} cx={k[2]:g} cy={k[3]:g} from {info['intrinsics_source']}"
                     + (f"; depth camera {', '.join(f'{v:g}' for v in info['depth_intrinsics'])}"
                        if "depth_intrinsics" in info else ""))
    if "depth_median_m" in info:
        lines.append(f"depth: median {info['depth_median_m']:.2f} m in the first frame "
                     f"({info.get('depth_scale', 0):g} units per metre)")
    if info.get("depth_warning"):
        lines.append(f"warning: {info['depth_warning']}")
    where = f" in '{info['map_frame']}' from '{info['camera_frame']}'" if "map_frame" in info else ""
    coverage = 100 * info["pose_coverage"]
    lines.append(f"poses: {info['posed_frames']}/{info['frames']} frames posed ({coverage:.1f}%){where}")
    if info.get("tf_frames"):
        lines.append(f"tf frames: {', '.join(info['tf_frames'])} (roots: {', '.join(info.get('tf_roots', []))})")
    if info.get("pose_hint"):
        lines.append(f"why not posed: {info['pose_hint']}")
    skipped = {k: v for k, v in info.get("skipped", {}).items() if v}
    lines.append("skipped: " + (", ".join(f"{k}={v}" for k, v in skipped.items()) if skipped else "nothing"))
    for reason, n in info.get("skip_reasons", {}).items():
        lines.append(f"  {n:6d} x {reason}")
    if "usable_frames" in info:
        lines.append(f"would map: {info['usable_frames']} of {info['frames']} frames ({info['checked']})")
    if info.get("why_no_frames"):
        lines.append(f"why none: {info['why_no_frames']}")
    return "\n".join(lines)
