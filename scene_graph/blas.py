"""Run small-matrix numpy code with one BLAS thread.

Plane RANSAC multiplies (samples x 3) by (3 x hypotheses) matrices: far too small for BLAS
threads to pay off, yet OpenBLAS spreads them over every core, and on a loaded 2-core machine the
thread hand-offs made feature extraction 5x slower (measured: 0.3 s vs 1.9 s for 44 entities).
``single_blas_thread`` sets every OpenBLAS in the process (numpy's, scipy's, OpenCV's) to one thread
for the duration of a block and restores it after; where no OpenBLAS is found (another BLAS, a
static build) it does nothing.
"""

from __future__ import annotations

import contextlib
import ctypes
from collections.abc import Iterator
from typing import Any

_SETTERS = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads", "openblas_set_num_threads64_",
            "openblas_set_num_threads")
_GETTERS = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads", "openblas_get_num_threads64_",
            "openblas_get_num_threads")


_HANDLES: dict[str, tuple[Any, Any] | None] = {}


def _openblas_libraries() -> list[tuple[Any, Any]]:
    """(setter, getter) of every OpenBLAS loaded in this process.

    numpy, scipy and OpenCV each bring their own copy, each with one thread per core; limiting numpy's
    alone left scipy's (linear algebra) free to use every core. (For the stage-4 worker processes
    this was not enough on its own: they start single-threaded, ``cad_replacement.workers``.)"""
    try:
        with open("/proc/self/maps", encoding="utf-8") as fh:
            libs = sorted({line.split()[-1] for line in fh if "openblas" in line.lower() and "/" in line})
    except OSError:
        return []
    out = []
    for path in libs:
        if path not in _HANDLES:
            _HANDLES[path] = _load(path)
        funcs = _HANDLES[path]
        if funcs is not None:
            out.append(funcs)
    return out


def _load(path: str) -> tuple[Any, Any] | None:
    try:
        lib = ctypes.CDLL(path)
    except OSError:
        return None
    setter = next((getattr(lib, n) for n in _SETTERS if hasattr(lib, n)), None)
    getter = next((getattr(lib, n) for n in _GETTERS if hasattr(lib, n)), None)
    if setter is None or getter is None:
        return None
    setter.argtypes, getter.restype = [ctypes.c_int], ctypes.c_int
    return setter, getter


@contextlib.contextmanager
def single_blas_thread() -> Iterator[None]:
    import numpy  # noqa: F401  (make sure numpy's BLAS is loaded)

    libs = _openblas_libraries()
    before = [int(getter()) for _setter, getter in libs]
    for setter, _getter in libs:
        setter(1)
    try:
        yield
    finally:
        for (setter, _getter), n in zip(libs, before, strict=True):
            setter(max(n, 1))
