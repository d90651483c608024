"""Subcommands of `scene-recon`; each module has `add_parser(subparsers)` and sets `func`."""

from . import demo_cmd, generate_cmd, inspect_cmd, map_cmd, suite_cmd

COMMANDS = [demo_cmd, generate_cmd, suite_cmd, inspect_cmd, map_cmd]
from . import eval_map_cmd  # noqa: E402

COMMANDS.append(eval_map_cmd)
from . import eval_graph_cmd, graph_cmd  # noqa: E402

COMMANDS += [graph_cmd, eval_graph_cmd]
