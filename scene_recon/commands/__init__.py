"""Subcommands of `scene-recon`; each module has `add_parser(subparsers)` and sets `func`."""

from . import inspect_cmd

COMMANDS = [inspect_cmd]
