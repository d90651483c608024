"""One way to run a node: environment, init, spin until Ctrl-C / SIGTERM, clean shutdown (exit 0).

SIGINT and SIGTERM only set a flag (`init_ros` installs the handlers instead of rclpy's own, which
shut the context down at once): the spin loop sees it between two waits, the executor finishes the
callbacks still running, the node's `on_shutdown()` runs (the mapper's last checkpoint), and only
then are the node and the context destroyed. Shutting rclpy down from inside the signal handler
made a callback that was publishing at that moment die with InvalidHandle (a traceback, exit 1).

A node that shut down cleanly exits 0 even when Open3D tensors are still allocated at the very end
(`keep_exit_code_from_open3d`): Open3D's allocation statistics call ``exit(1)`` then.
"""

from __future__ import annotations

import ctypes
import faulthandler
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import rclpy
import rclpy.logging
from rclpy.callback_groups import CallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import InvalidHandle
from rclpy.executors import Executor, ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.timer import Timer

from recon_core.ros_env import ensure_ros_environment
from ros_nodes.dds_profile import apply_dds_profile
from ros_nodes.parameters import warn_unknown_parameters

#: How often (s) the spin loop looks at the stop flag.
STOP_POLL_S = 0.1
#: How long (s) a node may take from SIGINT/SIGTERM to its exit before the exit watchdog ends it. An orderly
#: stop takes well under a second; `scene-recon ros-run` kills a node still running after 30 s.
EXIT_DEADLINE_S = 20.0
#: How long (s) the executor's callbacks get to finish once the node stops spinning.
DRAIN_S = 10.0

#: Set once a node's own shutdown (`on_shutdown`: the mapper's last checkpoint) has run: what is left is
#: the middleware's teardown, which the exit watchdog may cut short without losing anything.
_node_state_saved = threading.Event()
#: Set while that shutdown runs: a long last checkpoint is not cut short (the supervisor has the last word).
_node_saving = threading.Event()


def steady_timer(node: Node, period_s: float, callback: Callable[[], None],
                 callback_group: CallbackGroup | None = None) -> Timer:
    """A timer on the steady clock, for a node's own work (integrating, publishing, status).

    With `use_sim_time` a node's default timers run on /clock: when a bag is paused or has ended,
    /clock stops and so would such timers, leaving the last frames unintegrated and the scene
    unpublished. Stamps still come from the node's clock (the recording's time)."""
    return node.create_timer(period_s, callback, callback_group=callback_group,
                             clock=Clock(clock_type=ClockType.STEADY_TIME))


def init_ros(args: list[str] | None = None) -> threading.Event:
    """rclpy.init without rclpy's signal handlers; returns the event SIGINT/SIGTERM set. The project's Fast
    DDS writer profile is applied to this process first (`ros_nodes.dds_profile`: a lost reliable sample is
    resent within 0.1 s instead of 3 s)."""
    ensure_ros_environment()
    profile = apply_dds_profile()
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    log = rclpy.logging.get_logger("dds_profile")
    (log.warning if profile.problem else log.info)(profile.note)
    stop = threading.Event()

    def _on_signal(_signum: int, _frame: object) -> None:
        stop.set()

    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, _on_signal)
        # A supervisor about to kill a node that did not stop in time sends SIGUSR1 first: every thread's
        # Python stack goes to stderr (the node's log), so the log says where the shutdown hung.
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    return stop


def start_exit_watchdog(stop: threading.Event, deadline_s: float = EXIT_DEADLINE_S,
                        nothing_to_save: bool = False) -> threading.Thread:
    """Bound a node's exit: `deadline_s` after `stop` is set, a process still running writes every thread's
    stack to stderr (the node's log) and ends itself, with exit code 0 when the node's own shutdown had
    completed (`shutdown_node`; `nothing_to_save`: a node with no state) and only the teardown hung, else 1.

    Seen once in CI: a segmentation service was still running 30 s after SIGINT and the runner killed it
    (-9) without a trace of where it hung. A callback thread stuck in the middleware keeps a multi-threaded
    executor's shutdown (it joins its thread pool) and Python's own exit (it joins every pool thread) from
    ever returning; this names the place and ends the process while the supervisor still waits."""

    def watch() -> None:
        stop.wait()
        time.sleep(deadline_s)
        if _node_saving.is_set():
            while _node_saving.is_set():
                time.sleep(0.1)
            time.sleep(min(deadline_s, 5.0))
        done = nothing_to_save or _node_state_saved.is_set()
        sys.stderr.write(f"exit watchdog: the node is still running {deadline_s:.0f} s after the stop signal "
                         f"({'its shutdown had completed' if done else 'its shutdown had not completed'}); "
                         "the threads' stacks:\n")
        sys.stderr.flush()
        faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
        sys.stderr.flush()
        sys.stdout.flush()
        os._exit(0 if done else 1)

    thread = threading.Thread(target=watch, name="exit-watchdog", daemon=True)
    thread.start()
    return thread


def make_executor(node: Node, threads: int = 1) -> Executor:
    """The executor `node` asks for (its `executor_kind`: "events" for rclpy's C++ events executor), else a
    multi-threaded one on `threads` threads (one: single-threaded)."""
    if getattr(node, "executor_kind", "") == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor(context=node.context)
    return MultiThreadedExecutor(num_threads=threads) if threads > 1 else SingleThreadedExecutor()


def spin_until_stopped(node: Node, stop: threading.Event, threads: int = 1) -> None:
    """Spin `node` (on `threads` executor threads) until `stop` is set or rclpy shuts down; the callbacks
    still running when it stops are finished before this returns."""
    executor = make_executor(node, threads)
    executor.add_node(node)
    try:
        while not stop.is_set() and rclpy.ok():
            try:
                executor.spin_once(timeout_sec=STOP_POLL_S)
            except InvalidHandle:
                # A callback on another executor thread destroyed an entity (a camera subscription
                # recreated for its publishers' reliability, `SensorSubscription.check`) while this thread
                # was adding it to the wait set: rclpy raises here. The next spin builds the wait set
                # from the node's current entities; letting it propagate ended the node (seen in CI:
                # a best-effort camera's mapper died 2 s after start and integrated nothing).
                continue
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        drained = _drain(executor, node, timeout_s=DRAIN_S)
        if isinstance(executor, MultiThreadedExecutor):
            # (its shutdown joins the thread pool without a time limit: with a callback still stuck, the
            # node's own shutdown goes first, and the exit watchdog bounds the rest)
            executor.shutdown(timeout_sec=DRAIN_S, wait_for_threads=drained)
        else:
            executor.shutdown(timeout_sec=DRAIN_S)


def _drain(executor: Executor, node: Node, timeout_s: float) -> bool:
    """Let the callbacks already handed to a multi-threaded executor's thread pool finish, before the
    executor is shut down. rclpy's `Executor.shutdown` destroys its guard condition first and joins the
    pool after: a queued callback (one whose mutually exclusive group was busy) then triggered the
    destroyed guard and died with InvalidHandle, printed at exit as `The following exception was never
    retrieved: cannot use Destroyable because destruction was requested`. A callback that failed on
    its own is logged here instead of that line. Returns False when a callback was still running at the
    end of `timeout_s` (logged)."""
    tasks = list(getattr(executor, "_futures", ()))
    deadline = time.monotonic() + timeout_s
    while any(not t.done() for t in tasks) and time.monotonic() < deadline:
        time.sleep(0.01)
    for task in tasks:
        if task.done():
            exc = task.exception()  # marks it retrieved
            if exc is not None:
                node.get_logger().error(f"a callback failed while stopping: {type(exc).__name__}: {exc}")
    running = sum(1 for t in tasks if not t.done())
    if running:
        node.get_logger().warning(f"{running} callback(s) still running {timeout_s:.0f} s after the stop; "
                                  "shutting down without waiting for them")
    return not running


def shutdown_node(node: Node) -> None:
    """The node's `on_shutdown()` (if any; its failure is logged), then destroy it and the context."""
    hook = getattr(node, "on_shutdown", None)
    saved = True
    if hook is not None:
        _node_saving.set()
        try:
            hook()
        except Exception as exc:  # a failing clean-up is reported, the exit stays orderly
            saved = False
            node.get_logger().error(f"shutdown: {type(exc).__name__}: {exc}")
        _node_saving.clear()
    if saved:
        _node_state_saved.set()
    node.destroy_node()
    rclpy.try_shutdown()


def keep_exit_code_from_open3d() -> bool:
    """Stop Open3D (0.17+) from ending the process with exit code 1 because tensor memory is still
    allocated when the process ends; True when switched off, False when Open3D is not loaded or the
    switch is not found (nothing changes then).

    Open3D counts its tensor allocations and, from a static destructor at program end, prints those not
    freed and calls ``exit(EXIT_FAILURE)`` (``core/MemoryManagerStatistic.cpp``: meant to fail Open3D's
    own unit tests). A mapper node whose map stays referenced at that point (seen about once in 12
    SIGTERMs in `test_node_faults.py`: the node outlived `gc.collect()`, held only by objects the
    collector does not see, i.e. rclpy's C++ events executor) then exited 1 after a clean shutdown, and
    a launch file or supervisor took the clean stop for a crash. The memory is the process's and goes
    with it; the exit code is the node's."""
    o3d = sys.modules.get("open3d")
    if o3d is None or not getattr(o3d, "__file__", None):
        return False
    try:
        lib = ctypes.CDLL(str(next(Path(o3d.__file__).parent.glob("libOpen3D.so*"))))
        instance = lib._ZN6open3d4core22MemoryManagerStatistic11GetInstanceEv
        switch = lib._ZN6open3d4core22MemoryManagerStatistic20SetPrintAtProgramEndEb
    except (OSError, AttributeError, StopIteration):
        return False
    instance.restype = ctypes.c_void_p
    switch.argtypes = [ctypes.c_void_p, ctypes.c_bool]
    switch.restype = None
    switch(instance(), False)
    return True


def run_node(factory: Callable[[], Node], args: list[str] | None = None, threads: int = 1) -> int:
    """Create the node with `factory` and spin it (on `threads` executor threads); returns the exit code."""
    stop = init_ros(args)
    start_exit_watchdog(stop)
    node = factory()
    warn_unknown_parameters(node)
    try:
        spin_until_stopped(node, stop, threads)
    finally:
        shutdown_node(node)
        keep_exit_code_from_open3d()
    return 0
