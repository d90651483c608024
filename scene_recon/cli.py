"""`scene-recon`: one command line for the whole pipeline (each stage is a subcommand)."""

from __future__ import annotations

import argparse
import codecs
import contextlib
import logging
import os
import sys
import tempfile
import threading
from pathlib import Path
from typing import NoReturn

from scene_recon import __version__
from scene_recon.commands import COMMAND_NAMES, command_module


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The whole command line; with ``command`` (a subcommand name) only that subcommand is loaded and
    added (its module's imports are all a command line pays for; `--help` of the program lists all)."""
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
    for name in (command,) if command in COMMAND_NAMES else COMMAND_NAMES:
        command_module(name).add_parser(sub)
    return parser


def _named_command(argv: list[str]) -> str | None:
    """The subcommand a command line names: its first word that is not an option (the program's own
    options take no value), when that is a subcommand; else ``None`` (the full parser decides)."""
    word = next((a for a in argv if not a.startswith("-")), None)
    return word if word in COMMAND_NAMES else None


def main(argv: list[str] | None = None) -> int:
    from recon_core.ros_env import ensure_ros_environment

    ensure_ros_environment()
    words = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(_named_command(words))
    args = parser.parse_args(words)
    level = logging.WARNING if args.verbose == 0 else logging.INFO if args.verbose == 1 else logging.DEBUG
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    from recon_core.errors import SceneReconError

    _tolerate_undecodable_paths()
    try:
        check_output_folder(args)
        with _quiet_native_output(args):
            return int(args.func(args) or 0)
    except (SceneReconError, FileExistsError, FileNotFoundError, PermissionError, NotADirectoryError,
            IsADirectoryError) as exc:
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


def _escape_undecodable(exc: UnicodeError) -> tuple[str, int]:
    """Codec error handler: a byte that was not UTF-8 in a path (a surrogate escape) as ``\\xNN``,
    anything else unencodable as ``\\uNNNN`` (backslashreplace)."""
    if not isinstance(exc, UnicodeEncodeError):
        raise exc
    bad = exc.object[exc.start:exc.end]
    return "".join(f"\\x{ord(c) - 0xDC00:02x}" if 0xDC80 <= ord(c) <= 0xDCFF else c.encode(
        "ascii", "backslashreplace").decode("ascii") for c in bad), exc.end


def _tolerate_undecodable_paths() -> None:
    """A path with bytes that are not UTF-8 (kept by Python as surrogate escapes) is printed with them
    escaped (\\xNN) instead of ending the command with UnicodeEncodeError (PYTHONIOENCODING=utf-8,
    or a UTF-8 locale other than C.UTF-8, makes stdout strict)."""
    codecs.register_error("scene_recon_escape", _escape_undecodable)
    for stream in (sys.stdout, sys.stderr):
        if getattr(stream, "errors", None) in ("strict", "backslashreplace") and hasattr(stream, "reconfigure"):
            with contextlib.suppress(ValueError, OSError):  # a stream that cannot be reconfigured
                stream.reconfigure(errors="scene_recon_escape")


def _quiet_native_output(args: argparse.Namespace) -> contextlib.AbstractContextManager:
    """With `--json` (exactly one JSON document on stdout) and for `demo` (our progress and summaries only):
    what native libraries print to file descriptors 1 and 2 is captured, and shown on stderr with -v."""
    if getattr(args, "json", False) or args.command == "demo":
        from scene_recon.native_output import native_output_captured

        return native_output_captured(show=args.verbose > 0, label="output of native libraries")
    return contextlib.nullcontext()


def check_output_folder(args: argparse.Namespace) -> None:
    """Before any work: `--out` must be a folder we can create and write (else one line, exit 2)."""
    out = getattr(args, "out", None)
    if not out or not isinstance(out, str):
        return
    from recon_core.errors import StorageError

    path = Path(out)
    if path.exists() and not path.is_dir():
        raise StorageError(f"--out {out} is a file, not a folder")
    probe = path
    while not probe.exists():  # the nearest folder that exists must let us create the rest
        if probe.parent == probe:
            break
        probe = probe.parent
    if not probe.is_dir():
        raise StorageError(f"--out {out}: {probe} is a file, not a folder")
    why = "permission denied" if not os.access(probe, os.W_OK | os.X_OK) else ""
    if not why:
        try:  # what the permission bits do not say: a read-only mount, root on a folder it may not write
            with tempfile.TemporaryFile(dir=probe, prefix=".scene-recon-probe-"):
                pass
        except OSError as exc:
            why = exc.strerror or type(exc).__name__
    if why:
        what = "is not writable" if probe == path else f"cannot be created: {probe} is not writable"
        raise StorageError(f"--out {out} {what} ({why.lower()}); choose another output folder")


def run_and_exit() -> NoReturn:
    """The ``scene-recon`` command: ``main`` on the process's arguments, then leave without the
    interpreter's teardown of what the command imported (Open3D, SciPy, trimesh, ROS: 0.2-0.3 s of every
    command, 4-8 % of a `replace`, measured by ``benchmarks/bench_replace_cli.py``). Everything an exit
    must do still happens: the exit handlers run (multiprocessing's clean-up of its fork server and
    temporary folders, logging's flush) and the output is flushed. While another thread still runs, the
    ordinary exit (which waits for it) is taken. ``main`` itself returns normally, for callers in-process."""
    code = main()
    if threading.active_count() > 1:
        sys.exit(code)
    from recon_core.process_exit import exit_without_teardown

    exit_without_teardown(code)


if __name__ == "__main__":
    run_and_exit()
