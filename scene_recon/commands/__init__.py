"""Subcommands of `scene-recon`; each module has `add_parser(subparsers)` and sets `func`.

Modules are imported when asked for: a command line loads only the subcommand it names (`scene-recon
replace` had imported every stage, Open3D and the evaluation included, 1.2 s, before parsing its
arguments). ``COMMANDS`` (every module, in pipeline order) is still there for whoever needs them all.
"""

from __future__ import annotations

import importlib
from types import ModuleType
from typing import Any

#: Subcommand names in pipeline order (what `--help` lists); the module of `eval-map` is `eval_map_cmd`.
COMMAND_NAMES = ("demo", "generate", "suite", "inspect", "map", "eval-map", "graph", "eval-graph", "replace",
                 "eval-scene", "run", "ros-run", "benchmark")


def command_module(name: str) -> ModuleType:
    """The module of one subcommand (``KeyError`` for a name that is none)."""
    if name not in COMMAND_NAMES:
        raise KeyError(name)
    return importlib.import_module(f"{__name__}.{name.replace('-', '_')}_cmd")


def __getattr__(name: str) -> Any:
    if name == "COMMANDS":  # every subcommand module, in pipeline order
        return [command_module(n) for n in COMMAND_NAMES]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
