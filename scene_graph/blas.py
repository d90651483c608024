"""Run small-matrix numpy code with one BLAS thread.

Plane RANSAC multiplies (samples x 3) by (3 x hypotheses) matrices: far too small for BLAS
threads to pay off, yet OpenBLAS spreads them over every core, and on a loaded 2-core machine the
thread hand-offs made feature extraction 5x slower (measured: 0.3 s vs 1.9 s for 44 entities).
``single_blas_thread`` sets numpy's OpenBLAS to one thread for the duration of a block and
restores it after; where no OpenBLAS is found (another BLAS, a static build) it does nothing.
"""

from __future__ import annotations

import contextlib
import ctypes
from collections.abc import Iterator
from functools import lru_cache

_SETTERS = ("scipy_openblas_set_num_threads64_", "openblas_set_num_threads64_", "openblas_set_num_threads")
_GETTERS = ("scipy_openblas_get_num_threads64_", "openblas_get_num_threads64_", "openblas_get_num_threads")


@lru_cache(maxsize=1)
def _openblas() -> tuple[object, object] | None:
    """(setter, getter) of the OpenBLAS that numpy loaded, or None."""
    import numpy  # noqa: F401  (make sure numpy's BLAS is loaded)

    try:
        with open("/proc/self/maps", encoding="utf-8") as fh:
            libs = sorted({line.split()[-1] for line in fh if "openblas" in line.lower() and "/" in line})
    except OSError:
        return None
    for path in libs:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        setter = next((getattr(lib, n) for n in _SETTERS if hasattr(lib, n)), None)
        getter = next((getattr(lib, n) for n in _GETTERS if hasattr(lib, n)), None)
        if setter is not None and getter is not None:
            setter.argtypes, getter.restype = [ctypes.c_int], ctypes.c_int
            return setter, getter
    return None


@contextlib.contextmanager
def single_blas_thread() -> Iterator[None]:
    funcs = _openblas()
    if funcs is None:
        yield
        return
    setter, getter = funcs
    before = int(getter())  # type: ignore[operator]
    setter(1)  # type: ignore[operator]
    try:
        yield
    finally:
        setter(max(before, 1))  # type: ignore[operator]
