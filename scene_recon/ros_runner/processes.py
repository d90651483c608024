"""Child processes of the runner: one per node, logs forwarded line by line with a `[name]` prefix.

Each node runs in a session of its own, so a Ctrl-C typed in the terminal reaches the runner only:
the runner first asks the CAD replacer to export the scene, then stops the nodes itself, player
first (no new frames), each with SIGINT (the nodes' orderly shutdown: the mapper's last checkpoint),
and only a node that does not exit in time is killed. The caller's environment is passed through
unchanged (ROS_DOMAIN_ID, ROS_AUTOMATIC_DISCOVERY_RANGE, RMW settings are the user's to choose).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

import yaml

from recon_core.ros_graph import NodeSpec


@dataclass
class Child:
    """A running node process and where its output goes."""

    spec: NodeSpec
    proc: subprocess.Popen
    log_path: Path
    reader: threading.Thread
    lines: list[str] = field(default_factory=list)  # the last lines, for the failure report

    @property
    def name(self) -> str:
        return self.spec.name

    def poll(self) -> int | None:
        return self.proc.poll()


class LogSink:
    """Prefixed, line-atomic output of every child on one stream (and each child's own log file)."""

    def __init__(self, stream: TextIO | None = None, quiet: bool = False) -> None:
        self.stream = stream or sys.stdout
        self.quiet = quiet
        self._lock = threading.Lock()
        self.width = 20

    def line(self, prefix: str, text: str) -> None:
        if self.quiet:
            return
        with self._lock:
            self.stream.write(f"[{prefix:<{self.width}}] {text}\n")
            self.stream.flush()


def write_params(spec: NodeSpec, folder: Path, suffix: str = "") -> Path:
    """The node's parameter file (the form launch_ros writes too)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{spec.name}{suffix}.yaml"
    path.write_text(yaml.safe_dump(spec.params_yaml(), sort_keys=False), encoding="utf-8")
    return path


def _forward(child_name: str, stream: TextIO, log: TextIO, sink: LogSink, keep: list[str]) -> None:
    for raw in stream:
        text = raw.rstrip("\n")
        log.write(raw)
        log.flush()
        keep.append(text)
        del keep[:-50]
        sink.line(child_name, text)
    log.close()


def _libc_prctl():
    if not sys.platform.startswith("linux"):
        return None
    import ctypes

    try:
        return ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None


_PRCTL = _libc_prctl()


def _die_with_parent() -> None:
    """In the child before exec: SIGTERM it when the runner dies (Linux PR_SET_PDEATHSIG).

    The nodes run in sessions of their own (so a terminal's Ctrl-C reaches the runner first); without
    this, a runner killed with SIGKILL left them running, still answering on the DDS domain (seen: a
    later test's service calls were answered by such orphans)."""
    if _PRCTL is not None:  # (resolved beforehand: nothing may be imported between fork and exec)
        _PRCTL(1, int(signal.SIGTERM))  # 1 = PR_SET_PDEATHSIG


def start_child(spec: NodeSpec, run_dir: Path, sink: LogSink, env: dict[str, str] | None = None,
                attempt: int = 0) -> Child:
    """Start `python -m <module> --ros-args ...` for `spec`; its parameters go through a params file.
    A restarted node (`attempt` > 0) logs into `<name>.<attempt>.log`."""
    suffix = f".{attempt}" if attempt else ""
    params = write_params(spec, run_dir / "params", suffix)
    logs = run_dir / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    log_path = logs / f"{spec.name}{suffix}.log"
    argv = [sys.executable, "-m", spec.module, *spec.ros_args(params)]
    proc = subprocess.Popen(argv, env=env if env is not None else os.environ.copy(), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, text=True, bufsize=1,
                            start_new_session=True, preexec_fn=_die_with_parent)
    keep: list[str] = []
    log = log_path.open("w", encoding="utf-8")
    log.write(f"$ {' '.join(argv)}\n")
    reader = threading.Thread(target=_forward, args=(spec.name, proc.stdout, log, sink, keep),
                              name=f"log-{spec.name}", daemon=True)
    reader.start()
    return Child(spec, proc, log_path, reader, keep)


def usage(child: Child) -> dict[str, float]:
    """CPU seconds (user + system, since the start) and peak resident memory (MiB) of a running child,
    from /proc (Linux); {} when it is gone or /proc is not there."""
    try:
        stat = Path(f"/proc/{child.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        status = Path(f"/proc/{child.proc.pid}/status").read_text()
    except OSError:
        return {}
    ticks = os.sysconf("SC_CLK_TCK")
    cpu_s = (int(stat[11]) + int(stat[12])) / ticks  # utime, stime (fields 14, 15 of stat)
    peak = next((line.split()[1] for line in status.splitlines() if line.startswith("VmHWM:")), "0")
    return {"cpu_s": round(cpu_s, 2), "peak_rss_mib": round(int(peak) / 1024, 1)}


def interrupt_group(proc: subprocess.Popen, timeout_s: float) -> int:
    """Ctrl-C, once, to the process group `proc` leads (a `ros2 launch` started with
    `start_new_session=True` and its nodes), then wait; a group still running after `timeout_s` is
    killed. Returns `proc`'s exit code."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGINT)
    try:
        return int(proc.wait(timeout=timeout_s))
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        return int(proc.wait())


#: How long (s) a node that did not stop in time gets to write its threads' stacks (SIGUSR1) before SIGKILL.
STACK_DUMP_S = 2.0


def stop_children(children: list[Child], timeout_s: float = 30.0) -> dict[str, int]:
    """SIGINT every child still running (in the given order), then wait for each; a child that does not
    exit within `timeout_s` is asked for its threads' stacks (SIGUSR1: `ros_nodes.runner.init_ros` registers
    faulthandler for it; they land in the node's log) and then killed. Returns the exit codes by node name."""
    for child in children:
        if child.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                child.proc.send_signal(signal.SIGINT)
    codes: dict[str, int] = {}
    for child in children:
        try:
            child.proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                child.proc.send_signal(signal.SIGUSR1)
            with contextlib.suppress(subprocess.TimeoutExpired):
                child.proc.wait(timeout=STACK_DUMP_S)
            if child.proc.poll() is None:
                child.proc.kill()
                child.proc.wait()
        child.reader.join(timeout=5)
        codes[child.name] = int(child.proc.returncode)
    return codes
