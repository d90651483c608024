"""``recon_core.lazy_import``: a library imported with some of its optional packages deferred still works,
and those packages load only when first used (fresh interpreters: the test process has them loaded)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _python(code: str) -> list[str]:
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    return out.stdout.split()


def test_trimesh_without_networkx_until_a_graph_helper_needs_it():
    out = _python(
        "import sys; from recon_core.lazy_import import import_trimesh; import_trimesh(); "
        "import trimesh; print('networkx' in sys.modules); "
        "m = trimesh.creation.box(); print(m.is_watertight, round(float(m.volume), 6), 'networkx' in sys.modules); "
        "adj = trimesh.graph.face_adjacency(mesh=m); "
        "print(len(trimesh.graph.connected_components(adj, engine='networkx')), 'networkx' in sys.modules)")
    assert out == ["False", "True", "1.0", "False", "1", "True"]


def test_an_already_imported_package_is_never_replaced_by_a_stub():
    out = _python(
        "import sys, networkx; from recon_core.lazy_import import import_trimesh; import_trimesh(); "
        "import trimesh.graph; print(trimesh.graph.nx is networkx)")
    assert out == ["True"]


def test_a_missing_library_is_left_for_its_user_to_report():
    out = _python(
        "import sys; from recon_core.lazy_import import import_deferring; print('wave' in sys.modules); "
        "import_deferring('no_such_library_here', ('wave',)); print('wave' in sys.modules); "
        "import wave; print(type(wave).__name__, hasattr(wave, 'open'))")
    assert out == ["False", "False", "module", "True"]  # no stub left behind: the real module imports
