"""The launch files through the real launch machinery (issue 24, item 1): upstream launch / launch_ros /
ros2cli built by ../shared/ros2-upstream/build_prefix.sh beside the venv's PyPI rclpy, and this package
in an ament prefix laid out as `colcon build` installs it (share/scene_recon/{package.xml,launch},
the node executables in lib/scene_recon). `ros2 launch scene_recon <file> --show-args` loads each file;
`mapping.launch.py out:=DIR` starts a mapper whose data root is DIR/map (not the current directory).

Skipped where the upstream sources are absent. The prefix is built once per session (conftest.py,
`ros2_upstream_env`; 1-2 min): set SCENE_RECON_ROS2_PREFIX to a folder built before to reuse it."""

from __future__ import annotations

import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from testsupport.ros import domain_id

from recon_core.ros_graph import BAG_ARGUMENTS, LIVE_ARGUMENTS
from scene_recon.ros_runner.processes import interrupt_group

pytestmark = [pytest.mark.ros, pytest.mark.slow]
ROOT = Path(__file__).resolve().parents[2]
LAUNCH_FILES = sorted(p.name for p in (ROOT / "launch").glob("*.launch.py"))
EXECUTABLES = ("rgbd_player", "segmentation_service", "panoptic_mapper", "contact_graph_node", "cad_replacer")


@pytest.fixture(scope="module")
def ros2_env(ros2_upstream_env, tmp_path_factory) -> dict[str, str]:
    """Environment of a shell that sourced the upstream prefix (conftest) and this package's install prefix."""
    venv = Path(sys.prefix)
    # this package, as colcon's ament_python install lays it out
    pkg = tmp_path_factory.mktemp("scene_recon_prefix")
    (pkg / "share" / "ament_index" / "resource_index" / "packages").mkdir(parents=True)
    (pkg / "share" / "ament_index" / "resource_index" / "packages" / "scene_recon").touch()
    share = pkg / "share" / "scene_recon"
    shutil.copytree(ROOT / "launch", share / "launch")
    shutil.copy(ROOT / "package.xml", share / "package.xml")
    (pkg / "lib" / "scene_recon").mkdir(parents=True)
    for exe in EXECUTABLES:
        (pkg / "lib" / "scene_recon" / exe).symlink_to(venv / "bin" / exe)
    env = dict(ros2_upstream_env)
    env["AMENT_PREFIX_PATH"] = f"{pkg}:{env['AMENT_PREFIX_PATH']}"
    env.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain_id("spare1")))
    return env


@pytest.mark.parametrize("name", LAUNCH_FILES)
def test_ros2_launch_show_args(ros2_env, name, tmp_path):
    run = subprocess.run(["ros2", "launch", "scene_recon", name, "--show-args"], env=ros2_env, cwd=tmp_path,
                         capture_output=True, text=True, timeout=120)
    out = run.stdout + run.stderr
    assert run.returncode == 0 and "Traceback" not in out, out[-3000:]
    assert "Arguments (pass arguments as '<name>:=<value>'):" in out
    expected = {"bag.launch.py": [n for n, _, _ in BAG_ARGUMENTS],
                "reconstruct.launch.py": [n for n, _, _ in LIVE_ARGUMENTS],
                "mapping.launch.py": ["source", "backend", "ground_truth", "out"],
                "play_recording.launch.py": ["source"]}.get(name, [])
    for arg in expected:
        assert f"'{arg}':" in out, (arg, out[-3000:])


def test_mapping_launch_puts_the_map_under_out(ros2_env, tmp_path):
    """`out:=DIR`: the mapper's data root (checkpoints, saved maps) is DIR/map, not ./scene_recon_data."""
    out = tmp_path / "run_out"
    proc = subprocess.Popen(["ros2", "launch", "scene_recon", "mapping.launch.py", f"out:={out}"], env=ros2_env,
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(proc.stdout.readline, "")), daemon=True)
    reader.start()
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not any("data root" in line for line in lines):
            time.sleep(0.5)
        time.sleep(2.0)  # the nodes' timers and executor threads running
    finally:
        interrupt_group(proc, 60)
        reader.join(timeout=10)
    text = "".join(lines)
    assert f"data root {out / 'map'}" in text, text[-3000:]
    assert not (tmp_path / "scene_recon_data").exists()
    assert "never retrieved" not in text and "Traceback" not in text, text[-3000:]
    assert "[WARN]" not in text and "process has finished cleanly" in text, text[-3000:]  # clean start and stop
