"""A non-editable install carries the default configuration: the wheel holds config/ as package data."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_wheel_ships_every_default_config_file(tmp_path):
    result = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                             "-w", str(tmp_path), str(ROOT)], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    (wheel,) = tmp_path.glob("scene_recon-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    expected = {f"recon_core/default_config/{p.relative_to(ROOT / 'config')}"
                for p in (ROOT / "config").rglob("*.yaml")}
    assert expected and expected <= names, sorted(expected - names)
    packages = {n.split("/")[0] for n in names if n.endswith(".py")}
    assert {"recon_core", "panoptic_mapping", "scene_graph", "cad_replacement", "scene_recon",
            "ros_nodes"} <= packages
