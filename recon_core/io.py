"""Atomic file writes: a reader (or a crash) never sees a half-written file.

Everything the pipeline persists (entities, graphs, configs, checkpoints) is written to a temporary
file in the same folder, flushed and fsynced, then renamed over the target: the previous version
stays intact until the new one is complete.
"""

from __future__ import annotations

import io
import os
import tempfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np


def write_bytes_atomic(path: str | Path, data: bytes, *, sync: bool = True) -> Path:
    """Write ``data`` to ``path`` via a temporary file + rename (POSIX-atomic on one filesystem).

    ``sync=False`` skips the fsync: for caches, where a file lost to a power cut is rebuilt, and the
    fsync of every entry would cost more than the cache saves; the rename still keeps readers from
    ever seeing half a file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            if sync:
                fh.flush()
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def write_text_atomic(path: str | Path, text: str) -> Path:
    """``write_bytes_atomic`` for UTF-8 text."""
    return write_bytes_atomic(path, text.encode("utf-8"))


def write_npz_atomic(path: str | Path, arrays: Mapping[str, np.ndarray], *, sync: bool = True) -> Path:
    """``write_bytes_atomic`` for an uncompressed ``.npz`` of ``arrays`` (built in memory first)."""
    buf = io.BytesIO()
    np.savez(buf, **arrays)  # type: ignore[arg-type]
    return write_bytes_atomic(path, buf.getvalue(), sync=sync)


__all__ = ["write_bytes_atomic", "write_npz_atomic", "write_text_atomic"]
