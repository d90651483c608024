"""`scene-recon`: one command line for the whole pipeline (each stage is a subcommand)."""

from __future__ import annotations

import argparse
import logging
import sys

from scene_recon import __version__
from scene_recon.commands import COMMANDS


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="scene-recon",
        description="Turn an RGB-D stream into a functionally equivalent, interactive scene "
        "(panoptic map -> contact graph -> URDF kinematic tree).",
        epilog="Run 'scene-recon COMMAND --help' for the options of one command.",
    )
    parser.add_argument("--version", action="version", version=f"scene-recon {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv: debug)")
    parser.add_argument("--debug", action="store_true", help="show the full traceback of an error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in COMMANDS:
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    from recon_core.ros_env import ensure_ros_environment

    ensure_ros_environment()
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING if args.verbose == 0 else logging.INFO if args.verbose == 1 else logging.DEBUG
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    from recon_core.errors import SceneReconError

    try:
        return int(args.func(args) or 0)
    except (SceneReconError, FileExistsError, FileNotFoundError) as exc:
        # what the user must fix, in one line (the error family says where: input, config, model, storage)
        if args.debug:
            raise
        print(f"scene-recon {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into `head` and closed early
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
