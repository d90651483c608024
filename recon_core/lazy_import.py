"""Import a heavy library without the optional packages it loads at import time but our code never uses
on the paths that matter (Open3D's Plotly viewer loads Dash and Plotly, 0.4 s; trimesh loads networkx,
0.15 s, for path and graph helpers that only some calls need). Those packages stand in as stubs while
the library imports: the library keeps a reference to the stub, and the real package is imported the
first time any of its attributes is called or looked into, so every feature still works, later.

Used by the command line and by the CAD fork server, whose start-up is on a user's critical path."""

from __future__ import annotations

import importlib
import sys
import types
from collections.abc import Sequence
from typing import Any


class _Deferred(types.ModuleType):
    """Stands in for a module while a library imports it: each attribute is a ``_DeferredAttr`` (resolved
    from the real module on first use) or a registered deferred submodule."""

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        sub = sys.modules.get(f"{self.__name__}.{name}")
        return sub if isinstance(sub, _Deferred) else _DeferredAttr(self.__name__, name)


class _DeferredAttr:
    """``module.name``, imported when first called or looked into."""

    def __init__(self, module: str, name: str) -> None:
        self._where = (module, name)

    def _target(self) -> Any:
        module, name = self._where
        if isinstance(sys.modules.get(module), _Deferred):
            del sys.modules[module]
        return getattr(importlib.import_module(module), name)

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self._target()(*args, **kwargs)

    def __getattr__(self, attr: str) -> Any:
        if attr.startswith("__"):
            raise AttributeError(attr)
        return getattr(self._target(), attr)


def import_deferring(library: str, deferred: Sequence[str]) -> None:
    """Import ``library`` with the packages ``deferred`` (and their listed submodules) as stubs, imported
    on first use. Nothing changes when ``library`` or any of them is already imported; a library that
    is not installed is left for the code that needs it to report."""
    if library in sys.modules or any(name in sys.modules for name in deferred):
        return
    stubs = {name: _Deferred(name) for name in deferred}
    sys.modules.update(stubs)
    try:
        importlib.import_module(library)
    except ImportError:
        pass  # the command that needs it says so when it imports it
    finally:
        for name, stub in stubs.items():
            if sys.modules.get(name) is stub:
                del sys.modules[name]


#: What ``import open3d`` loads for ``open3d.visualization.draw_plotly`` alone (0.4 s of its 0.8 s).
OPEN3D_UNUSED = ("dash", "plotly", "plotly.graph_objects")
#: What ``import trimesh`` loads for its graph and path helpers (``trimesh.graph`` imports it at module
#: level; 0.15 s of trimesh's 0.6 s): face adjacency, splitting and our fits use SciPy's graph code.
TRIMESH_UNUSED = ("networkx",)


def import_open3d() -> None:
    """Import Open3D without Dash and Plotly (``draw_plotly`` still works, importing them on first use)."""
    import_deferring("open3d", OPEN3D_UNUSED)


def import_trimesh() -> None:
    """Import trimesh without networkx (every trimesh function that uses it still works, importing it then)."""
    import_deferring("trimesh", TRIMESH_UNUSED)


def import_geometry_libraries() -> None:
    """Open3D and trimesh, each without the packages above (what `scene-recon replace` and the CAD fork
    server load first)."""
    import_open3d()
    import_trimesh()


__all__ = ["OPEN3D_UNUSED", "TRIMESH_UNUSED", "import_deferring", "import_geometry_libraries", "import_open3d",
           "import_trimesh"]
