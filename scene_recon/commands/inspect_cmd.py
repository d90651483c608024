"""`scene-recon inspect PATH`: what a bag or frame folder holds."""

from __future__ import annotations

import argparse

from panoptic_mapping.dataio.inspect import inspect_dataset
from scene_recon.commands.common import add_data_options, data_config_from_args, print_json


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "inspect",
        help="show what a bag or frame folder holds",
        description="Print the topics (type, count, rate, encoding, resolution), duration, synchronised "
        "color/depth frames and camera-pose coverage of a ROS 2 bag (.mcap/.db3) or of a TUM / "
        "7-Scenes frame folder.",
    )
    p.add_argument("path", help="bag (.mcap/.db3 file or rosbag2 folder) or frame folder")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_data_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    info = inspect_dataset(args.path, data_config_from_args(args))
    if args.json:
        print_json(info)
        return 0 if "error" not in info else 2
    print(format_summary(info))
    return 0 if "error" not in info else 2


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
    res = info.get("resolution")
    lines.append(
        f"frames: {info['frames']} synchronised color/depth pairs"
        + (f", {res[0]}x{res[1]}" if res else "")
        + f", {info['duration_s']:.2f} s, {info['frame_rate_hz']:.2f} Hz"
    )
    where = f" in '{info['map_frame']}' from '{info['camera_frame']}'" if "map_frame" in info else ""
    coverage = 100 * info["pose_coverage"]
    lines.append(f"poses: {info['posed_frames']}/{info['frames']} frames posed ({coverage:.1f}%){where}")
    if info.get("tf_frames"):
        lines.append(f"tf frames: {', '.join(info['tf_frames'])}")
    skipped = {k: v for k, v in info.get("skipped", {}).items() if v}
    lines.append("skipped: " + (", ".join(f"{k}={v}" for k, v in skipped.items()) if skipped else "nothing"))
    return "\n".join(lines)
