"""Leave a process without the interpreter's teardown of what it imported.

Finalizing Open3D, SciPy, trimesh and rclpy modules takes 0.2-0.3 s after a command has done its work, and
a caller reading the command's output waits for it (also for the CAD fork server's, which holds the
caller's stdout and stderr). The command line and the fork server both leave through here."""

from __future__ import annotations

import atexit
import contextlib
import os
import sys
from typing import NoReturn


def exit_without_teardown(code: int, run_exit_handlers: bool = True) -> NoReturn:
    """Flush the standard streams and end the process with `code`, skipping module teardown.
    `run_exit_handlers`: run the `atexit` handlers first (multiprocessing's clean-up of its children and
    temporary folders, logging's flush); false only for a caller that is itself such a handler."""
    if run_exit_handlers:
        atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):  # a closed pipe (output piped into `head`)
            stream.flush()
    os._exit(code)


__all__ = ["exit_without_teardown"]
