"""Frame folders as real datasets ship them: 3DMatch / 7-Scenes (camera-intrinsics.txt, rgbd-frames/),
ScanNet exports (colour and depth of different sizes, 4x4 intrinsics, -inf poses), invalid depth markers,
intrinsics options and files."""

from __future__ import annotations

import numpy as np
import pytest
from testsupport.frames import (
    plane_mm,
    ray_color,
    ray_of_color,
    seven_scenes,
    translation_pose,
    tum,
    write_matrix,
    write_png,
)

from panoptic_mapping.dataio import DataInputConfig, DatasetError
from panoptic_mapping.dataio.align import register_to_depth, scale_intrinsics
from panoptic_mapping.dataio.intrinsics import parse_intrinsics_option, read_intrinsics_file
from panoptic_mapping.dataio.registry import detect_format, open_dataset
from recon_core.errors import ConfigError

K_3DMATCH = (570.342, 570.342, 320.0, 240.0)  # sun3d / 3DMatch camera-intrinsics.txt
K_SMALL = (36.0, 37.0, 19.5, 14.5)


def test_3dmatch_camera_intrinsics_txt_beside_the_sequences(tmp_path):
    """3DMatch: scene/camera-intrinsics.txt (3x3) + scene/seq-01/frame-*; the 7-Scenes default 585 is wrong."""
    scene = tmp_path / "sun3d-home_at-home_at_scan1_2013_jan_1"
    seven_scenes(scene / "seq-01", 2, K_3DMATCH, w=64, h=48)
    write_matrix(scene / "camera-intrinsics.txt", K_3DMATCH, size=3)
    for source in (scene, scene / "seq-01"):  # the scene folder or one of its sequences
        with open_dataset(source) as loader:
            frames = list(loader)
            assert loader.intrinsics_source.endswith("camera-intrinsics.txt")
        assert len(frames) == 2
        k = frames[0].intrinsics
        assert (k.fx, k.fy, k.cx, k.cy) == K_3DMATCH and (k.width, k.height) == (64, 48)


def test_rgbd_frames_folder_is_recognised(tmp_path):
    scene = tmp_path / "7-scenes-redkitchen"
    poses = seven_scenes(scene / "rgbd-frames", 3, K_SMALL)
    write_matrix(scene / "rgbd-frames" / "camera-intrinsics.txt", K_SMALL)
    assert detect_format(scene) == "7scenes"
    assert detect_format(scene / "rgbd-frames") == "7scenes"
    with open_dataset(scene) as loader:
        frames = list(loader)
    assert len(frames) == 3
    for f, pose in zip(frames, poses, strict=True):
        np.testing.assert_allclose(f.pose, pose)
        assert f.intrinsics.fx == 36.0
        np.testing.assert_allclose(f.depth, 1.5)


def test_intrinsics_txt_4x4_and_precedence(tmp_path):
    folder = tmp_path / "tum"
    tum(folder, 2, np.zeros((30, 40, 3), np.uint8), plane_mm(40, 30) * 5)
    write_matrix(folder / "intrinsics.txt", (50.0, 51.0, 19.0, 14.0), size=4)
    with open_dataset(folder, DataInputConfig(require_pose=False)) as loader:
        f = next(iter(loader))
    assert (f.intrinsics.fx, f.intrinsics.fy, f.intrinsics.cx, f.intrinsics.cy) == (50.0, 51.0, 19.0, 14.0)
    (folder / "camera.yaml").write_text("fx: 60\nfy: 61\ncx: 19.5\ncy: 14.5\n")
    with open_dataset(folder, DataInputConfig(require_pose=False)) as loader:
        assert loader._k == (60.0, 61.0, 19.5, 14.5)  # camera.yaml before intrinsics.txt
    write_matrix(tmp_path / "other.txt", (70.0, 70.0, 19.5, 14.5))
    with open_dataset(folder, DataInputConfig(require_pose=False, intrinsics_file=str(tmp_path / "other.txt"))) as ld:
        assert ld._k == (70.0, 70.0, 19.5, 14.5)  # a file option before the folder's files
    with open_dataset(folder, DataInputConfig(require_pose=False, intrinsics=[80, 80, 19.5, 14.5],
                                              intrinsics_file=str(tmp_path / "other.txt"))) as ld:
        assert ld._k == (80.0, 80.0, 19.5, 14.5) and ld.intrinsics_source == "intrinsics option"


def test_intrinsics_option_parsing(tmp_path):
    assert parse_intrinsics_option("570.34,570.34,320,240") == ([570.34, 570.34, 320.0, 240.0], "")
    assert parse_intrinsics_option(["570", "571", "320", "240"]) == ([570.0, 571.0, 320.0, 240.0], "")
    write_matrix(tmp_path / "k.txt", K_3DMATCH)
    assert parse_intrinsics_option(str(tmp_path / "k.txt")) == ([], str(tmp_path / "k.txt"))
    assert read_intrinsics_file(tmp_path / "k.txt") == K_3DMATCH
    (tmp_path / "k.yaml").write_text("fx: 1\nfy: 2\ncx: 3\ncy: 4\n")
    assert read_intrinsics_file(tmp_path / "k.yaml") == (1.0, 2.0, 3.0, 4.0)
    with pytest.raises(ConfigError, match="4 numbers"):
        parse_intrinsics_option("570,570,320")
    with pytest.raises(ConfigError, match="neither"):
        parse_intrinsics_option(str(tmp_path / "missing.txt"))
    (tmp_path / "bad.txt").write_text("1 2 3\n4 5 6\n")
    with pytest.raises(DatasetError, match="3x3 or 4x4"):
        read_intrinsics_file(tmp_path / "bad.txt")
    (tmp_path / "notk.txt").write_text("1 0 2\n0 1 3\n5 5 5\n")
    with pytest.raises(DatasetError, match="third row"):
        read_intrinsics_file(tmp_path / "notk.txt")


@pytest.mark.parametrize("layout", ["tum", "7scenes", "scannet"])
def test_16bit_depth_65535_is_invalid_in_every_layout(tmp_path, layout):
    """65535 is the sensors' "no reading" marker: TUM read it as 13.1 m, ScanNet-style mm as 65.5 m."""
    raw = plane_mm(40, 30)
    raw[:5, :] = 65535
    raw[5, :] = 0
    folder = tmp_path / layout
    if layout == "tum":
        tum(folder, 1, ray_color(K_SMALL, 40, 30), raw, poses=[np.eye(4)])
    elif layout == "7scenes":
        seven_scenes(folder, 1, K_SMALL, depth=raw)
    else:
        _scannet(folder, 1, depth=raw, color_size=(40, 30))
    with open_dataset(folder) as loader:
        (f,) = list(loader)
    assert np.all(f.depth[:6] == 0)
    np.testing.assert_allclose(f.depth[6:], 1.5 if layout != "tum" else 1.5 / 5)  # TUM: 5000 units per metre


# ---------------------------------------------------------------------------------------------- ScanNet
K_DEPTH = (36.0, 36.0, 19.5, 14.5)  # a 40x30 depth camera (ScanNet: 577.6, 577.6, 318.9, 238.5 at 640x480)
K_COLOR = (70.0, 69.0, 40.3, 30.9)  # an 81x61 colour camera, a wider field of view (ScanNet: 1296x968)


def _scannet(folder, n, depth=None, color_size=(81, 61), poses=None, k_color=K_COLOR, k_depth=K_DEPTH,
             color_ext="jpg"):
    wc, hc = color_size
    for i in range(n):
        write_png(folder / "color" / f"{i}.{color_ext}", ray_color(k_color, wc, hc))
        write_png(folder / "depth" / f"{i}.png", plane_mm(40, 30) if depth is None else depth)
        (folder / "pose").mkdir(exist_ok=True)
        np.savetxt(folder / "pose" / f"{i}.txt", poses[i] if poses is not None else translation_pose(0.01 * i, 0, 0))
    if k_color is not None:
        write_matrix(folder / "intrinsic" / "intrinsic_color.txt", k_color, size=4)
    if k_depth is not None:
        write_matrix(folder / "intrinsic" / "intrinsic_depth.txt", k_depth, size=4)


def test_scannet_export_colour_resampled_onto_depth_grid(tmp_path):
    folder = tmp_path / "scene0000_00"
    lost = translation_pose(0, 0, 0)
    lost[:3, :] = -np.inf  # ScanNet marks frames where tracking was lost with -inf poses
    poses = [translation_pose(0.01 * i, 0, 0) for i in range(12)]
    poses[3] = lost
    _scannet(folder, 12, poses=poses)
    assert detect_format(folder) == "scannet"
    with open_dataset(folder) as loader:
        frames = list(loader)
        skips = loader.skips
        assert loader.resampled_frames == 11
    assert len(frames) == 11 and skips.no_pose == 1
    assert skips.reasons["pose not finite (tracking lost)"] == 1
    # numeric order (0, 1, 2, ..., 10, 11), not file-name order (0, 1, 10, 11, 2, ...)
    assert [round(f.pose[0, 3], 2) for f in frames] == [0.0, 0.01, 0.02, 0.04, 0.05, 0.06, 0.07, 0.08, 0.09,
                                                        0.1, 0.11]
    f = frames[0]
    assert f.color.shape == (30, 40, 3) and f.depth.shape == (30, 40)
    assert (f.intrinsics.fx, f.intrinsics.cx, f.intrinsics.width) == (36.0, 19.5, 40)
    # every depth pixel got the colour of its own viewing ray (JPEG: a few levels of error)
    xr, yr = ray_of_color(f.color)
    u, v = np.meshgrid(np.arange(40.0), np.arange(30.0))
    np.testing.assert_allclose(xr, (u - 19.5) / 36.0, atol=6 / 150)
    np.testing.assert_allclose(yr, (v - 14.5) / 36.0, atol=6 / 150)


def test_scannet_colour_resized_to_depth_size_uses_the_depth_intrinsics(tmp_path):
    """Exports with colour already at 640x480: same size, no resampling, the depth camera's matrix."""
    folder = tmp_path / "scan"
    _scannet(folder, 2, color_size=(40, 30), k_color=K_COLOR)
    with open_dataset(folder) as loader:
        frames = list(loader)
        assert loader.resampled_frames == 0
    assert frames[0].intrinsics.fx == K_DEPTH[0]


def test_one_matrix_and_two_sizes(tmp_path):
    """A depth stream at half resolution (same field of view): colour resized, intrinsics scaled."""
    folder = tmp_path / "tum"
    k = (60.0, 60.0, 39.5, 29.5)  # of the 80x60 colour image
    tum(folder, 1, ray_color(k, 80, 60), plane_mm(40, 30) * 5, poses=[np.eye(4)])
    write_matrix(folder / "camera-intrinsics.txt", k)
    with open_dataset(folder) as loader:
        (f,) = list(loader)
    kd = scale_intrinsics(k, 0.5, 0.5)
    assert (f.intrinsics.fx, f.intrinsics.fy, f.intrinsics.cx, f.intrinsics.cy) == kd
    assert f.color.shape == (30, 40, 3)
    xr, _ = ray_of_color(f.color)
    np.testing.assert_allclose(xr, (np.arange(40.0) - kd[2]) / kd[0] * np.ones((30, 1)), atol=2 / 150)
    # another aspect ratio and one matrix: refused per frame, with what is missing
    folder2 = tmp_path / "tum2"
    tum(folder2, 2, ray_color(k, 80, 40), plane_mm(40, 30) * 5, poses=[np.eye(4), np.eye(4)])
    with open_dataset(folder2) as loader:
        assert list(loader) == []
        assert loader.skips.size_mismatch == 2
        (reason,) = loader.skips.reasons
    assert "differ in size and aspect ratio" in reason and "intrinsics" in reason


def test_register_never_interpolates_depth_and_keeps_labels_discrete():
    rng = np.random.default_rng(0)
    depth = rng.choice([0.0, 1.0, 4.0], size=(30, 40)).astype(np.float32)
    color = ray_color(K_COLOR, 81, 61)
    labels = np.zeros((61, 81), np.int32)
    labels[:, 40:] = 7
    labels[20:30, 10:20] = 1_000_003
    out_c, intr, out_l, resampled = register_to_depth(color, depth, K_COLOR, K_DEPTH, labels)
    assert resampled and out_c.shape == (30, 40, 3) and intr.width == 40
    assert out_l is not None and set(np.unique(out_l).tolist()) <= {0, 7, 1_000_003}
    # the label boundary at colour column 40 lands at depth column (40 - cx_c) * fx_d / fx_c + cx_d = 19.35
    assert np.all(out_l[:, :20] != 7) and np.all(out_l[:, 20:] == 7)
    with pytest.raises(DatasetError, match="no camera intrinsics"):
        register_to_depth(color, depth, None, None)
