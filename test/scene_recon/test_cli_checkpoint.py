"""`scene-recon map` never loses a run: kill -9 mid-run, SIGTERM, then `--resume`; damaged checkpoints."""

from __future__ import annotations

import json
import logging
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from panoptic_mapping.checkpoint import CheckpointStore
from scene_recon.cli import main

REPO_ROOT = Path(__file__).resolve().parents[2]
INTERVAL = 10


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    """`scene-recon generate --frames 60 --objects 4`."""
    path = tmp_path_factory.mktemp("ckpt") / "bag"
    assert main(["generate", "--out", str(path), "--frames", "60", "--objects", "4", "--json"]) == 0
    return path


def _start_map(bag: Path, out: Path, log: Path, *extra: str) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cmd = [sys.executable, "-m", "scene_recon.cli", *extra, "map", str(bag), "--out", str(out),
           "--checkpoint-every", str(INTERVAL), "--checkpoint-every-s", "0"]
    return subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=log.open("w"), cwd=REPO_ROOT)


def _wait_for_generations(proc: subprocess.Popen, store: CheckpointStore, n: int, log: Path) -> None:
    deadline = time.monotonic() + 120
    while len(store.generations()) < n:
        assert proc.poll() is None, f"map ended (rc {proc.returncode}) early: {log.read_text()[-2000:]}"
        assert time.monotonic() < deadline, "no checkpoint within 120 s"
        time.sleep(0.05)


def _resume(bag: Path, out: Path, capsys) -> dict:
    capsys.readouterr()
    rc = main(["map", str(bag), "--out", str(out), "--resume", "--json", "--checkpoint-every", str(INTERVAL)])
    assert rc == 0
    return json.loads(capsys.readouterr().out)


def test_kill_9_mid_run_then_resume_completes_losing_at_most_one_interval(bag, tmp_path, capsys, caplog):
    out, log = tmp_path / "out", tmp_path / "map.log"
    store = CheckpointStore(out / "checkpoints")
    proc = _start_map(bag, out, log, "-vv")  # -vv: a debug line per integrated frame
    _wait_for_generations(proc, store, 2, log)
    proc.send_signal(signal.SIGKILL)
    assert proc.wait(timeout=30) == -signal.SIGKILL
    mapped = [int(m) for m in re.findall(r"frame (\d+) of the recording integrated", log.read_text())]
    at_kill = max(mapped)
    ckpt = store.load_latest()
    kept = ckpt.progress["frames_read"]
    assert at_kill < 60, "killed too late to test anything"
    assert 2 * INTERVAL <= kept <= at_kill and at_kill - kept <= INTERVAL, (at_kill, kept)

    summary = _resume(bag, out, capsys)
    run = summary["run"]
    assert run["resumed_generation"] == ckpt.generation and run["resumed_frames_read"] == kept
    assert run["frames"] == 60 and run["frames_read"] == 60  # every frame mapped once: none lost, none twice
    assert summary["panoptic_entities"] >= 3 and (out / "map.npz").is_file() and (out / "entities.json").is_file()

    # the newest checkpoint damaged (truncated npz): the older one is used, with a warning naming the file
    gens = store.generations()
    assert len(gens) == 2
    (_, newest), (older_gen, _) = gens
    (newest / "map.npz").write_bytes((newest / "map.npz").read_bytes()[:4096])
    with caplog.at_level(logging.WARNING):
        summary = _resume(bag, out, capsys)
    assert any(str(newest / "map.npz") in r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING)
    assert summary["run"]["resumed_generation"] == older_gen and summary["run"]["frames"] == 60

    # every checkpoint damaged: an error naming the files, exit 2, nothing overwritten silently
    for _, gen in store.generations():
        (gen / "map.json").write_text("{", encoding="utf-8")
    rc = main(["map", str(bag), "--out", str(out), "--resume", "--json"])
    err = capsys.readouterr().err
    assert rc == 2 and "map.json" in err and "no usable checkpoint" in err


def test_sigterm_checkpoints_and_exits_then_resume_finishes(bag, tmp_path, capsys):
    out, log = tmp_path / "out", tmp_path / "map.log"
    store = CheckpointStore(out / "checkpoints")
    proc = _start_map(bag, out, log)
    _wait_for_generations(proc, store, 1, log)
    proc.send_signal(signal.SIGTERM)
    rc = proc.wait(timeout=60)
    text = log.read_text()
    assert rc == 128 + signal.SIGTERM, text[-2000:]
    assert "interrupted by SIGTERM" in text and "Traceback" not in text
    ckpt = store.load_latest()
    assert ckpt.progress["frames_read"] < 60
    assert not (out / "map.npz").exists()  # outputs are for finished runs; the checkpoint holds the progress
    summary = _resume(bag, out, capsys)
    assert summary["run"]["frames"] == 60 and summary["run"]["resumed_frames_read"] == ckpt.progress["frames_read"]
