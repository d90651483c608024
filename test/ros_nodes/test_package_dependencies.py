"""package.xml declares what the nodes import (issue 24, item 2): on a stock ROS 2 install, `rosdep install
--from-paths src` reads package.xml only. Every third-party top-level module imported (at module level
or inside a function) under the packages the nodes run is declared there by its rosdep key, or, where
rosdep has no key, is a pinned line of requirements.txt (docs/ROS.md: `pip install -r requirements.txt`)."""

from __future__ import annotations

import ast
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("ros_nodes", "recon_core", "panoptic_mapping", "scene_graph", "cad_replacement")
#: This repository's own packages, and stdlib modules newer than this Python (3.14's compression.zstd).
OWN = {"ros_nodes", "recon_core", "panoptic_mapping", "scene_graph", "cad_replacement", "scene_recon", "compression"}
#: ROS 2 packages whose Python module has the package's name (declared as themselves).
ROS = {"rclpy", "rcl_interfaces", "builtin_interfaces", "rosgraph_msgs", "std_msgs", "std_srvs", "geometry_msgs",
       "sensor_msgs", "shape_msgs", "visualization_msgs", "diagnostic_msgs", "tf2_msgs", "scene_recon_interfaces",
       "launch", "launch_ros"}
#: import name -> rosdep key (rosdistro's rosdep/python.yaml, checked 2026-08) ...
ROSDEP = {"numpy": "python3-numpy", "scipy": "python3-scipy", "yaml": "python3-yaml", "networkx": "python3-networkx",
          "cv2": "python3-opencv", "lxml": "python3-lxml", "matplotlib": "python3-matplotlib", "tqdm": "python3-tqdm",
          "rtree": "python3-rtree", "shapely": "python3-shapely", "open3d": "python3-open3d-pip",
          "onnxruntime": "python3-onnxruntime-pip", "trimesh": "python3-trimesh-pip",
          "rosbags": "python3-rosbags-pip", "yourdfpy": "python3-yourdfpy-pip",
          # rosbags' own dependencies (its MCAP chunk codecs): installed with it
          "lz4": "python3-rosbags-pip", "backports": "python3-rosbags-pip"}
#: ... or, without a rosdep key, the pip distribution in requirements.txt.
PIP_ONLY = {"manifold3d": "manifold3d", "fcl": "python-fcl", "embreex": "embreex", "coacd": "coacd"}
#: Modules trimesh uses when they are installed (ray casts, collision, spatial index, polygons): the
#: stages' results depend on them although no file imports them by name.
TRIMESH_BACKENDS = ("embreex", "fcl", "rtree", "shapely")


def _imports() -> dict[str, set[str]]:
    """top-level module -> files importing it (absolute imports only)."""
    found: dict[str, set[str]] = {}
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    found.setdefault(name.split(".")[0], set()).add(str(path.relative_to(ROOT)))
    return found


def _declared() -> set[str]:
    root = ET.parse(ROOT / "package.xml").getroot()
    return {e.text.strip() for tag in ("depend", "exec_depend") for e in root.findall(tag) if e.text}


def _requirements() -> set[str]:
    names = set()
    for line in (ROOT / "requirements.txt").read_text().splitlines():
        line = line.split("#")[0].strip()
        if line:
            names.add(re.split(r"[=<>!~;\[ ]", line)[0].lower())
    return names


def test_every_imported_third_party_module_is_declared():
    declared, pip = _declared(), _requirements()
    third_party = {m: files for m, files in _imports().items()
                   if m not in sys.stdlib_module_names and m not in OWN}
    unmapped = {m: sorted(f)[:3] for m, f in third_party.items() if m not in ROS | set(ROSDEP) | set(PIP_ONLY)}
    assert not unmapped, f"new third-party imports: add a rosdep key (package.xml) or a requirements.txt line, " \
                         f"and map them in this test: {unmapped}"
    missing = []
    for module in sorted(third_party):
        if module in ROS or module in ROSDEP:
            key = module if module in ROS else ROSDEP[module]
            if key not in declared:
                missing.append(f"{module}: <exec_depend>{key}</exec_depend>")
        elif PIP_ONLY[module] not in pip:
            missing.append(f"{module}: requirements.txt {PIP_ONLY[module]}")
    assert not missing, missing


def test_trimesh_backends_are_declared_too():
    declared, pip = _declared(), _requirements()
    for module in TRIMESH_BACKENDS:
        assert (module in ROSDEP and ROSDEP[module] in declared) or PIP_ONLY.get(module) in pip, module


def test_the_pip_keys_name_pip_packages_of_requirements_txt():
    """A `-pip` rosdep key installs the same distribution the venv pins (requirements.txt)."""
    pip = _requirements()
    for key in {k for k in _declared() if k.endswith("-pip")}:
        dist = key.removeprefix("python3-").removesuffix("-pip")
        assert dist in pip or dist.replace("-", "_") in pip or {"open3d": "open3d-cpu"}.get(dist) in pip, key


def _pins(name: str) -> dict[str, str]:
    pins = {}
    for line in (ROOT / name).read_text().splitlines():
        line = line.split("#")[0].strip()
        if line:
            dist = re.split(r"[=<>!~;\[ ]", line)[0].lower()
            pins[dist] = line[len(dist):].strip()
    return pins


def test_the_stock_ros_requirements_complete_package_xml():
    """requirements-ros.txt (pip, in a venv over /opt/ros): no ROS wheel, numpy kept below 2 (ROS's compiled
    modules), every pip-only and pip-key package, at requirements.txt's pins."""
    stock, venv = _pins("requirements-ros.txt"), _pins("requirements.txt")
    assert not [d for d in stock if d.startswith(("ros-", "colcon"))]
    assert stock.pop("numpy") == "<2"
    pip_keys = {k.removeprefix("python3-").removesuffix("-pip") for k in _declared() if k.endswith("-pip")}
    needed = set(PIP_ONLY.values()) | {{"open3d": "open3d-cpu"}.get(d, d) for d in pip_keys}
    assert needed <= set(stock), needed - set(stock)
    for dist, pin in stock.items():
        assert venv.get(dist) == pin, (dist, pin, venv.get(dist))
