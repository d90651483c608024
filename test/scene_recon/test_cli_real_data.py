"""Honest exits of `scene-recon map`, `run` and `inspect` on recordings that cannot (fully) be used:
the status and message say why and what to pass; nothing claims a file it did not write."""

from __future__ import annotations

import json

import numpy as np
import pytest
from testsupport.frames import ray_color, rgbd_rawbag, tum, write_matrix

from panoptic_mapping.mapper import PanopticMapper
from scene_recon.cli import main


@pytest.fixture
def world_bag(tmp_path):
    """TF tree rooted at 'world' (no 'map' frame): every frame lacks a pose in the default map frame."""
    return rgbd_rawbag(n=4, root="world").write(tmp_path / "world_rec")


def test_map_names_the_tf_root_and_writes_nothing(world_bag, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["map", str(world_bag), "--out", str(out), "--segmenter", "none"]) == 2
    err = capsys.readouterr().err
    assert "4 frames have no camera pose: TF root is 'world', not 'map': pass --map-frame world" in err
    assert not (out / "entities.json").exists() and not (out / "panoptic_map.png").exists()
    # doing what the message says works
    assert main(["map", str(world_bag), "--out", str(out), "--segmenter", "none", "--map-frame", "world"]) == 0
    stdout = capsys.readouterr().out
    assert "mapped 4 frames" in stdout and "panoptic_map.png" in stdout
    assert (out / "panoptic_map.png").is_file()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["files"][-1] == "panoptic_map.png" and summary["run"]["frames"] == 4


def test_map_without_surface_exits_3_and_claims_no_picture(tmp_path, capsys):
    bag = rgbd_rawbag(n=4).write(tmp_path / "rec")
    out = tmp_path / "out"
    assert main(["map", str(bag), "--out", str(out), "--segmenter", "none", "--max-depth", "1.0"]) == 3
    captured = capsys.readouterr()
    assert "has no surface" in captured.err and "0.1-1.0 m" in captured.err
    assert "panoptic_map.png" not in captured.out and not (out / "panoptic_map.png").exists()
    assert "panoptic_map.png" not in json.loads((out / "summary.json").read_text())["files"]


def test_map_of_unreconcilable_sizes_is_an_error_not_an_empty_success(tmp_path, capsys):
    bag = rgbd_rawbag(n=3, color_wh=(64, 48), depth_wh=(40, 40)).write(tmp_path / "odd")
    assert main(["map", str(bag), "--out", str(tmp_path / "out"), "--segmenter", "none"]) == 2
    err = capsys.readouterr().err
    assert "3 frames whose images cannot be used" in err and "differ in size and aspect ratio" in err


def test_map_survives_a_frame_the_mapper_fails_on(tmp_path, capsys, monkeypatch):
    bag = rgbd_rawbag(n=4).write(tmp_path / "rec")
    real = PanopticMapper.integrate_geometry  # --segmenter none: every frame takes the geometry-only path

    def flaky(self, frame):
        if frame.index == 1:
            raise RuntimeError("No block is touched in TSDF volume")
        return real(self, frame)

    monkeypatch.setattr(PanopticMapper, "integrate_geometry", flaky)
    assert main(["map", str(bag), "--out", str(tmp_path / "out"), "--segmenter", "none"]) == 0
    out = capsys.readouterr().out
    assert "mapped 3 frames" in out
    assert "warning: 1 frames failed in the mapper and were skipped (most often: No block is touched" in out


def test_inspect_counts_why_frames_would_be_skipped(world_bag, tmp_path, capsys):
    assert main(["inspect", str(world_bag), "--json"]) == 3
    info = json.loads(capsys.readouterr().out)
    assert info["usable_frames"] == 0 and info["frames"] == 4 and info["skipped"]["no_pose"] == 4
    assert info["tf_roots"] == ["world"]
    assert info["pose_hint"] == "TF root is 'world', not 'map': pass --map-frame world"
    assert main(["inspect", str(world_bag)]) == 3
    text = capsys.readouterr().out
    assert "why not posed: TF root is 'world', not 'map': pass --map-frame world" in text
    assert "would map: 0 of 4 frames (every frame decoded)" in text
    assert main(["inspect", str(world_bag), "--map-frame", "world", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["usable_frames"] == 4
    # a folder with two frames without valid depth (all 0 / 65535) and one good frame
    folder = tmp_path / "tum"
    depth = [np.zeros((60, 80), np.uint16), np.full((60, 80), 65535, np.uint16), np.full((60, 80), 7500, np.uint16)]
    tum(folder, 3, ray_color((60, 60, 39.5, 29.5), 80, 60), depth, poses=[np.eye(4)] * 3)
    assert main(["inspect", str(folder), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["usable_frames"] == 1 and info["skipped"]["all_depth_invalid"] == 2
    assert info["intrinsics_source"] == "dataset default"


def test_inspect_and_map_take_intrinsics_as_numbers_or_a_file(tmp_path, capsys):
    folder = tmp_path / "tum"
    tum(folder, 2, ray_color((60, 60, 39.5, 29.5), 80, 60), np.full((60, 80), 7500, np.uint16),
        poses=[np.eye(4)] * 2)
    assert main(["inspect", str(folder), "--json", "--intrinsics", "570.34,570.34,39.5,29.5"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["intrinsics"] == [570.34, 570.34, 39.5, 29.5] and info["intrinsics_source"] == "intrinsics option"
    write_matrix(tmp_path / "k.txt", (61.0, 62.0, 39.5, 29.5), size=4)
    assert main(["inspect", str(folder), "--json", "--intrinsics", str(tmp_path / "k.txt")]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["intrinsics"] == [61.0, 62.0, 39.5, 29.5] and info["intrinsics_source"] == str(tmp_path / "k.txt")
    assert main(["inspect", str(folder), "--intrinsics", "570,570"]) == 2
    assert "--intrinsics needs 4 numbers" in capsys.readouterr().err


def test_inspect_reports_a_truncated_bag(tmp_path, capsys):
    bag = rgbd_rawbag(n=40).write(tmp_path / "rec")
    data = next(bag.glob("*.mcap")).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 7 // 10])
    assert main(["inspect", str(cut), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["truncated"] and info["damage"] and 10 < info["usable_frames"] < 40


def test_run_stops_after_a_map_without_objects_and_forwards_data_options(world_bag, tmp_path, capsys):
    out = tmp_path / "run"
    # no ground truth beside the recording: 'auto' maps without a segmenter, which detects no object
    assert main(["run", str(world_bag), "--out", str(out), "--map-frame", "world"]) == 3
    err = capsys.readouterr().err
    assert "no ground truth lies beside the recording" in err and "--segmenter onnx --model-config" in err
    assert (out / "map" / "entities.json").is_file() and not (out / "graph").exists()
    assert main(["run", str(world_bag), "--out", str(tmp_path / "run2")]) == 2  # without --map-frame: no pose
    assert "pass --map-frame world" in capsys.readouterr().err


def test_inspect_warns_when_a_folders_depth_unit_looks_wrong(tmp_path, capsys):
    """A TUM-layout folder in millimetres is read at TUM's 5000 units/m: 1.2 m becomes 0.24 m. inspect
    says so and names the scale that fits; at the right scale it reports the depth quietly."""
    folder = tmp_path / "desk"
    tum(folder, 2, ray_color((60, 60, 39.5, 29.5), 80, 60), np.full((60, 80), 1200, np.uint16),
        poses=[np.eye(4)] * 2)
    assert main(["inspect", str(folder), "--intrinsics", "60,60,39.5,29.5"]) == 0
    out = capsys.readouterr().out
    assert "median 0.24 m" in out and "warning:" in out and "--depth-scale 1000" in out
    assert main(["inspect", str(folder), "--intrinsics", "60,60,39.5,29.5", "--depth-scale", "1000"]) == 0
    out = capsys.readouterr().out
    assert "median 1.20 m" in out and "warning:" not in out
