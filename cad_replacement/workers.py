"""Replace objects in worker processes: one per core, each with its own warm caches.

Replacing one object (matching, screening, the full fits, articulation) is independent of every
other object until the global physical check, and it is pure Python + numpy + Open3D calls that
hold the interpreter lock: threads gain nothing (measured), processes scale with the cores. On the
2-core machine a 30-object scene took 7.4-8.0 s in one process.

Workers come from a ``forkserver`` (a clean, thread-free process that imports this module once and
forks workers from it; never a fork of the caller, which may run ROS executor threads or Open3D's
thread pool). Each worker unpickles the library once and keeps its own ``GeometryCache`` (restored
from the library's disk store), so the pool stays warm across scenes and graph updates. A result
comes back without its CAD model (the caller's cache rebuilds it from the entry); the numbers are
identical to an in-process run because every subsample is seeded (``CadReplacementConfig.seed``).

A pool that cannot start or dies is logged and replaced by in-process replacement, never a failure.
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import TYPE_CHECKING, Any

from .result_store import ResultStore, library_digest, library_result_store, result_key

if TYPE_CHECKING:  # the fits' modules (Open3D, trimesh, scipy: 1-2 s) load where they run, not on import
    from recon_core.classes import ClassTable

    from .geometry_cache import GeometryCache
    from .observation import ObjectObservation
    from .replace_config import CadReplacementConfig
    from .replace_object import CadSource, ObjectReplacement

log = logging.getLogger(__name__)


class _DocAsIs:
    """Stands in for SciPy's numpydoc parser in ``skip_scipy_docstring_notes``: the docstring stays as written."""

    def __init__(self, func: Any, *args: Any, **kwargs: Any) -> None:
        self._doc = getattr(func, "__doc__", None) or ""
        self._sections: dict[str, list[str]] = {}

    def __getitem__(self, key: str) -> list[str]:
        return self._sections.setdefault(key, [])

    def __setitem__(self, key: str, value: Any) -> None:
        self._sections[key] = value

    def __str__(self) -> str:
        return "\n" + self._doc  # the caller drops the first line (the signature numpydoc writes)


def skip_scipy_docstring_notes() -> None:
    """SciPy (1.15+) rewrites the docstring of each of its ~360 array-API functions as they are imported
    (numpydoc parses it to append a table of supported array backends): 0.1-0.3 CPU s of every process
    that imports trimesh or the fits (the command line, the fork server). Only help text reads those
    notes; with this their docstrings stay as SciPy wrote them. Call before SciPy's submodules load (a
    no-op where SciPy has no such step)."""
    try:
        from scipy._lib import _array_api
    except ImportError:
        return
    if hasattr(_array_api, "FunctionDoc") and hasattr(_array_api, "xp_capabilities"):
        _array_api.FunctionDoc = _DocAsIs


#: Set for the fork server (``_single_threaded_children``): this module is the first it loads, so the CAD
#: code it preloads imports SciPy without the docstring step (the command line calls the function itself,
#: after it has started the fork server: NumPy's and SciPy's imports must not delay that), and the code's
#: digest (the result and model stores' keys) is computed once there, not in every worker forked from it.
_FORK_SERVER = "SCENE_RECON_CAD_FORK_SERVER"


if os.environ.get(_FORK_SERVER) == "1":
    skip_scipy_docstring_notes()
    from recon_core.lazy_import import import_geometry_libraries
    from recon_core.process_exit import exit_without_teardown

    import_geometry_libraries()  # before the preloads import them: without Dash, Plotly and networkx
    from .result_store import code_digest

    code_digest()
    if multiprocessing.parent_process() is None:  # the fork server itself, not a worker of a spawn pool
        # its last exit handler: the loop's own clean-up has run, the workers it forked leave by os._exit
        atexit.register(exit_without_teardown, 0, run_exit_handlers=False)

#: What the fork server imports once, so that every worker forked from it starts warm.
_PRELOAD = ("cad_replacement.replace_object", "cad_replacement.geometry_cache", "scene_graph.blas")

#: Most workers ``auto`` starts: beyond a few, the scene's largest objects bound the wall time.
MAX_AUTO_WORKERS = 4

# Per-worker state (set by ``_init_worker`` in the worker process only).
_LIBRARY: Any = None
_CACHES: dict[int, GeometryCache] = {}


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity mask, not the machine's count)."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # not Linux
        return max(os.cpu_count() or 1, 1)


def resolve_workers(requested: int) -> int:
    """``CadReplacementConfig.workers`` -> a process count: 0 is auto (usable CPUs, at most 4)."""
    if requested < 0:
        raise ValueError(f"workers must be >= 0 (0: one per usable CPU), got {requested}")
    return min(usable_cpus(), MAX_AUTO_WORKERS) if requested == 0 else requested


def _init_worker(library: Any) -> None:
    """Worker start: keep the library, one BLAS thread, and leave Ctrl-C to the parent."""
    global _LIBRARY
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from scene_graph.blas import single_blas_thread

    single_blas_thread().__enter__()  # for the worker's life: the fits multiply tiny matrices
    _LIBRARY = library
    _CACHES.clear()


def _replace_in_worker(obs: ObjectObservation, config: CadReplacementConfig,
                       class_table: ClassTable | None, key: str | None = None) -> ObjectReplacement:
    """Replace one object; with ``key``, store the result for later processes (``result_store``)."""
    from .geometry_cache import GeometryCache, library_store
    from .replace_object import replace_object

    cache = _CACHES.get(config.ae_model_samples)
    if cache is None:
        cache = GeometryCache(_LIBRARY.model, samples=config.ae_model_samples, store=library_store(_LIBRARY))
        _CACHES[config.ae_model_samples] = cache
    rep = replace_object(obs, _LIBRARY, config, cache=cache, class_table=class_table)
    keep = getattr(_LIBRARY, "keep_model", None)
    if keep is not None and rep.chosen is not None:
        # the caller reads the chosen model, collision shapes included, from the library's model store
        # instead of building it and computing its collisions after every fit has come back
        keep(rep.chosen.match.entry)
    rep.model = None  # the caller rebuilds it from the entry: meshes are costly to send back
    store = library_result_store(_LIBRARY) if key is not None else None
    if store is not None and key is not None:
        store.save(key, rep)
    return rep


#: Thread-count variables of the BLAS and OpenMP runtimes the workers load (numpy's, scipy's and
#: OpenCV's OpenBLAS each start one thread per core when they load).
_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


@contextlib.contextmanager
def _single_threaded_children() -> Iterator[None]:
    """Processes started in this block (the fork server, the workers) load their BLAS and OpenMP
    runtimes with one thread (and SciPy without its docstring step: ``skip_scipy_docstring_notes``);
    this process's own environment is restored after.

    Setting the thread count once they are loaded (``single_blas_thread``) did not do it: bench-kitchen
    with 2 workers took 2.9-3.6 s that way, 2.7-2.9 s with the workers started single-threaded, and
    2.1-2.6 s with this process's Open3D on one thread as well (``open3d_threads``)."""
    saved = {k: os.environ.get(k) for k in (*_THREAD_VARIABLES, _FORK_SERVER)}
    os.environ.update({k: "1" for k in (*_THREAD_VARIABLES, _FORK_SERVER)})
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@contextlib.contextmanager
def open3d_threads(limit: int | None) -> Iterator[None]:
    """Open3D (oneTBB: ``OMP_NUM_THREADS`` does not reach it) limited to ``limit`` threads in the
    block, restored after; ``None`` leaves it alone. While worker processes fill the cores, this
    process's raycasting threads only contend with them: bench-kitchen with 2 workers took
    2.7-2.9 s, 2.3-2.4 s with one Open3D thread here."""
    if limit is None:
        yield
        return
    import open3d as o3d

    before = int(o3d.utility.get_max_threads())
    o3d.utility.set_max_threads(int(limit))
    try:
        yield
    finally:
        o3d.utility.set_max_threads(before)


def _context() -> multiprocessing.context.BaseContext:
    if "forkserver" in multiprocessing.get_all_start_methods():
        ctx = multiprocessing.get_context("forkserver")
        # The fork server imports the CAD code (numpy, Open3D, trimesh, scipy) once; workers forked
        # from it start in milliseconds instead of re-importing.
        ctx.set_forkserver_preload([__name__, *_PRELOAD])
        return ctx
    return multiprocessing.get_context("spawn")


def prestart_fork_server() -> bool:
    """Start the fork server now (single-threaded runtimes, like the workers), so that it imports the
    CAD code while this process does other work: a command-line ``replace`` had waited 1.5-2 s for
    those imports when its first object was submitted. Returns whether one was started (or runs)."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return False
    from multiprocessing import forkserver

    _context()
    try:
        with _single_threaded_children():
            forkserver.ensure_running()
    except (OSError, ValueError, RuntimeError) as exc:
        log.warning("CAD replacement fork server could not start (%s)", exc)
        return False
    return True


class ReplaceWorkers:
    """A lazily started pool of ``workers`` processes replacing objects of one library.

    ``store`` (default: none; ``"library"``: beside the library's feature cache, ``result_store``)
    keeps every result on disk: a job whose result a process stored before (same observation,
    settings, library and code) is answered from there, and the pool starts only for a job that
    is not."""

    def __init__(self, library: CadSource, workers: int, store: ResultStore | str | None = None) -> None:
        self.library = library
        self.workers = max(int(workers), 1)
        self._pool: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()
        self.failed = False
        if store is not None and store != "library" and not isinstance(store, ResultStore):
            raise ValueError(f"store must be a ResultStore, 'library' or None, got {store!r}")
        self.store: ResultStore | None = library_result_store(library) if store == "library" else \
            store if isinstance(store, ResultStore) else None
        self._library_hash: str | None = None
        #: Jobs answered from the result store / sent to the workers (for tests and the records).
        self.restored = 0
        self.submitted = 0

    @property
    def started(self) -> bool:
        return self._pool is not None

    def start(self) -> None:
        """Start the workers now (else on the first job the store cannot answer)."""
        self._ensure()

    def _ensure(self) -> ProcessPoolExecutor | None:
        with self._lock:
            return self._ensure_locked()

    def _ensure_locked(self) -> ProcessPoolExecutor | None:
        if self._pool is None and not self.failed:
            try:
                with _single_threaded_children():
                    pool = ProcessPoolExecutor(self.workers, mp_context=_context(), initializer=_init_worker,
                                               initargs=(self.library,))
                    try:
                        for f in [pool.submit(os.getpid) for _ in range(self.workers)]:
                            f.result()  # the fork server and every worker start now, under these settings
                    except BaseException:
                        pool.shutdown(wait=False, cancel_futures=True)
                        raise
                self._pool = pool
            except (OSError, ValueError, RuntimeError, BrokenProcessPool) as exc:
                log.warning("CAD replacement workers could not start (%s): replacing in this process", exc)
                self.failed = True
        return self._pool

    def submit(self, obs: ObjectObservation, config: CadReplacementConfig,
               class_table: ClassTable | None) -> Future[ObjectReplacement] | None:
        """Start replacing one observation; ``None`` when the pool is unavailable (replace in-process).
        A result in the store comes back as a finished future (its timings carry ``restored_s``)."""
        key = None
        if self.store is not None:
            t0 = time.perf_counter()
            if self._library_hash is None:
                self._library_hash = library_digest(self.library) or ""
            if self._library_hash:
                key = result_key(obs, config, class_table, self._library_hash)
                stored = self.store.load(key)
                if stored is not None and getattr(stored, "entity_id", None) == obs.entity_id:
                    stored.timings = {**stored.timings, "restored_s": time.perf_counter() - t0}
                    done: Future[ObjectReplacement] = Future()
                    done.set_result(stored)
                    self.restored += 1
                    return done
        pool = self._ensure()
        if pool is None:
            return None
        try:
            self.submitted += 1
            return pool.submit(_replace_in_worker, obs, config, class_table, key)
        except (BrokenProcessPool, RuntimeError) as exc:
            self._fail(exc)
            return None

    def result(self, future: Future[ObjectReplacement]) -> ObjectReplacement | BaseException | None:
        """A submitted job's replacement or the exception it raised; ``None`` when the pool broke
        (the worker died: the caller replaces that observation in-process)."""
        try:
            return future.result()
        except (BrokenProcessPool, OSError) as exc:
            self._fail(exc)
            return None
        except Exception as exc:  # the job's own error (e.g. ObservationError): the caller decides
            return exc

    def _fail(self, exc: BaseException) -> None:
        log.warning("CAD replacement workers failed (%s): replacing in this process from now on", exc)
        self.failed = True
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)

    def close(self) -> None:
        """Stop the workers (idempotent); a later ``replace`` starts new ones."""
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)


__all__ = ["MAX_AUTO_WORKERS", "ReplaceWorkers", "prestart_fork_server", "resolve_workers", "usable_cpus"]
