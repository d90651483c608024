"""TUM-style and 7-Scenes-style frame folders: association, depth units, poses, bad files."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from panoptic_mapping.dataio import DataInputConfig, DatasetError
from panoptic_mapping.dataio.registry import detect_format, open_dataset
from panoptic_mapping.dataio.transforms import make_transform

W, H = 32, 24


def _write_pngs(folder: Path, name: str, color: np.ndarray, depth_raw: np.ndarray) -> tuple[str, str]:
    (folder / "rgb").mkdir(exist_ok=True)
    (folder / "depth").mkdir(exist_ok=True)
    cv2.imwrite(str(folder / "rgb" / f"{name}.png"), color[:, :, ::-1])
    cv2.imwrite(str(folder / "depth" / f"{name}.png"), depth_raw)
    return f"rgb/{name}.png", f"depth/{name}.png"


def make_tum(folder: Path, n: int = 4, seed: int = 0):
    rng = np.random.default_rng(seed)
    folder.mkdir()
    colors = rng.integers(0, 256, (n, H, W, 3), dtype=np.uint8)
    raws = rng.integers(0, 30000, (n, H, W)).astype(np.uint16)
    rgb_lines, depth_lines = ["# color images"], ["# depth"]
    for i in range(n):
        t = 100.0 + i / 30.0
        c, d = _write_pngs(folder, f"{i:03d}", colors[i], raws[i])
        rgb_lines.append(f"{t + 0.004:.6f} {c}")  # color 4 ms after depth, as in TUM
        depth_lines.append(f"{t:.6f} {d}")
    (folder / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (folder / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    gt = ["# timestamp tx ty tz qx qy qz qw"]
    for k in range(0, 3 * n):
        t = 99.99 + k / 60.0
        gt.append(f"{t:.6f} {t - 100:.6f} 1.0 1.5 0 0 0 1")
    (folder / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    return colors, raws


def test_tum_folder(tmp_path):
    colors, raws = make_tum(tmp_path / "tum")
    assert detect_format(tmp_path / "tum") == "tum"
    with open_dataset(tmp_path / "tum") as loader:
        frames = list(loader)
    assert len(frames) == 4
    for i, f in enumerate(frames):
        np.testing.assert_array_equal(f.color, colors[i])
        np.testing.assert_allclose(f.depth, raws[i] / 5000.0, rtol=1e-6)  # TUM: 5000 units per metre
        t = 100.0 + i / 30.0
        np.testing.assert_allclose(f.pose, make_transform([t - 100.0, 1.0, 1.5], [0, 0, 0, 1]), atol=1e-6)
        assert f.intrinsics.fx == 525.0 and (f.intrinsics.width, f.intrinsics.height) == (W, H)
        assert f.invalid_depth_pixels == 0


def test_tum_camera_yaml_and_depth_scale_override(tmp_path):
    make_tum(tmp_path / "tum")
    (tmp_path / "tum" / "camera.yaml").write_text("fx: 100\nfy: 101\ncx: 15.5\ncy: 11.5\n")
    with open_dataset(tmp_path / "tum", DataInputConfig(depth_scale=1000.0)) as loader:
        f = next(iter(loader))
    assert (f.intrinsics.fx, f.intrinsics.fy) == (100.0, 101.0)
    (tmp_path / "tum" / "rgb.txt").write_text("100.0\n")
    with pytest.raises(DatasetError, match="timestamp filename"):
        open_dataset(tmp_path / "tum")


def test_seven_scenes_folder_with_sequences(tmp_path):
    rng = np.random.default_rng(1)
    root = tmp_path / "chess"
    poses = []
    for s in (1, 2):
        seq = root / f"seq-0{s}"
        seq.mkdir(parents=True)
        for i in range(2):
            color = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
            raw = rng.integers(500, 4000, (H, W)).astype(np.uint16)
            raw[0, 0] = 65535  # 7-Scenes' invalid marker
            cv2.imwrite(str(seq / f"frame-{i:06d}.color.png"), color[:, :, ::-1])
            cv2.imwrite(str(seq / f"frame-{i:06d}.depth.png"), raw)
            pose = make_transform([s, i, 0.0], [0, 0, np.sin(0.1 * i), np.cos(0.1 * i)])
            poses.append(pose)
            np.savetxt(seq / f"frame-{i:06d}.pose.txt", pose)
    assert detect_format(root) == "7scenes"
    with open_dataset(root) as loader:
        frames = list(loader)
    assert len(frames) == 4
    for f, pose in zip(frames, poses, strict=False):
        np.testing.assert_allclose(f.pose, pose, atol=1e-12)
        assert f.depth[0, 0] == 0 and f.invalid_depth_pixels == 0
        assert 0.5 <= f.depth[1, 1] <= 4.0
    assert [f.timestamp_ns for f in frames] == [0, 33_333_333, 66_666_666, 99_999_999]


def test_corrupt_png_is_a_counted_skip_and_unknown_folder_errors(tmp_path):
    make_tum(tmp_path / "tum")
    (tmp_path / "tum" / "depth" / "001.png").write_bytes(b"not a png")
    with open_dataset(tmp_path / "tum") as loader:
        frames = list(loader)
        assert loader.skips.unreadable == 1
    assert len(frames) == 3
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="not a recognised RGB-D source"):
        open_dataset(tmp_path / "empty")
    with pytest.raises(DatasetError, match="does not exist"):
        open_dataset(tmp_path / "missing")
