"""`scene-recon inspect` on a real bag: human and JSON output, exit codes, --help everywhere."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from panoptic_mapping.dataio import CameraIntrinsics
from panoptic_mapping.dataio.bag_writer import RGBDBagWriter
from scene_recon.cli import build_parser, main


def _bag(tmp_path, n=5):
    intr = CameraIntrinsics(50, 50, 15.5, 11.5, 32, 24)
    path = tmp_path / "rec"
    with RGBDBagWriter(path, storage="db3") as w:
        for i in range(n):
            pose = np.eye(4) if i < n - 1 else None  # last frame has no TF
            w.write_frame(10**9 + i * 100_000_000, np.zeros((24, 32, 3), np.uint8),
                          np.ones((24, 32), np.float32), intr, pose)
    return path


def test_inspect_json(tmp_path, capsys):
    path = _bag(tmp_path)
    assert main(["inspect", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == "rosbag2" and info["storage"] == "sqlite3"
    assert info["frames"] == 5 and info["resolution"] == [32, 24]
    assert info["posed_frames"] == 4 and info["pose_coverage"] == 0.8
    assert abs(info["duration_s"] - 0.4) < 1e-6
    topics = {t["topic"]: t for t in info["topics"]}
    assert topics["/camera/depth/image_rect_raw"]["encoding"] == "16UC1"
    assert topics["/camera/color/image_raw"]["count"] == 5
    assert abs(topics["/camera/color/image_raw"]["rate_hz"] - 10.0) < 1e-6
    assert set(info["tf_frames"]) == {"map", "camera_link", "camera_color_optical_frame"}


def test_inspect_text_and_errors(tmp_path, capsys):
    path = _bag(tmp_path)
    assert main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    assert "frames: 5 synchronised color/depth pairs, 32x24" in out
    assert "poses: 4/5 frames posed (80.0%)" in out
    assert main(["inspect", str(tmp_path / "nope")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_every_subcommand_has_help():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    for name in sub.choices:
        proc = subprocess.run([sys.executable, "-m", "scene_recon.cli", name, "--help"],
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0 and "usage: scene-recon" in proc.stdout, name
