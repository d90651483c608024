"""Options shared by the subcommands that read RGB-D data."""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import TYPE_CHECKING, Any

import numpy as np

from recon_core.config import CONFIG_DIR, Preset, load_config, load_preset, preset_names, preset_overrides

#: (option, dest, config key) of the data options that take a value (forwarded by `run` to `map`).
if TYPE_CHECKING:  # the data input is imported by the commands that read RGB-D data only (0.25 s)
    from panoptic_mapping.dataio import DataInputConfig

_VALUE_OPTIONS = (
    ("--data-config", "data_config", ""), ("--color-topic", "color_topic", "topics.color"),
    ("--depth-topic", "depth_topic", "topics.depth"),
    ("--camera-info-topic", "camera_info_topic", "topics.camera_info"),
    ("--labels-topic", "labels_topic", "topics.labels"), ("--map-frame", "map_frame", "map_frame"),
    ("--camera-frame", "camera_frame", "camera_frame"), ("--max-frames", "max_frames", "max_frames"),
    ("--stride", "stride", "stride"), ("--depth-scale", "depth_scale", "depth_scale"),
)


def add_data_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("data input (defaults: config/data.yaml)")
    g.add_argument("--data-config", metavar="YAML", help="data input config file (default: config/data.yaml)")
    g.add_argument("--color-topic", help="color image topic (default: auto-detect)")
    g.add_argument("--depth-topic", help="depth image topic, 16UC1 mm or 32FC1 m (default: auto-detect)")
    g.add_argument("--camera-info-topic", help="camera info topic (default: the one beside the color topic)")
    g.add_argument("--labels-topic", help="ground-truth label image topic (32SC1), optional")
    g.add_argument("--map-frame", help="gravity-aligned fixed frame for camera poses (default: map)")
    g.add_argument("--camera-frame", help="camera optical frame (default: the color image's frame_id)")
    g.add_argument("--intrinsics", metavar="FX,FY,CX,CY|FILE",
                   help="override camera intrinsics: fx,fy,cx,cy (one argument, e.g. 570.3,570.3,320,240) or a "
                   "file: 3x3/4x4 matrix text (camera-intrinsics.txt, intrinsic_color.txt) or YAML with fx, fy, cx, cy")
    g.add_argument("--depth-scale", type=float, metavar="UNITS",
                   help="frame folders: depth PNG units per metre (default: TUM 5000, 7-Scenes/ScanNet 1000)")
    g.add_argument("--max-frames", type=int, help="read at most this many frames")
    g.add_argument("--stride", type=int, help="read every N-th frame")


def add_preset_option(p: argparse.ArgumentParser) -> None:
    """`--preset NAME`: a speed/accuracy preset of config/presets/ (overrides of the stage configs)."""
    names = preset_names()
    p.add_argument("--preset", metavar="NAME|YAML",
                   help=f"speed/accuracy preset ({', '.join(names) or 'config/presets/*.yaml'}, or a YAML file with "
                   "mapper/data/scene_graph/cad sections): overrides of the stage configs' keys, measured in the "
                   "README (Benchmarks and presets); options given on the command line win over it")


def preset_from_args(args: argparse.Namespace) -> Preset | None:
    return load_preset(getattr(args, "preset", None))


def preset_argv(args: argparse.Namespace) -> list[str]:
    """`--preset NAME` for another subcommand when one was given."""
    return ["--preset", str(args.preset)] if getattr(args, "preset", None) else []


def data_config_from_args(args: argparse.Namespace) -> DataInputConfig:
    from panoptic_mapping.dataio import DataInputConfig
    from panoptic_mapping.dataio.intrinsics import parse_intrinsics_option

    overrides: dict[str, Any] = preset_overrides(preset_from_args(args), "data")
    for _opt, dest, key in _VALUE_OPTIONS:
        value = getattr(args, dest, None)
        if value is not None and key:
            overrides[key] = value
    if getattr(args, "intrinsics", None):
        values, file = parse_intrinsics_option(args.intrinsics)
        overrides["intrinsics"] = values
        overrides["intrinsics_file"] = file
    path = args.data_config or (CONFIG_DIR / "data.yaml" if (CONFIG_DIR / "data.yaml").is_file() else None)
    return load_config(DataInputConfig, path, overrides)


def data_options_argv(args: argparse.Namespace) -> list[str]:
    """The data options given on this command line, as arguments for another subcommand."""
    argv: list[str] = []
    for opt, dest, _key in _VALUE_OPTIONS:
        value = getattr(args, dest, None)
        if value is not None:
            argv += [opt, str(value)]
    if getattr(args, "intrinsics", None):
        argv += ["--intrinsics", args.intrinsics]
    return argv


#: Why a figure is null in a ``--json`` document when the code that made it gave no reason of its own.
NON_FINITE_REASONS = {"nan": "not a number: undefined for this input (e.g. nothing to measure it on)",
                      "inf": "infinite: no value exists (e.g. nothing was matched or chosen)"}


def _non_finite(value: Any) -> str | None:
    """'nan' / 'inf' for a non-finite float (numpy's included), else None."""
    if isinstance(value, (float, np.floating)) and not math.isfinite(float(value)):
        return "nan" if math.isnan(float(value)) else "inf"
    return None


def _printable(text: str) -> str:
    """A string that survives a strict UTF-8 encoder: undecodable path bytes (surrogate escapes) as \\xNN."""
    try:
        text.encode("utf-8")
        return text
    except UnicodeEncodeError:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def strict_json_value(data: Any) -> Any:
    """`data` as strict JSON can hold it: NaN/Infinity become null with ``<key>_null_reason`` beside them
    (a reason the producer already gave is kept); numpy scalars and arrays become Python numbers and
    lists; strings with undecodable bytes (paths) are escaped; anything else is written as its str()."""
    if isinstance(data, dict):
        out: dict[Any, Any] = {}
        for key, value in data.items():
            key = _printable(key) if isinstance(key, str) else str(key)
            kind = _non_finite(value)
            if kind is not None:
                out[key] = None
                out.setdefault(f"{key}_null_reason", data.get(f"{key}_null_reason", NON_FINITE_REASONS[kind]))
            elif key.endswith("_null_reason") and key in out:
                continue  # already set beside its value
            else:
                out[key] = strict_json_value(value)
        return out
    if isinstance(data, (list, tuple)):
        return [None if _non_finite(v) is not None else strict_json_value(v) for v in data]
    if isinstance(data, np.ndarray):
        return strict_json_value(data.tolist())
    if isinstance(data, np.generic):
        return strict_json_value(data.item())
    if _non_finite(data) is not None:
        return None
    if isinstance(data, str):
        return _printable(data)
    if data is None or isinstance(data, (bool, int, float)):
        return data
    return _printable(str(data))


def json_text(data: Any, indent: int | None = 2) -> str:
    """One strict JSON document (no NaN/Infinity: see ``strict_json_value``)."""
    return json.dumps(strict_json_value(data), indent=indent, sort_keys=False, allow_nan=False)


def print_json(data: Any) -> None:
    """Write `data` on stdout as exactly one strict JSON document (jq, JavaScript, Go can parse it)."""
    sys.stdout.write(json_text(data) + "\n")
    sys.stdout.flush()
