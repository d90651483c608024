"""Every `--json` writes exactly one strict JSON document on stdout (no NaN/Infinity, no native chatter);
what PyBullet/MuJoCo print from C is captured at the file-descriptor level and shown only with -v."""

from __future__ import annotations

import ctypes
import os
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from scene_recon.commands.common import NON_FINITE_REASONS, print_json
from scene_recon.native_output import native_output_captured

NATIVE_MARKERS = ("b3Warning", "pybullet build time", "No inertial data")


def test_native_output_is_captured_at_the_descriptor_level_and_python_output_is_not(capfd):
    libc = ctypes.CDLL(None)
    with native_output_captured() as native:
        os.write(1, b"native line on fd 1\n")
        os.write(2, b"native line on fd 2\n")
        libc.printf(b"printf line, buffered in C stdio\n")
        print("our own line")
        print("our own error line", file=sys.stderr)
    out, err = capfd.readouterr()
    assert out == "our own line\n" and err == "our own error line\n"
    assert native.lines() == ["native line on fd 1", "native line on fd 2", "printf line, buffered in C stdio"]

    with native_output_captured(show=True, label="libfoo output"):  # -v: shown on stderr, never on stdout
        os.write(1, b"chatter\n")
    out, err = capfd.readouterr()
    assert out == "" and "libfoo output" in err and "chatter" in err

    with native_output_captured() as outer:  # blocks nest: the inner one restores the outer capture
        os.write(1, b"outer 1\n")
        with native_output_captured() as inner:
            os.write(1, b"inner\n")
        os.write(1, b"outer 2\n")
    assert inner.lines() == ["inner"] and outer.lines() == ["outer 1", "outer 2"]
    assert capfd.readouterr().out == ""


def test_print_json_writes_null_with_a_reason_for_nan_and_infinity(capsys, strict_json):
    print_json({"a": float("nan"), "b": np.float32(np.inf), "b_null_reason": "nothing matched", "c": [1.5, np.nan],
                "d": np.arange(2), "e": {"f": -np.inf}, "path": Path(os.fsdecode(b"/tmp/x\xfe"))})
    data = strict_json(capsys.readouterr().out)
    assert data == {"a": None, "a_null_reason": NON_FINITE_REASONS["nan"],
                    "b": None, "b_null_reason": "nothing matched",  # the producer's reason is kept
                    "c": [1.5, None], "d": [0, 1], "e": {"f": None, "f_null_reason": NON_FINITE_REASONS["inf"]},
                    "path": "/tmp/x\\xfe"}


def test_eval_scene_json_is_strict_and_free_of_physics_engine_chatter(replaced_scene, run_cli, strict_json):
    gt, _graph, scene = replaced_scene
    proc = run_cli("eval-scene", str(scene), str(gt), "--seeds-per-class", "3", "--json")
    out, err = proc.stdout.decode(), proc.stderr.decode()
    assert proc.returncode == 0, err[-2000:]
    figures = strict_json(out)  # would fail on a b3Warning line before the document or on NaN
    for marker in NATIVE_MARKERS:
        assert marker not in out and marker not in err, marker
    assert figures["physics"]["pybullet"]["loaded"] and figures["physics"]["mujoco"]["loaded"]
    for obj in figures["per_object"]:  # a figure is a number, or null with the reason beside it
        for key in ("ae", "ae_points", "ae_model", "translation_error"):
            assert isinstance(obj[key], float) or (obj[key] is None and obj[f"{key}_null_reason"]), (key, obj)

    # -v: the chatter is shown, on stderr only; stdout stays one strict document
    proc = run_cli("-v", "eval-scene", str(scene), str(gt), "--seeds-per-class", "3", "--json")
    out, err = proc.stdout.decode(), proc.stderr.decode()
    assert proc.returncode == 0
    strict_json(out)
    assert "pybullet build time" in err and "pybullet output (captured)" in err


def test_eval_scene_text_has_no_native_lines_and_formatted_numbers(replaced_scene, run_cli):
    gt, _graph, scene = replaced_scene
    proc = run_cli("eval-scene", str(scene), str(gt), "--seeds-per-class", "3")
    out, err = proc.stdout.decode(), proc.stderr.decode()
    assert proc.returncode == 0, err[-2000:]
    for marker in NATIVE_MARKERS:
        assert marker not in out and marker not in err, marker
    assert re.search(r"pybullet: loaded, still \d+\.\d %", out), out
    assert not re.search(r"\d\.\d{5,}", out), out  # no raw floats like 0.8888888888888888


def test_every_json_command_writes_strict_json(tiny_bag, tiny_map, replaced_scene, main_json, tmp_path):
    gt_dir = tiny_bag.with_name(tiny_bag.name + "_groundtruth")
    rc, info = main_json(["inspect", str(tiny_bag), "--json"])
    assert rc == 0 and info["frames"] == 40
    rc, scores = main_json(["eval-map", str(tiny_map), str(gt_dir), "--json"])
    assert rc == 0 and scores["averages"]["all"]["pq"] is not None
    rc, graph = main_json(["graph", str(tiny_map), "--out", str(tmp_path / "graph"), "--json"])
    assert rc == 0 and graph["nodes"] >= 1
    rc, ged = main_json(["eval-graph", str(tmp_path / "graph" / "contact_graph.json"), str(gt_dir), "--json"])
    assert rc == 0 and "ged" in ged
    rc, suites = main_json(["suite", "--json"])
    assert rc == 0 and suites
    gt, graph_dir, _scene = replaced_scene
    rc, summary = main_json(["replace", str(graph_dir), "--out", str(tmp_path / "scene"), "--seeds-per-class", "3",
                             "--json"])
    assert rc == 0 and summary["objects"] >= 1
    rc, figures = main_json(["eval-scene", str(tmp_path / "scene"), str(gt), "--seeds-per-class", "3",
                             "--no-physics", "--json"])
    assert rc == 0 and figures["matched"] >= 1
    # generate and map: the session fixtures ran `generate --json` (in a child process) and `map --json`


@pytest.mark.slow  # about 25 s: the whole pipeline on a 3-object, 12-frame scene
def test_demo_console_shows_no_native_library_line(tmp_path, run_cli):
    """`make demo` on a small scene: our steps and summaries only (pybullet's lines shown only with -v)."""
    proc = run_cli("demo", "--out", str(tmp_path / "demo"), "--objects", "3", "--frames", "12")
    out, err = proc.stdout.decode(), proc.stderr.decode()
    assert proc.returncode == 0, (out + err)[-3000:]
    assert "== 8. interactive scene against the ground truth" in out
    for marker in NATIVE_MARKERS:
        assert marker not in out and marker not in err, marker
    summary = out[out.index("== 8."):]
    assert re.search(r"pybullet: loaded, still \d+\.\d %", summary), summary
    assert not re.search(r"\d\.\d{5,}", summary), summary
