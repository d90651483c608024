"""Bad input gets one line and exit 2 before any work, SIGINT a checkpoint that --resume continues, and an
evaluation against another scene's ground truth a refusal (--force: a loud warning)."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from panoptic_mapping.checkpoint import CheckpointStore
from scene_recon.cli import main


def _gt(bag: Path) -> Path:
    return bag.with_name(bag.name + "_groundtruth")


# ------------------------------------------------------------------ paths that are not UTF-8
def test_inspect_of_a_path_with_non_utf8_bytes(tiny_bag, tmp_path, run_cli, strict_json):
    odd = Path(os.fsdecode(os.fsencode(tmp_path) + b"/rec\xfe"))  # the byte 0xfe is no UTF-8
    shutil.copytree(tiny_bag, odd)
    strict = {"env": {"PYTHONIOENCODING": "utf-8"}}  # a strict stdout: the setting that raised before
    proc = run_cli("inspect", "--quick", odd, **strict)
    out, err = proc.stdout.decode(), proc.stderr.decode()
    assert proc.returncode == 0 and "Traceback" not in err, err[-2000:]
    assert "rec\\xfe" in out and "would map: 40 of 40 frames" in out
    proc = run_cli("inspect", "--quick", "--json", odd, **strict)
    assert proc.returncode == 0, proc.stderr.decode()[-2000:]
    assert strict_json(proc.stdout.decode())["path"].endswith("rec\\xfe")
    proc = run_cli("inspect", Path(os.fsdecode(os.fsencode(tmp_path) + b"/none\xff")), **strict)
    err = proc.stderr.decode()
    assert proc.returncode == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert "none\\xff" in err and "does not exist" in err


# ------------------------------------------------------------------ unwritable --out
def _unwritable_folder(tmp_path: Path) -> Path:
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        (locked / "probe").touch()
    except PermissionError:
        return locked
    (locked / "probe").unlink()  # root writes anywhere: use a folder no one may create files in
    for folder in (Path("/sys/kernel"), Path("/proc/sys")):
        try:
            (folder / "scene-recon-probe").touch()
        except OSError:
            return folder
    pytest.skip("no folder refuses writes here: running as root (permission bits do not apply) and neither "
                "/sys nor /proc (sysfs, procfs) exists on this system")


def test_map_into_an_unwritable_folder_fails_before_mapping(tiny_bag, tmp_path, capsys):
    locked = _unwritable_folder(tmp_path)
    t0 = time.perf_counter()
    rc = main(["map", str(tiny_bag), "--out", str(locked / "map")])
    out, err = capsys.readouterr()
    assert rc == 2 and out == "", out  # nothing started: not even the segmenter line
    assert err.startswith("scene-recon map: error: --out") and "not writable" in err
    assert len(err.strip().splitlines()) == 1 and time.perf_counter() - t0 < 5
    rc = main(["graph", str(_gt(tiny_bag)), "--out", str(locked / "graph")])
    assert rc == 2 and "not writable" in capsys.readouterr().err


# ------------------------------------------------------------------ SIGINT
def test_sigint_writes_a_checkpoint_that_resume_continues(tiny_bag, tmp_path, run_cli, main_json):
    """Even with --no-checkpoints (no periodic ones; the default periodic ones would not fire in 40
    frames either): the frames mapped before SIGINT are in a checkpoint and --resume maps the rest."""
    out, log = tmp_path / "map", tmp_path / "map.log"
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[2]))
    proc = subprocess.Popen([sys.executable, "-m", "scene_recon.cli", "-vv", "map", str(tiny_bag), "--out", str(out),
                             "--segmenter", "oracle", "--no-checkpoints"],
                            stdout=subprocess.DEVNULL, stderr=log.open("w"), env=env)
    deadline = time.monotonic() + 120
    while not re.search(r"frame 3 of the recording integrated", log.read_text()):
        assert proc.poll() is None, f"map ended (rc {proc.returncode}) early: {log.read_text()[-2000:]}"
        assert time.monotonic() < deadline, "no frame mapped within 120 s"
        time.sleep(0.02)
    proc.send_signal(signal.SIGINT)
    rc = proc.wait(timeout=120)
    text = log.read_text()
    assert rc == 130, text[-2000:]
    assert "interrupted by SIGINT" in text and "Traceback" not in text and "--resume" in text
    ckpt = CheckpointStore(out / "checkpoints").load_latest()
    kept = ckpt.progress["frames_read"]
    assert 3 <= kept < 40
    rc, summary = main_json(["map", str(tiny_bag), "--out", str(out), "--segmenter", "oracle", "--resume", "--json"])
    assert rc == 0
    assert summary["run"]["resumed_frames_read"] == kept and summary["run"]["frames_read"] == 40
    assert (out / "map.npz").is_file() and (out / "entities.json").is_file()


def test_sigint_while_the_map_is_written_finishes_the_outputs(tiny_bag, tmp_path, monkeypatch, capsys):
    import panoptic_mapping.pipeline as pipeline

    write = pipeline.write_map_outputs

    def interrupted_write(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C just as the outputs are being written
        return write(*args, **kwargs)

    monkeypatch.setattr(pipeline, "write_map_outputs", interrupted_write)
    out = tmp_path / "map"
    rc = main(["map", str(tiny_bag), "--out", str(out), "--segmenter", "oracle", "--max-frames", "8"])
    err = capsys.readouterr().err
    assert rc == 0 and "SIGINT while writing the outputs" in err, err[-2000:]
    assert (out / "map.npz").is_file() and (out / "entities.json").is_file() and (out / "summary.json").is_file()


# ------------------------------------------------------------------ map / graph / scene vs another scene's truth
def test_eval_map_refuses_another_scenes_ground_truth(tiny_bag, tiny_map, other_ground_truth, capsys, main_json):
    rc = main(["eval-map", str(tiny_map), str(other_ground_truth)])
    out, err = capsys.readouterr()
    assert rc == 2 and out == "" and "different scenes" in err and "--force" in err
    assert len(err.strip().splitlines()) == 1
    rc, scores = main_json(["eval-map", str(tiny_map), str(other_ground_truth), "--force", "--json"])
    assert rc == 0 and "pq" in scores["averages"]["all"]
    assert "WARNING" in capsys.readouterr().err
    rc, _ = main_json(["eval-map", str(tiny_map), str(_gt(tiny_bag)), "--json"])  # its own scene: no word
    assert rc == 0 and capsys.readouterr().err == ""


def test_eval_graph_and_eval_scene_refuse_another_scenes_ground_truth(tiny_bag, tiny_map, replaced_scene,
                                                                      other_ground_truth, tmp_path, capsys):
    assert main(["graph", str(tiny_map), "--out", str(tmp_path / "graph"), "--json"]) == 0
    capsys.readouterr()
    graph = tmp_path / "graph" / "contact_graph.json"
    assert main(["eval-graph", str(graph), str(other_ground_truth)]) == 2
    assert "different scenes" in capsys.readouterr().err
    assert main(["eval-graph", str(graph), str(_gt(tiny_bag)), "--json"]) == 0
    capsys.readouterr()
    _gt_dir, _graph, scene = replaced_scene
    t0 = time.perf_counter()
    assert main(["eval-scene", str(scene), str(_gt(tiny_bag))]) == 2  # refused before the physics check
    out, err = capsys.readouterr()
    assert out == "" and "different scenes" in err and time.perf_counter() - t0 < 5
    assert main(["eval-scene", str(scene), str(_gt(tiny_bag)), "--force", "--no-physics", "--seeds-per-class",
                 "3"]) == 0
    assert "WARNING" in capsys.readouterr().err
