"""The mapper and the mapping pipeline on what real recordings bring: depth beyond the range, frames
without valid depth, frames the mapper fails on, poses thousands of kilometres from the origin."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from testsupport.frames import ray_color, translation_pose, tum

from panoptic_mapping.config import MapperConfig, TSDFConfig
from panoptic_mapping.dataio import CameraIntrinsics, DatasetError, RGBDFrame
from panoptic_mapping.fusion import BACKGROUND, PanopticMasks
from panoptic_mapping.mapper import PanopticMapper
from panoptic_mapping.pipeline import MappingFailed, map_recording
from panoptic_mapping.tsdf_map import LabeledTSDF

INTR = CameraIntrinsics(60.0, 60.0, 39.5, 29.5, 80, 60)
K = (60.0, 60.0, 39.5, 29.5)


def _masks(shape) -> PanopticMasks:
    labels = np.ones(shape, np.int32)  # one "table" mask over the whole image
    return PanopticMasks(labels, np.array([BACKGROUND, 10], np.int32), np.array([False, True]), np.ones(2))


def _frame(depth: np.ndarray, pose=None, index=0) -> RGBDFrame:
    return RGBDFrame(ray_color(K, 80, 60), depth.astype(np.float32), INTR,
                     np.eye(4) if pose is None else pose, index * 100_000_000, index=index)


def test_labels_and_blocks_only_within_the_depth_range():
    """Readings past max_depth_m (4 m) allocated label blocks the TSDF never fills (1.8x memory on a real room)."""
    near = np.full((60, 80), 2.0, np.float32)
    both = near.copy()
    both[:, 40:] = 8.0  # beyond the 4 m range
    cut = near.copy()
    cut[:, 40:] = 0.0
    blocks = {}
    for name, depth in (("both", both), ("cut", cut)):
        mapper = PanopticMapper(MapperConfig())
        mapper.integrate(_frame(depth), _masks(depth.shape))
        blocks[name] = mapper.tsdf.num_blocks
        labelled = mapper.tsdf.vbg.attribute("label").numpy().reshape(-1) > 0
        assert labelled.any()
    assert blocks["both"] == blocks["cut"] > 0
    # the near side is configurable: --min-depth / tsdf.min_depth_m
    cfg = MapperConfig()
    cfg.tsdf.min_depth_m = 2.5
    mapper = PanopticMapper(cfg)
    mapper.integrate(_frame(both), _masks(both.shape))
    assert mapper.tsdf.num_blocks == 0


def test_frames_without_depth_in_range_integrate_nothing_and_do_not_raise():
    tsdf = LabeledTSDF(TSDFConfig())
    assert tsdf.integrate_depth(np.zeros((60, 80), np.float32), INTR.matrix, np.eye(4)) == 0  # Open3D would raise
    assert tsdf.integrate_depth(np.full((60, 80), 9.0, np.float32), INTR.matrix, np.eye(4)) == 0
    assert tsdf.integrate_depth(np.full((60, 80), 2.0, np.float32), INTR.matrix, np.eye(4)) > 0
    mapper = PanopticMapper(MapperConfig())
    for i, d in enumerate((0.0, 9.0, 0.05)):
        stats = mapper.integrate(_frame(np.full((60, 80), d, np.float32), index=i), _masks((60, 80)))
        assert stats.segments == 0
    assert mapper.tsdf.num_blocks == 0


def _recording(folder, n=5, offset=(0.0, 0.0, 0.0), with_poses=True):
    poses = [translation_pose(0.02 * i + offset[0], offset[1], offset[2]) for i in range(n)]
    tum(folder, n, ray_color(K, 80, 60), np.full((60, 80), 7500, np.uint16), poses if with_poses else None)
    (folder / "camera.yaml").write_text("fx: 60\nfy: 60\ncx: 39.5\ncy: 29.5\n")
    return poses


def test_a_frame_the_mapper_fails_on_is_logged_counted_and_skipped(tmp_path, monkeypatch, caplog):
    _recording(tmp_path / "rec")
    real = PanopticMapper.integrate_geometry  # no segmenter: every frame takes the geometry-only path

    def flaky(self, frame):
        if frame.index == 2:
            raise RuntimeError("\x1b[1;31m[Open3D Error] No block is touched in TSDF volume\x1b[0;m")
        return real(self, frame)

    monkeypatch.setattr(PanopticMapper, "integrate_geometry", flaky)
    with caplog.at_level(logging.WARNING):
        mapper, run = map_recording(tmp_path / "rec", None, progress=False)
    assert run.frames == 4 and run.failed_frames == 1 and run.skipped["mapper_failed"] == 1
    assert run.failures == {"[Open3D Error] No block is touched in TSDF volume": 1}  # colour codes stripped
    assert "frame 2 (t=10.067 s) not integrated" in caplog.text
    assert mapper.frames_integrated == 4

    monkeypatch.setattr(PanopticMapper, "integrate_geometry", lambda self, f: (_ for _ in ()).throw(ValueError("boom")))
    with pytest.raises(MappingFailed, match="all 5 frames failed in the mapper"):
        map_recording(tmp_path / "rec", None, progress=False)


def test_no_frame_with_a_pose_raises_and_says_why(tmp_path):
    _recording(tmp_path / "rec", with_poses=False)
    with pytest.raises(DatasetError, match=r"5 frames have no camera pose: .*has no groundtruth.txt"):
        map_recording(tmp_path / "rec", None, progress=False)


def test_far_away_poses_are_recentred_on_the_first_pose(tmp_path, caplog):
    """UTM-like coordinates (5000 km): float32 voxels of 2 cm would collapse; the map is built around
    the first pose and remembers the offset."""
    _recording(tmp_path / "near")
    offset = (5_000_000.0, 4_000_000.0, 1.5)
    _recording(tmp_path / "far", offset=offset)
    near, _ = map_recording(tmp_path / "near", None, progress=False)
    with caplog.at_level(logging.WARNING):
        far, run = map_recording(tmp_path / "far", None, progress=False)
    assert "km from the map frame's origin" in caplog.text
    np.testing.assert_array_equal(far.origin_offset, [5_000_000.0, 4_000_000.0, 2.0])  # whole metres
    assert run.origin_offset_m == [5_000_000.0, 4_000_000.0, 2.0]
    assert not np.any(near.origin_offset)
    v_near, f_near, _ = near.tsdf.extract_mesh()
    v_far, f_far, _ = far.tsdf.extract_mesh()
    assert len(f_near) > 100 and len(f_far) == len(f_near)
    # same surface: the far map's local coordinates plus its offset are the input's coordinates

    def rows(v):  # vertex order follows the voxel hash map: compare sorted
        v = np.round(v, 4)
        return v[np.lexsort(v.T[::-1])]

    np.testing.assert_allclose(rows(v_far + far.origin_offset - offset), rows(v_near), atol=2e-4)
    far.save(tmp_path / "saved")
    np.testing.assert_array_equal(PanopticMapper.load(tmp_path / "saved").origin_offset, far.origin_offset)
    # without recentring the mapper refuses such poses instead of building a collapsed map
    with pytest.raises(MappingFailed, match="km from the map origin"):
        map_recording(tmp_path / "far", None, progress=False, recentre_beyond_m=0)


def test_the_progress_total_counts_the_frames_stride_and_max_frames_select(tmp_path, monkeypatch):
    """`map --stride 5` on 1000 frames showed a bar to 1000 that stopped at 200."""
    import tqdm

    from panoptic_mapping.dataio import DataInputConfig
    from panoptic_mapping.pipeline import frames_to_read

    _recording(tmp_path / "rec")  # 5 frames
    totals = []
    real = tqdm.tqdm

    def spy(*args, **kwargs):
        totals.append(kwargs.get("total"))
        return real(*args, **kwargs)

    monkeypatch.setattr(tqdm, "tqdm", spy)
    _mapper, run = map_recording(tmp_path / "rec", None, data_config=DataInputConfig(stride=2), progress=False)
    assert run.frames == 3 and totals == [3]
    assert frames_to_read(1000, DataInputConfig(stride=5)) == 200
    assert frames_to_read(1000, DataInputConfig(start=3, stride=5, max_frames=50)) == 50
    assert frames_to_read(10, DataInputConfig(start=12)) == 0
