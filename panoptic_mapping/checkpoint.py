"""Checkpoints of a mapping run: a crash, a kill or a power cut loses at most one checkpoint interval.

A checkpoint store is a folder of generations::

    checkpoints/
      gen-000007/   map.npz, map.json (the map, as PanopticMapper.save writes it),
                    progress.npz (arrays of the run: camera poses), checkpoint.json (the manifest)
      gen-000008/   ...

A generation is written into a hidden temporary folder, every file fsynced, then the folder is
renamed to its final name: a generation either exists complete or not at all, and the previous
ones stay untouched until the new one is in place (only then are generations beyond `keep`
deleted). The manifest holds the generation id, the SHA-256 and size of every file (so map.npz
and map.json are checked as a pair) and the run's progress (how much of the input was consumed).
Loading tries the newest generation first; a damaged one (truncated npz, bad JSON, mismatched
files) is reported, naming the file, and the next older one is used.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import os
import re
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from panoptic_mapping.config import CheckpointConfig
from panoptic_mapping.mapper import MapSnapshot, PanopticMapper
from recon_core.errors import CheckpointError
from recon_core.io import write_bytes_atomic, write_text_atomic

log = logging.getLogger(__name__)

#: Folder of the checkpoint store inside an output folder.
CHECKPOINT_DIR = "checkpoints"
MANIFEST = "checkpoint.json"
PROGRESS_ARRAYS = "progress.npz"
_GEN = re.compile(r"^gen-(\d{6,})$")
CHECKPOINT_FORMAT_VERSION = 1


@dataclass
class Checkpoint:
    """A checkpoint loaded back: the map, the run's progress and arrays, where it came from."""

    mapper: PanopticMapper
    generation: int
    path: Path
    progress: dict[str, Any]
    arrays: dict[str, np.ndarray]
    #: Newer generations that could not be used, each with the reason (the file named).
    skipped: list[str] = field(default_factory=list)


def _sha256(path: Path) -> tuple[str, int]:
    h = hashlib.sha256()
    n = 0
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
            n += len(chunk)
    return h.hexdigest(), n


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


class CheckpointStore:
    """Generations of checkpoints in one folder (see the module docstring)."""

    def __init__(self, folder: str | Path, keep: int = 2):
        self.folder = Path(folder)
        self.keep = max(1, int(keep))

    def generations(self) -> list[tuple[int, Path]]:
        """(generation, folder) of every complete generation, newest first."""
        if not self.folder.is_dir():
            return []
        out = []
        for p in self.folder.iterdir():
            m = _GEN.match(p.name)
            if m and p.is_dir():
                out.append((int(m.group(1)), p))
        return sorted(out, reverse=True)

    def __bool__(self) -> bool:
        return bool(self.generations())

    # ------------------------------------------------------------------ writing
    def save(self, snapshot: MapSnapshot | PanopticMapper, progress: dict[str, Any] | None = None,
             arrays: dict[str, np.ndarray] | None = None) -> Path:
        """Write a new generation (a snapshot taken under the caller's lock, or a mapper) and return it."""
        snap = snapshot.snapshot() if isinstance(snapshot, PanopticMapper) else snapshot
        self.folder.mkdir(parents=True, exist_ok=True)
        gens = self.generations()
        gen = (gens[0][0] + 1) if gens else 1
        tmp = self.folder / f".gen-{gen:06d}.tmp-{os.getpid()}"
        if tmp.exists():
            shutil.rmtree(tmp)
        try:
            snap.write(tmp)
            buf = io.BytesIO()
            np.savez(buf, **(arrays or {}))  # type: ignore[arg-type]  # numpy's stub types **kwds as bool
            write_bytes_atomic(tmp / PROGRESS_ARRAYS, buf.getvalue())
            files = {}
            for name in ("map.npz", "map.json", PROGRESS_ARRAYS):
                digest, size = _sha256(tmp / name)
                files[name] = {"sha256": digest, "bytes": size}
            manifest = {"format_version": CHECKPOINT_FORMAT_VERSION, "generation": gen,
                        "created_unix_s": time.time(), "frames_integrated": snap.meta.get("frames_integrated"),
                        "files": files, "progress": progress or {}}
            write_text_atomic(tmp / MANIFEST, json.dumps(manifest, indent=1))
            _fsync_dir(tmp)
            final = self.folder / f"gen-{gen:06d}"
            os.rename(tmp, final)  # the generation appears complete, or not at all
            _fsync_dir(self.folder)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        self._prune()
        return final

    def _prune(self) -> None:
        for _gen, path in self.generations()[self.keep:]:
            shutil.rmtree(path, ignore_errors=True)
        for p in self.folder.glob(".gen-*.tmp-*"):  # left by a writer killed mid-way
            pid = p.name.rsplit("-", 1)[-1]
            if pid != str(os.getpid()) and not _alive(pid):
                shutil.rmtree(p, ignore_errors=True)

    # ------------------------------------------------------------------ reading
    @staticmethod
    def read(path: Path) -> Checkpoint:
        """Load one generation; CheckpointError (naming the file) when it is damaged or incomplete."""
        manifest_path = path / MANIFEST
        m = _GEN.match(path.name)
        if not manifest_path.is_file():
            raise CheckpointError(f"{manifest_path}: missing (incomplete checkpoint)")
        try:
            manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
            files = manifest["files"]
            progress = dict(manifest.get("progress") or {})
        except (ValueError, UnicodeDecodeError, KeyError, TypeError) as exc:
            raise CheckpointError(f"{manifest_path}: damaged ({type(exc).__name__}: {exc})") from None
        for name, want in files.items():
            f = path / name
            if not f.is_file():
                raise CheckpointError(f"{f}: missing from the checkpoint")
            digest, size = _sha256(f)
            if digest != want.get("sha256"):
                raise CheckpointError(f"{f}: damaged (checksum mismatch; {size} bytes, the checkpoint wrote "
                                      f"{want.get('bytes')}): truncated, modified or not of this checkpoint")
        mapper = PanopticMapper.load(path)  # checks map.json <-> map.npz again, and the contents
        arrays: dict[str, np.ndarray] = {}
        if (path / PROGRESS_ARRAYS).is_file():
            try:
                with np.load(path / PROGRESS_ARRAYS, allow_pickle=False) as npz:
                    arrays = {k: npz[k] for k in npz.files}
            except Exception as exc:
                raise CheckpointError(f"{path / PROGRESS_ARRAYS}: damaged ({exc})") from None
        gen = int(m.group(1)) if m else int(manifest.get("generation", 0))
        return Checkpoint(mapper, gen, path, progress, arrays)

    def load_latest(self) -> Checkpoint:
        """The newest usable generation; each newer damaged one is logged as a warning and skipped.

        Raises CheckpointError when there is none (the message lists why each one was refused).
        """
        skipped: list[str] = []
        for gen, path in self.generations():
            try:
                ckpt = self.read(path)
            except (CheckpointError, FileNotFoundError) as exc:
                skipped.append(str(exc))
                log.warning("checkpoint generation %d unusable: %s; trying an older one", gen, exc)
                continue
            ckpt.skipped = skipped
            if skipped:
                log.warning("resuming from the older checkpoint %s", path)
            return ckpt
        if skipped:
            raise CheckpointError(f"no usable checkpoint in {self.folder}: " + "; ".join(skipped))
        raise CheckpointError(f"no checkpoint in {self.folder}")


def _alive(pid: str) -> bool:
    try:
        os.kill(int(pid), 0)
    except (ValueError, ProcessLookupError):
        return False
    except PermissionError:
        return True
    return True


class Checkpointer:
    """When to checkpoint: every `every_n_frames` integrated frames and/or every `every_s` seconds.

    `due(frames)` asks with the mapper's frame count; `save(...)` writes a generation and restarts
    both clocks. `last_cost_s` / `total_cost_s` measure what checkpoints cost the run.
    """

    def __init__(self, store: CheckpointStore, config: CheckpointConfig,
                 clock: Callable[[], float] = time.monotonic):
        self.store = store
        self.config = config
        self.clock = clock
        self._last_t = clock()
        self.last_frames: int | None = None
        self.saved = 0
        self.last_cost_s = 0.0
        self.total_cost_s = 0.0
        self.last_path: Path | None = None

    def start(self, frames: int) -> None:
        """Count the interval from now and from `frames` (a resumed map's count)."""
        self._last_t = self.clock()
        self.last_frames = frames

    def due(self, frames: int) -> bool:
        c = self.config
        if not c.enabled:
            return False
        if self.last_frames is None:
            self.last_frames = frames
        if frames <= self.last_frames:
            return False
        if c.every_n_frames > 0 and frames - self.last_frames >= c.every_n_frames:
            return True
        return c.every_s > 0 and self.clock() - self._last_t >= c.every_s

    def save(self, snapshot: MapSnapshot | PanopticMapper, progress: dict[str, Any] | None = None,
             arrays: dict[str, np.ndarray] | None = None) -> Path:
        t0 = time.perf_counter()
        snap = snapshot.snapshot() if isinstance(snapshot, PanopticMapper) else snapshot
        path = self.store.save(snap, progress, arrays)
        self.last_cost_s = time.perf_counter() - t0
        self.total_cost_s += self.last_cost_s
        self.saved += 1
        self.last_path = path
        self._last_t = self.clock()
        self.last_frames = int(snap.meta.get("frames_integrated", 0))
        log.info("checkpoint %s written (%d frames, %.2f s)", path, self.last_frames, self.last_cost_s)
        return path


__all__ = ["CHECKPOINT_DIR", "Checkpoint", "CheckpointStore", "Checkpointer"]
