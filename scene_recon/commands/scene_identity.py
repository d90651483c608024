"""Which generated scene a map, a contact graph or a replaced scene comes from, and the check that an
evaluation compares it with that scene's ground truth (not another scene's, which scores without meaning).

A scene's identity is its name and seed from ``scene.json`` plus a fingerprint of what the scores
depend on: the room size and every entity's name, class and pose (to the millimetre), so the same
scene generated again has the same identity and two scenes of the same name and seed but other
settings (object count, layout) do not. ``scene-recon map`` records it in summary.json (``scene``),
``graph`` in contact_graph.json (``stats.scene``), ``replace`` in replacement.json; for outputs
written before that, the recording named in summary.json (``source``) leads to the ground truth beside it.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path
from typing import Any

from recon_core.errors import InputError


def ground_truth_identity(gt_dir: str | Path) -> str | None:
    """``<name> (seed N) #<fingerprint>`` of a ground-truth folder (None without a readable scene.json)."""
    try:
        data = json.loads((Path(gt_dir) / "scene.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict):
        return None
    key: list[Any] = [[round(float(v), 3) for v in data.get("room_size", [])]]
    for e in sorted(data.get("entities", []), key=lambda e: str(e.get("name", ""))):
        pose = e.get("pose") or []
        key.append([str(e.get("name", "")), str(e.get("class_name", "")),
                    [[round(float(v), 3) for v in row] for row in pose]])
    digest = hashlib.sha256(json.dumps(key, separators=(",", ":")).encode()).hexdigest()[:12]
    return f"{data.get('name', 'scene')} (seed {data.get('seed', '?')}) #{digest}"


def recording_identity(source: str | Path, ground_truth: str | Path | None = None) -> str | None:
    """The identity of the generated scene a recording shows: its ground truth (given, or beside the bag)."""
    from scene_recon.synthetic.generate import ground_truth_path

    gt = Path(ground_truth) if ground_truth else ground_truth_path(Path(source))
    return ground_truth_identity(gt)


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def map_identity(map_dir: str | Path) -> str | None:
    """The scene of a map folder written by `scene-recon map` (None when it cannot be told)."""
    summary = _read_json(Path(map_dir) / "summary.json")
    if summary.get("scene"):
        return str(summary["scene"])
    if summary.get("source"):
        return recording_identity(summary["source"])
    return None


def graph_identity(graph_file: str | Path) -> str | None:
    """The scene of a contact graph file (``stats.scene``, written by `scene-recon graph`)."""
    stats = _read_json(Path(graph_file)).get("stats") or {}
    return str(stats["scene"]) if isinstance(stats, dict) and stats.get("scene") else None


def scene_folder_identity(scene_dir: str | Path) -> str | None:
    """The scene of a folder written by `scene-recon replace` (replacement.json, else its contact graph)."""
    folder = Path(scene_dir)
    recorded = _read_json(folder / "replacement.json").get("scene_identity")
    return str(recorded) if recorded else graph_identity(folder / "contact_graph.json")


def check_same_scene(what: str, identity: str | None, gt_dir: str | Path, force: bool = False,
                     command: str = "") -> None:
    """Refuse (InputError: one line, exit 2) to score `what` of one scene against the ground truth of
    another; with `force`, say so loudly on stderr and go on. Nothing is said when either is unknown."""
    truth = ground_truth_identity(gt_dir)
    if not identity or not truth or identity == truth:
        return
    text = (f"{what} comes from scene {identity}, but the ground truth {gt_dir} is scene {truth}: the scores "
            "would compare different scenes")
    if not force:
        raise InputError(f"{text}. Pass that scene's own ground truth (or --force to score anyway)")
    prefix = f"scene-recon {command}: " if command else ""
    print(f"{prefix}WARNING: {text} (scoring anyway: --force)", file=sys.stderr)


__all__ = ["check_same_scene", "graph_identity", "ground_truth_identity", "map_identity", "recording_identity",
           "scene_folder_identity"]
