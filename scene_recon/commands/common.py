"""Options shared by the subcommands that read RGB-D data."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from panoptic_mapping.dataio import DataInputConfig
from recon_core.config import CONFIG_DIR, load_config


def add_data_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("data input (defaults: config/data.yaml)")
    g.add_argument("--data-config", metavar="YAML", help="data input config file (default: config/data.yaml)")
    g.add_argument("--color-topic", help="color image topic (default: auto-detect)")
    g.add_argument("--depth-topic", help="depth image topic, 16UC1 mm or 32FC1 m (default: auto-detect)")
    g.add_argument("--camera-info-topic", help="camera info topic (default: the one beside the color topic)")
    g.add_argument("--labels-topic", help="ground-truth label image topic (32SC1), optional")
    g.add_argument("--map-frame", help="gravity-aligned fixed frame for camera poses (default: map)")
    g.add_argument("--camera-frame", help="camera optical frame (default: the color image's frame_id)")
    g.add_argument("--intrinsics", nargs=4, type=float, metavar=("FX", "FY", "CX", "CY"),
                   help="override camera intrinsics")
    g.add_argument("--max-frames", type=int, help="read at most this many frames")
    g.add_argument("--stride", type=int, help="read every N-th frame")


def data_config_from_args(args: argparse.Namespace) -> DataInputConfig:
    overrides: dict[str, Any] = {}
    for opt, key in (("color_topic", "topics.color"), ("depth_topic", "topics.depth"),
                     ("camera_info_topic", "topics.camera_info"), ("labels_topic", "topics.labels"),
                     ("map_frame", "map_frame"), ("camera_frame", "camera_frame"),
                     ("max_frames", "max_frames"), ("stride", "stride")):
        value = getattr(args, opt, None)
        if value is not None:
            overrides[key] = value
    if getattr(args, "intrinsics", None):
        overrides["intrinsics"] = list(args.intrinsics)
    path = args.data_config or (CONFIG_DIR / "data.yaml" if (CONFIG_DIR / "data.yaml").is_file() else None)
    return load_config(DataInputConfig, path, overrides)


def print_json(data: Any) -> None:
    json.dump(data, sys.stdout, indent=2, sort_keys=False, default=str)
    sys.stdout.write("\n")
