"""Native libraries' own output kept off our console: capture at the file-descriptor level.

PyBullet prints ``pybullet build time: ...`` and ``b3Warning[...]`` lines, MuJoCo and Open3D their
warnings, from C/C++ straight to file descriptors 1 and 2; ``contextlib.redirect_stdout`` cannot
catch them. ``native_output_captured`` points the descriptors at a temporary file for its block,
while Python's ``sys.stdout``/``sys.stderr`` (and the logging handlers writing to them) keep
writing to the real console through duplicates of the original descriptors. So a ``--json``
command writes exactly one JSON document on stdout, and the chatter is shown (on stderr) only when
asked for (``-v``). Blocks nest: an inner block captures into its own file and restores the outer
one's. Child processes started inside a block inherit the capture.
"""

from __future__ import annotations

import contextlib
import ctypes
import io
import logging
import os
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass

_STREAMS = {1: "stdout", 2: "stderr"}


@dataclass
class NativeOutput:
    """What the native code wrote inside a ``native_output_captured`` block (filled when it ends)."""

    text: str = ""

    def lines(self) -> list[str]:
        return [line for line in self.text.splitlines() if line.strip()]


def _flush_c_stdio() -> None:
    """Flush C's stdio buffers: printf output to a file or pipe sits there until then."""
    with contextlib.suppress(OSError, AttributeError):  # no C library to ask (not on this platform)
        ctypes.CDLL(None).fflush(None)


def _fileno(stream: object) -> int | None:
    try:
        return int(stream.fileno())  # type: ignore[attr-defined]
    except (AttributeError, OSError, ValueError, io.UnsupportedOperation):
        return None


def _flush(stream: object) -> None:
    with contextlib.suppress(AttributeError, OSError, ValueError):
        stream.flush()  # type: ignore[attr-defined]


@contextlib.contextmanager
def native_output_captured(show: bool = False, fds: tuple[int, ...] = (1, 2),
                           label: str = "native output") -> Iterator[NativeOutput]:
    """Capture what is written to the file descriptors `fds` (default stdout and stderr) in the block.

    Python's own ``sys.stdout``/``sys.stderr`` still reach the console when they write to those
    descriptors (they are swapped for streams on duplicates for the block); streams that are not
    the descriptors themselves (pytest's capture, a StringIO) are left alone. `show`: write the
    captured text to stderr when the block ends (``-v``), under a line naming `label`.
    """
    result = NativeOutput()
    for name in _STREAMS.values():
        _flush(getattr(sys, name))
    _flush_c_stdio()
    saved: dict[int, int] = {}
    swapped: list[tuple[str, object, io.TextIOWrapper]] = []
    handlers: list[tuple[logging.StreamHandler, object]] = []
    sink = tempfile.TemporaryFile()  # noqa: SIM115 - closed in the finally clause, after reading
    try:
        for fd in fds:
            try:
                saved[fd] = os.dup(fd)
            except OSError:  # descriptor closed: nothing can be written there anyway
                continue
        for fd, copy in saved.items():
            name = _STREAMS.get(fd, "")
            stream = getattr(sys, name) if name else None
            if name and stream is not None and _fileno(stream) == fd:
                replacement = open(os.dup(copy), "w", encoding=getattr(stream, "encoding", None) or "utf-8",  # noqa: SIM115
                                   errors=getattr(stream, "errors", None) or "backslashreplace",
                                   buffering=1, closefd=True)
                setattr(sys, name, replacement)
                swapped.append((name, stream, replacement))
                for handler in _stream_handlers():
                    if handler.stream is stream:
                        handlers.append((handler, stream))
                        handler.setStream(replacement)
            os.dup2(sink.fileno(), fd)
        yield result
    finally:
        for _name, _old, new in swapped:
            _flush(new)
        _flush_c_stdio()
        for fd, copy in saved.items():
            os.dup2(copy, fd)
            os.close(copy)
        for handler, old in handlers:
            handler.setStream(old)
        for name, old, new in swapped:
            setattr(sys, name, old)
            new.close()
        sink.seek(0)
        result.text = sink.read().decode("utf-8", errors="replace")
        sink.close()
        if show and result.text.strip():
            text = result.text if result.text.endswith("\n") else result.text + "\n"
            sys.stderr.write(f"-- {label} (captured) --\n{text}-- end of {label} --\n")
            _flush(sys.stderr)


def _stream_handlers() -> list[logging.StreamHandler]:
    loggers = [logging.getLogger()] + [lg for lg in logging.Logger.manager.loggerDict.values()
                                       if isinstance(lg, logging.Logger)]
    return [h for lg in loggers for h in lg.handlers
            if isinstance(h, logging.StreamHandler) and not isinstance(h, logging.FileHandler)]


__all__ = ["NativeOutput", "native_output_captured"]
