"""Bags as real robots record them: a TF tree rooted elsewhere than `map`, depth at another resolution
than colour (with or without its own camera info), 65535 depth markers, intrinsics overrides."""

from __future__ import annotations

import numpy as np
import pytest
from testsupport.frames import T0, ray_of_color, rgbd_rawbag
from testsupport.rawbag import RawBag, camera_info, image

from panoptic_mapping.dataio import DataInputConfig
from panoptic_mapping.dataio.diagnose import explain_empty
from panoptic_mapping.dataio.registry import open_dataset


def _bag(tmp_path, name, storage="mcap", **kw):
    return rgbd_rawbag(**kw).write(tmp_path / name, storage)


def test_tf_rooted_at_world_names_the_root_and_the_option(tmp_path):
    path = _bag(tmp_path, "world", root="world")
    with open_dataset(path) as loader:
        assert list(loader) == []
        assert loader.skips.no_pose == 3
        hint = loader.pose_hint()
        why = explain_empty(loader, path)
    assert hint == "TF root is 'world', not 'map': pass --map-frame world"
    assert "3 frames have no camera pose: TF root is 'world', not 'map': pass --map-frame world" in why
    with open_dataset(path, DataInputConfig(map_frame="world")) as loader:
        frames = list(loader)
    assert len(frames) == 3
    np.testing.assert_allclose(frames[2].pose[:3, 3], [0.02, 0, 0])


def test_pose_hints_for_other_tf_problems(tmp_path):
    with open_dataset(_bag(tmp_path, "a"), DataInputConfig(camera_frame="camera_depth_optical_frame")) as loader:
        list(loader)
        hint = loader.pose_hint()
    assert "camera frame 'camera_depth_optical_frame'" in hint and "--camera-frame" in hint
    bag = RawBag()  # no TF at all
    bag.add("/camera/color/camera_info", camera_info(T0, "opt", (60, 60, 31.5, 23.5), 64, 48))
    bag.add("/camera/color/image_raw", image(T0, "opt", "rgb8", np.zeros((48, 64, 3), np.uint8)))
    bag.add("/camera/depth/image_rect_raw", image(T0, "opt", "16UC1", np.full((48, 64), 900, "<u2")))
    with open_dataset(bag.write(tmp_path / "notf")) as loader:
        list(loader)
        assert "no TF data" in loader.pose_hint()


def test_depth_with_its_own_camera_info_at_another_size(tmp_path):
    """Colour 64x48 (one camera), depth 40x30 (another, narrower): colour resampled onto the depth grid."""
    k_depth = (36.0, 36.0, 19.5, 14.5)
    path = _bag(tmp_path, "two", color_wh=(64, 48), depth_wh=(40, 30), k_color=(50.0, 50.0, 31.5, 23.5),
                k_depth=k_depth)
    with open_dataset(path) as loader:
        frames = list(loader)
        assert loader.topics["depth_camera_info"] == "/camera/depth/camera_info"
        assert loader.resampled_frames == 3
    assert len(frames) == 3
    f = frames[0]
    assert (f.intrinsics.fx, f.intrinsics.cx, f.intrinsics.width, f.intrinsics.height) == (36.0, 19.5, 40, 30)
    xr, yr = ray_of_color(f.color)
    u, v = np.meshgrid(np.arange(40.0), np.arange(30.0))
    np.testing.assert_allclose(xr, (u - 19.5) / 36.0, atol=1.5 / 150)
    np.testing.assert_allclose(yr, (v - 14.5) / 36.0, atol=1.5 / 150)
    np.testing.assert_array_equal(f.depth, np.float32(1500) * np.float32(0.001))  # depth untouched


def test_decimated_depth_without_its_own_info_scales_the_colour_intrinsics(tmp_path):
    path = _bag(tmp_path, "dec", color_wh=(64, 48), depth_wh=(32, 24))
    with open_dataset(path) as loader:
        frames = list(loader)
    assert len(frames) == 3
    k = frames[0].intrinsics
    assert (k.fx, k.fy, k.cx, k.cy, k.width, k.height) == (30.0, 30.0, 15.5, 11.5, 32, 24)
    # a depth of another aspect ratio and no depth camera info: skipped, counted, with what is missing
    with open_dataset(_bag(tmp_path, "odd", color_wh=(64, 48), depth_wh=(40, 40))) as loader:
        assert list(loader) == []
        assert loader.skips.bad_image == 3
        why = explain_empty(loader)
    assert "differ in size and aspect ratio" in why and "depth camera's intrinsics" in why


def test_intrinsics_override_and_65535_depth_in_a_bag(tmp_path):
    raw = np.full((48, 64), 2000, "<u2")
    raw[:, :10] = 65535
    path = _bag(tmp_path, "sat", depth_mm=raw)
    with open_dataset(path, DataInputConfig(intrinsics=[70.0, 71.0, 31.5, 23.5])) as loader:
        frames = list(loader)
    assert len(frames) == 3
    assert (frames[0].intrinsics.fx, frames[0].intrinsics.fy) == (70.0, 71.0)
    np.testing.assert_array_equal(frames[0].depth[:, :10], 0.0)
    np.testing.assert_allclose(frames[0].depth[:, 10:], 2.0)
    (tmp_path / "k.txt").write_text("80 0 31.5\n0 80 23.5\n0 0 1\n")
    with open_dataset(path, DataInputConfig(intrinsics_file=str(tmp_path / "k.txt"))) as loader:
        assert next(iter(loader)).intrinsics.fx == 80.0


@pytest.mark.parametrize("storage", ["mcap", "db3"])
def test_bag_folder_without_metadata_opens(tmp_path, storage):
    """A recorder killed before writing metadata.yaml leaves the storage file(s) only."""
    bag = _bag(tmp_path, "rec", storage)
    folder = tmp_path / "killed"
    folder.mkdir()
    (folder / f"killed_0.{storage}").write_bytes(next(bag.glob(f"*.{storage}")).read_bytes())
    with open_dataset(folder) as loader:
        assert len(list(loader)) == 3
        assert not loader.truncated  # the file itself is complete
