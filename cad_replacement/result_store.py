"""``ResultStore``: per-object replacement results on disk, reused by the next process.

Replacing an object (matching, screening, the full fits, articulation) depends on its observation,
the library, the settings and the code, nothing else (every subsample is seeded). A command-line
``scene-recon replace`` is a new process each time, and the fits were most of what a second run of
the same graph waited for (20 objects: 5-7 s of 9-13 s). Each result is stored under a SHA-256 of

* the observation's content (points, normals, box, support height, front hint, mesh, node and class),
* the settings (``CadReplacementConfig``) and the class table,
* the library (every entry's key and content digest: its model definition or asset files),
* the code (the sources of ``cad_replacement``, ``recon_core`` and ``scene_graph``, and the versions
  of numpy, scipy, Open3D and trimesh),

so any change to one of them is a miss, never a stale result; a graph update re-fits only the objects
whose observation changed. Files are written atomically (temp + rename) by the worker that computed
the result, read with an unpickler that builds only the project's own classes, numpy arrays and
plain containers (it calls no function of theirs); a damaged or foreign file is ignored (and
overwritten by the next fit).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import io
import logging
import os
import pickle
import tempfile
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

#: Bump when the stored layout changes (the code digest covers every change of the classes stored).
RESULT_STORE_VERSION = 1
#: Packages whose sources enter the code digest (what a replacement's result can depend on).
_CODE_PACKAGES = ("cad_replacement", "recon_core", "scene_graph")
_LIBRARIES = ("numpy", "scipy", "open3d", "open3d-cpu", "trimesh")
#: The unpickler builds classes of these packages (and calls nothing else of theirs) ...
_ALLOWED_PREFIXES = ("cad_replacement.", "recon_core.", "numpy.", "collections", "pathlib")
#: ... the plain builtin types ...
_ALLOWED_BUILTINS = {"set", "frozenset", "tuple", "list", "dict", "slice", "complex", "range", "bytearray",
                     "bytes", "str", "int", "float", "bool", "object"}
#: ... and these functions: pickle's object reconstructors and numpy's array and scalar rebuilders.
_ALLOWED_FUNCTIONS = {("copyreg", "__newobj__"), ("copyreg", "__newobj_ex__"), ("copyreg", "_reconstructor"),
                      ("numpy._core.multiarray", "_reconstruct"), ("numpy.core.multiarray", "_reconstruct"),
                      ("numpy._core.multiarray", "scalar"), ("numpy.core.multiarray", "scalar"),
                      ("numpy._core.numeric", "_frombuffer"), ("numpy.core.numeric", "_frombuffer"),
                      ("numpy", "dtype"), ("numpy", "ndarray")}


def default_store_dir() -> Path:
    """``$XDG_CACHE_HOME/scene_recon/cad_results`` (``~/.cache/...`` when unset)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "scene_recon" / "cad_results"


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """SHA-256 of the replacement code and the numeric libraries' versions (computed once a process)."""
    from importlib import metadata

    h = hashlib.sha256(f"results{RESULT_STORE_VERSION}".encode())
    root = Path(__file__).resolve().parent.parent
    for package in _CODE_PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            h.update(path.relative_to(root).as_posix().encode() + b"\0")
            h.update(hashlib.sha256(path.read_bytes()).digest())
    for name in _LIBRARIES:
        try:
            h.update(f"{name}={metadata.version(name)}\0".encode())
        except metadata.PackageNotFoundError:
            h.update(f"{name}=-\0".encode())
    return h.hexdigest()


def library_digest(library: Any) -> str | None:
    """SHA-256 over every entry's key and content digest; ``None`` for a library that has no digests."""
    entries = getattr(library, "entries", None)
    digest = getattr(library, "digest", None)
    if entries is None or digest is None:
        return None
    h = hashlib.sha256(type(library).__qualname__.encode())
    for entry in sorted(entries(), key=lambda e: e.key):
        h.update(f"{entry.key}\0{digest(entry)}\0".encode())
    return h.hexdigest()


def _feed(h: Any, value: Any) -> None:
    """Add a value's content to a hash: arrays by dtype, shape and bytes, meshes by their arrays,
    dataclasses field by field, anything else by ``repr`` (one with an address never matches twice)."""
    import numpy as np

    if isinstance(value, np.ndarray):
        h.update(f"nd{value.dtype.str}{value.shape}".encode())
        h.update(np.ascontiguousarray(value).tobytes())
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        h.update(type(value).__qualname__.encode())
        for f in dataclasses.fields(value):
            h.update(f.name.encode() + b"=")
            _feed(h, getattr(value, f.name))
    elif hasattr(value, "vertices") and hasattr(value, "faces"):  # a trimesh.Trimesh
        h.update(b"mesh")
        _feed(h, np.asarray(value.vertices))
        _feed(h, np.asarray(value.faces))
    elif isinstance(value, (list, tuple)):
        h.update(f"{type(value).__name__}{len(value)}".encode())
        for v in value:
            _feed(h, v)
    elif isinstance(value, dict):
        h.update(f"dict{len(value)}".encode())
        for k in sorted(value, key=repr):
            _feed(h, k)
            _feed(h, value[k])
    elif isinstance(value, (str, bytes, int, float, complex, bool, type(None), np.generic)):
        h.update(repr(value).encode())
    elif hasattr(value, "__dict__"):  # a plain object: its attributes (a repr may abridge arrays)
        h.update(type(value).__qualname__.encode())
        _feed(h, vars(value))
    else:
        h.update(repr(value).encode())
    h.update(b"\0")


def result_key(obs: Any, config: Any, class_table: Any, library_hash: str) -> str:
    """The store key of one replacement (see the module doc)."""
    h = hashlib.sha256(f"{code_digest()}\0{library_hash}\0".encode())
    _feed(h, config)
    _feed(h, None if class_table is None else (tuple(class_table), class_table.confusion_groups))
    _feed(h, obs)
    return h.hexdigest()


class _Unpickler(pickle.Unpickler):
    """Builds only classes of the project and numpy, numpy arrays and plain containers: no function of
    theirs is called (a file from elsewhere cannot make it write files). The store is a cache in the
    user's own folder, trusted as far as that folder is; this only keeps a stray file from doing more."""

    def find_class(self, module: str, name: str) -> Any:
        if (module == "builtins" and name in _ALLOWED_BUILTINS) or (module, name) in _ALLOWED_FUNCTIONS:
            return super().find_class(module, name)
        if module.startswith(_ALLOWED_PREFIXES) or module in ("collections", "pathlib"):
            found = super().find_class(module, name)
            if isinstance(found, type):
                return found
        raise pickle.UnpicklingError(f"result store: {module}.{name} is not allowed")


@dataclasses.dataclass
class ResultStore:
    """Folder of ``<key>.pkl`` results (``key``: ``result_key``)."""

    folder: Path

    def path(self, key: str) -> Path:
        return self.folder / key[:2] / f"{key}.pkl"

    def has(self, key: str) -> bool:
        return self.path(key).is_file()

    def load(self, key: str) -> Any | None:
        path = self.path(key)
        try:
            data = path.read_bytes()
        except OSError:
            return None
        try:
            header, _, body = data.partition(b"\n")
            if header != f"scene_recon.cad_result {RESULT_STORE_VERSION} {key}".encode():
                raise ValueError("header mismatch")
            return _Unpickler(io.BytesIO(body)).load()
        except Exception as exc:  # a damaged or foreign file is a miss, whatever broke
            log.warning("result store %s unreadable (%s): replacing the object again", path, exc)
            return None

    def save(self, key: str, result: Any) -> None:
        path = self.path(key)
        tmp: Path | None = None
        try:
            body = pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL)
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, name = tempfile.mkstemp(prefix=".tmp-", suffix=".pkl", dir=path.parent)
            tmp = Path(name)
            with os.fdopen(fd, "wb") as fh:
                fh.write(f"scene_recon.cad_result {RESULT_STORE_VERSION} {key}\n".encode())
                fh.write(body)
            os.replace(tmp, path)
        except (OSError, pickle.PicklingError, TypeError, AttributeError) as exc:  # speed, never a failure
            log.warning("result store %s not written (%s)", path, exc)
            if tmp is not None:
                tmp.unlink(missing_ok=True)


def library_result_store(library: Any) -> ResultStore | None:
    """The result store beside a library's feature cache (``<cache>/cad_results``), when it has one."""
    cache_dir = getattr(library, "cache_dir", None)
    if not isinstance(cache_dir, Path) or getattr(library, "digest", None) is None:
        return None
    if cache_dir.name == "cad_features":
        return ResultStore(cache_dir.parent / "cad_results")
    return ResultStore(cache_dir / "results")


__all__ = ["RESULT_STORE_VERSION", "ResultStore", "code_digest", "default_store_dir", "library_digest",
           "library_result_store", "result_key"]
