"""The layer contract (pyproject.toml, import-linter) holds and would catch an upward import."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("recon_core", "panoptic_mapping", "scene_graph", "cad_replacement", "scene_recon", "ros_nodes")
LINT_IMPORTS = Path(sys.executable).with_name("lint-imports")


def _lint(tree: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    return subprocess.run([str(LINT_IMPORTS), "--config", str(tree / "pyproject.toml"), "--no-cache"], cwd=tree,
                          env=env, capture_output=True, text=True, timeout=120)


def _copy_tree(dst: Path) -> Path:
    for pkg in PACKAGES:
        shutil.copytree(ROOT / pkg, dst / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", dst / "pyproject.toml")
    return dst


@pytest.fixture(scope="module")
def lint_imports() -> Path:
    if not LINT_IMPORTS.exists():
        pytest.skip("import-linter is not installed in this environment (make setup installs it)")
    return LINT_IMPORTS


def test_the_tree_keeps_its_layers(lint_imports, tmp_path):
    result = _lint(_copy_tree(tmp_path))
    assert result.returncode == 0, result.stdout + result.stderr
    assert "BROKEN" not in result.stdout


@pytest.mark.parametrize(("module", "upward"), [
    ("recon_core/entity.py", "import scene_graph.builder"),
    ("panoptic_mapping/mapper.py", "from scene_recon.synthetic import scene"),
    ("scene_graph/builder.py", "import cad_replacement.cad"),
    ("cad_replacement/cad/model.py", "import ros_nodes.qos"),
])
def test_an_upward_import_breaks_the_contract(lint_imports, tmp_path, module, upward):
    tree = _copy_tree(tmp_path)
    target = tree / module
    target.write_text(target.read_text(encoding="utf-8") + f"\n{upward}  # noqa\n", encoding="utf-8")
    result = _lint(tree)
    assert result.returncode != 0
    assert "BROKEN" in result.stdout and "is not allowed to import" in result.stdout, result.stdout
