"""Fixtures of the tests that run the upstream ROS 2 tooling (issue 24, item 1).

`ros2_upstream_env`: the environment of a shell that sourced the prefix `../shared/ros2-upstream/build_prefix.sh`
builds (upstream launch, launch_ros, ros2cli beside the venv's PyPI Kilted wheels; the stand-in for
`source /opt/ros/<distro>/setup.bash`), built once per test session into a scratch folder. Every test using it
skips, with the reason, only where those sources are absent. Set SCENE_RECON_ROS2_PREFIX to a folder built
before (`build_prefix.sh VENV DEST`, DEST) to reuse it.

`colcon_workspace`: this package built as docs/ROS.md's stock-ROS recipe writes it: the sources in
`WS/src/scene_recon`, the recipe's own `colcon build` line run in WS, its `source install/...` line sourced.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
UPSTREAM = next((p for p in (ROOT.parent / "shared" / "ros2-upstream", Path("/work/shared/ros2-upstream"))
                 if (p / "build_prefix.sh").is_file()), None)
ROS_DOC = ROOT / "docs" / "ROS.md"
#: Names never copied into the workspace (the .gitignore's build products and caches), where git cannot list.
_NOT_SOURCES = {".git", ".venv", ".build", "build", "install", "log", "out", "__pycache__", ".pytest_cache",
                ".ruff_cache", ".mypy_cache", ".cache"}


def sourced_env(script: Path, base: dict[str, str], cwd: Path | None = None) -> dict[str, str]:
    """The environment after `. script` in a POSIX shell started with `base`."""
    run = subprocess.run(["bash", "-c", f". {shlex.quote(str(script))} && env -0"], env=base, cwd=cwd,
                         capture_output=True, check=True)
    return dict(item.split("=", 1) for item in run.stdout.decode().split("\0") if "=" in item)


@pytest.fixture(scope="session")
def ros2_upstream_env(tmp_path_factory) -> dict[str, str]:
    """The environment of a shell that sourced the upstream prefix's env.sh (DDS settings: the caller's)."""
    if UPSTREAM is None:
        pytest.skip("../shared/ros2-upstream (upstream launch, launch_ros, ros2cli sources) is absent")
    dest = Path(os.environ.get("SCENE_RECON_ROS2_PREFIX") or tmp_path_factory.mktemp("ros2_upstream"))
    build = subprocess.run(["bash", str(UPSTREAM / "build_prefix.sh"), sys.prefix, str(dest)],
                           capture_output=True, text=True, timeout=900)
    if build.returncode != 0:
        pytest.fail(f"build_prefix.sh failed: {build.stdout[-2000:]}{build.stderr[-2000:]}")
    return sourced_env(dest / "env.sh", dict(os.environ))


def stock_ros_recipe() -> tuple[str, str]:
    """docs/ROS.md's stock-ROS recipe: (its `colcon build` command, the setup script it sources)."""
    text = ROS_DOC.read_text(encoding="utf-8")
    section = text.split("### On a stock ROS 2 install", 1)[1]
    block = re.search(r"^```bash\n(.*?)^```", section, flags=re.S | re.M)
    assert block, "docs/ROS.md: no bash block in the stock-ROS section"
    lines = [line.split("#", 1)[0].strip() for line in block.group(1).splitlines()]
    build = next(line for line in lines if "colcon build" in line)
    setup = next(line for line in lines if line.startswith("source install/"))
    return build, setup.split()[1]


def _source_files() -> list[Path]:
    """The repository's files as a fresh clone has them (tracked, plus new files git does not ignore)."""
    try:
        out = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                             capture_output=True, check=True).stdout.decode()
        return [Path(p) for p in out.split("\0") if p and (ROOT / p).is_file()]
    except (OSError, subprocess.CalledProcessError):
        return [p.relative_to(ROOT) for p in ROOT.rglob("*") if p.is_file()
                and not _NOT_SOURCES.intersection(p.relative_to(ROOT).parts)
                and not any(part.endswith(".egg-info") for part in p.parts)]


@dataclass
class ColconWorkspace:
    root: Path
    #: The recipe's `colcon build` command as run, its output and how long it took.
    command: str
    output: str
    build_s: float
    #: ros2_upstream_env after sourcing the workspace's setup script (DDS settings: the caller's).
    env: dict[str, str]


@pytest.fixture(scope="session")
def colcon_workspace(ros2_upstream_env, tmp_path_factory) -> ColconWorkspace:
    """The package built in a fresh colcon workspace exactly as docs/ROS.md's recipe does."""
    build, setup = stock_ros_recipe()
    ws = tmp_path_factory.mktemp("colcon_ws")
    src = ws / "src" / "scene_recon"
    for rel in _source_files():
        (src / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / rel, src / rel)
    t0 = time.monotonic()
    run = subprocess.run(["bash", "-c", build], env=ros2_upstream_env, cwd=ws, capture_output=True, text=True,
                         timeout=900)
    took = time.monotonic() - t0
    output = run.stdout + run.stderr
    if run.returncode != 0:
        pytest.fail(f"`{build}` failed in {ws} ({took:.0f} s):\n{output[-4000:]}")
    return ColconWorkspace(ws, build, output, took, sourced_env(ws / setup, ros2_upstream_env, cwd=ws))
