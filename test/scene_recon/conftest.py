"""Small generated scenes shared by the command-line tests (made once per test session, on first use)."""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]


def _reject(constant: str) -> Any:
    raise ValueError(f"not strict JSON: {constant}")


def strict_json(text: str) -> Any:
    """Parse `text` as exactly one strict JSON document: NaN/Infinity (and anything before or after) fail."""
    data = json.loads(text, parse_constant=_reject)

    def walk(value: Any) -> None:
        if isinstance(value, float):
            assert math.isfinite(value), value
        elif isinstance(value, dict):
            for v in value.values():
                walk(v)
        elif isinstance(value, list):
            for v in value:
                walk(v)

    walk(data)
    return data


def run_cli(*args: str, timeout: float = 300, **kwargs: Any) -> subprocess.CompletedProcess:
    """`python -m scene_recon.cli ARGS` in a child process (its fd 1 is a real pipe: native prints land there)."""
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.update(kwargs.pop("env", {}))
    return subprocess.run([sys.executable, "-m", "scene_recon.cli", *args], capture_output=True, env=env,
                          cwd=REPO_ROOT, timeout=timeout, **kwargs)


@pytest.fixture(scope="session")
def tiny_bag(tmp_path_factory) -> Path:
    """`scene-recon generate --json` of a 3-object room, 40 frames of 320x240 (its JSON parsed strictly)."""
    path = tmp_path_factory.mktemp("tiny") / "bag"
    proc = run_cli("generate", "--out", str(path), "--frames", "40", "--objects", "3", "--seed", "3",
                   "--width", "320", "--height", "240", "--json")
    assert proc.returncode == 0, proc.stderr.decode()[-2000:]
    summary = strict_json(proc.stdout.decode())
    assert summary["frames"] == 40
    return path


def main_json(argv: list[str]) -> tuple[int, Any]:
    """`scene_recon.cli.main(argv)` in this process, its stdout parsed as one strict JSON document."""
    from scene_recon.cli import main

    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        rc = main(argv)
    return rc, strict_json(buffer.getvalue())


@pytest.fixture(scope="session")
def tiny_map(tiny_bag, tmp_path_factory) -> Path:
    """The oracle map of `tiny_bag` (`map --json`, parsed strictly)."""
    out = tmp_path_factory.mktemp("tiny_map") / "map"
    rc, summary = main_json(["map", str(tiny_bag), "--out", str(out), "--segmenter", "oracle", "--json"])
    assert rc == 0 and summary["panoptic_entities"] >= 1, summary
    return out


@pytest.fixture(scope="session")
def other_ground_truth(tmp_path_factory) -> Path:
    """The ground-truth folder of another generated scene (no recording: scene.json and meshes only)."""
    from scene_recon.synthetic.scene import build_scene

    gt = tmp_path_factory.mktemp("other") / "room_groundtruth"
    build_scene(4, 11).save(gt)
    return gt


@pytest.fixture(scope="session")
def replaced_scene(tmp_path_factory) -> tuple[Path, Path, Path]:
    """(ground truth, graph folder, replaced scene folder) of a generated room, as test_cli_replace builds it."""
    from scene_recon.synthetic.scene import build_scene

    root = tmp_path_factory.mktemp("replaced")
    gt = root / "room_groundtruth"
    build_scene(6, 5).save(gt)
    assert main_json(["graph", str(gt), "--out", str(root / "graph"), "--json"])[0] == 0
    assert main_json(["replace", str(root / "graph"), "--out", str(root / "scene"), "--seeds-per-class", "3",
                      "--json"])[0] == 0
    return gt, root / "graph", root / "scene"


@pytest.fixture(name="strict_json")
def strict_json_fixture():
    """`strict_json(text)`: one strict JSON document (NaN/Infinity rejected)."""
    return strict_json


@pytest.fixture(name="run_cli")
def run_cli_fixture():
    """`run_cli(*args)`: the command line in a child process."""
    return run_cli


@pytest.fixture(name="main_json")
def main_json_fixture():
    """`main_json(argv)`: (exit status, strict JSON of stdout) of the command line run in this process."""
    return main_json
