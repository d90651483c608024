"""`scene-recon` as a process leaves through ``run_and_exit``: the interpreter's teardown is skipped, what an
exit must do is not (exit handlers, flushed output, the command's exit status)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _run(script: str, tmp_path: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "XDG_CACHE_HOME": str(tmp_path / "cache")}
    return subprocess.run([sys.executable, "-c", textwrap.dedent(script)], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=120)


def test_exit_status_output_and_exit_handlers_survive_the_fast_exit(tmp_path):
    marker = tmp_path / "handler_ran"
    proc = _run(f"""
        import atexit, sys
        atexit.register(lambda: open({str(marker)!r}, "w").write("ran"))
        print("buffered line before the command", end="")  # no newline: only a flush writes it
        sys.argv = ["scene-recon", "replace", {str(tmp_path / "missing")!r}, "--out", {str(tmp_path / "out")!r}]
        from scene_recon.cli import run_and_exit
        run_and_exit()
        raise AssertionError("run_and_exit returned")
        """, tmp_path)
    assert proc.returncode == 2, proc.stderr  # the command's own status: an input error
    assert "not found" in proc.stderr and "scene-recon graph" in proc.stderr
    assert proc.stdout == "buffered line before the command"
    assert marker.read_text() == "ran"


def test_a_running_thread_gets_the_ordinary_exit(tmp_path):
    """A thread the command left running is waited for (the ordinary exit), not cut off."""
    marker = tmp_path / "thread_done"
    proc = _run(f"""
        import sys, threading, time
        def late():
            time.sleep(0.5)
            open({str(marker)!r}, "w").write("done")
        threading.Thread(target=late).start()
        sys.argv = ["scene-recon", "--version"]
        import scene_recon.cli as cli
        cli.main = lambda: 0  # a command that returns while the thread still runs
        cli.run_and_exit()
        """, tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert marker.read_text() == "done"
