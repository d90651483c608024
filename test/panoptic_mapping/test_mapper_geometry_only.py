"""The geometry-only fast path: without a segmenter (and between keyframes on frames that propagate
no labels) the mapper integrates the TSDF only, and that geometry is the labelled path's geometry."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from testsupport.frames import ray_color, translation_pose, tum

import panoptic_mapping.mapper as mapper_module
from panoptic_mapping.config import MapperConfig, TSDFConfig
from panoptic_mapping.dataio import CameraIntrinsics, RGBDFrame
from panoptic_mapping.fusion import BACKGROUND, PanopticMasks
from panoptic_mapping.mapper import UNKNOWN_ENTITY_ID, PanopticMapper
from panoptic_mapping.pipeline import class_metas, map_recording
from panoptic_mapping.segmentation.config import SegmentationConfig
from panoptic_mapping.segmentation.factory import make_segmenter
from panoptic_mapping.tsdf_map import LabeledTSDF
from scene_recon.synthetic.geometry import look_at_pose
from scene_recon.synthetic.items import RenderItem
from scene_recon.synthetic.renderer import RaycastRenderer

INTR = CameraIntrinsics(160.0, 160.0, 79.5, 59.5, 160, 120)
EYES = [(0.0, -0.5, 1.4), (0.1, 0.0, 1.5), (0.0, 0.5, 1.4), (0.3, -0.3, 1.6), (0.3, 0.4, 1.3), (0.2, 0.1, 1.2)]
CLASSES = {1: 1, 2: 10, 3: 19}  # mask id -> class: floor (stuff), table, cup


def _box(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    m = trimesh.creation.box(extents=hi - lo)
    m.apply_translation((lo + hi) / 2)
    return m


@pytest.fixture(scope="module")
def frames() -> list[tuple[RGBDFrame, PanopticMasks]]:
    meshes = [_box([-3, -3, -0.05], [3, 3, 0]), _box([1.2, -0.4, 0], [2.0, 0.4, 0.7]),
              _box([1.55, -0.05, 0.7], [1.65, 0.05, 0.82])]
    renderer = RaycastRenderer([RenderItem(m, i + 1) for i, m in enumerate(meshes)])
    out = []
    for i, eye in enumerate(EYES):
        pose = look_at_pose(np.array(eye, float), np.array((1.6, 0.2, 0.4)))
        hits, rgb = renderer.render(pose, INTR)
        depth = hits.depth.astype(np.float32)
        depth[:5, :5] = 9.0  # beyond max_depth_m: must be cut on both paths alike
        cls = np.array([BACKGROUND, *CLASSES.values()], np.int32)
        masks = PanopticMasks(hits.labels.astype(np.int32), cls, cls != 1, np.ones(len(cls)))
        masks.is_thing[0] = False
        out.append((RGBDFrame(rgb, depth, INTR, pose, i * 100_000_000, index=i), masks))
    return out


def _mapper(label_every_n_frames: int = 3) -> PanopticMapper:
    cfg = MapperConfig(mode="full", downsample=1)
    cfg.keyframes.enabled = False
    cfg.keyframes.label_every_n_frames = label_every_n_frames
    cfg.fusion.min_segment_points = 40
    cfg.depth_segmentation.min_segment_pixels = 20
    return PanopticMapper(cfg, class_metas())


def _forbid_label_work(monkeypatch) -> None:
    """Every step of the labelled path raises: the fast path must reach none of them."""

    def boom(*_a, **_k):
        raise AssertionError("label work on the geometry-only path")

    monkeypatch.setattr(mapper_module, "segment_depth_planes", boom)
    monkeypatch.setattr(mapper_module, "fuse", boom)
    monkeypatch.setattr(PanopticMapper, "_associate", boom)
    monkeypatch.setattr(PanopticMapper, "_vote", boom)
    monkeypatch.setattr(PanopticMapper, "regularize", boom)
    monkeypatch.setattr(LabeledTSDF, "integrate_labels", boom)
    monkeypatch.setattr(LabeledTSDF, "labels_at", boom)
    monkeypatch.setattr(mapper_module.PanopticCounts, "canonical_lut", boom)


def _voxels(tsdf: LabeledTSDF) -> dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]]:
    st = tsdf.state()
    return {tuple(k): (t, w) for k, t, w in zip(st["block_keys"].tolist(), st["tsdf"], st["weight"], strict=True)}


def test_integrate_geometry_does_no_label_work(frames, monkeypatch):
    mapper = _mapper()
    _forbid_label_work(monkeypatch)
    for frame, _ in frames:
        stats = mapper.integrate_geometry(frame)
        assert set(stats.timings_ms) == {"integration"} and stats.segments == 0
    assert mapper.frames_integrated == len(frames) and mapper.tsdf.num_blocks > 0
    assert not mapper.tsdf.vbg.attribute("label").numpy().any()


def test_integrate_without_masks_takes_the_fast_path_between_label_frames(frames, monkeypatch):
    mapper = _mapper(label_every_n_frames=0)  # no label propagation: every frame without masks is geometry only
    _forbid_label_work(monkeypatch)
    for frame, _ in frames:
        mapper.integrate(frame, None)
    assert mapper.frames_integrated == len(frames)
    # every 3rd frame (0, 3, ...) propagates labels: the others never reach the depth segmentation
    mapper = _mapper(label_every_n_frames=3)
    assert [mapper.fuses_labels(None) for mapper.frames_integrated in range(6)] == [True, False, False] * 2
    assert mapper.fuses_labels(frames[0][1])


def test_geometry_equals_the_labelled_paths_geometry(frames):
    labelled, geometric = _mapper(), _mapper()
    for frame, masks in frames:
        labelled.integrate(frame, masks)  # masks on every frame: the full labelled path
        geometric.integrate_geometry(frame)
    a, b = _voxels(labelled.tsdf), _voxels(geometric.tsdf)
    # bit-identical TSDF and weights; label votes may activate a few blocks next to the surface that
    # the depth never reached (weight 0: no geometry), the geometric map never has a block of its own
    assert b.keys() <= a.keys() and len(b) > 50
    for key, (t, w) in a.items():
        if key in b:
            assert np.array_equal(t, b[key][0]) and np.array_equal(w, b[key][1])
        else:
            assert not w.any()
    va, fa, _ = labelled.tsdf.extract_mesh()
    vb, fb, _ = geometric.tsdf.extract_mesh()
    assert len(fa) == len(fb) > 1000
    assert np.array_equal(np.unique(va, axis=0), np.unique(vb, axis=0))
    # with no labels, extraction gives the whole surface to the 'unknown' entity (as before)
    ents = geometric.entities()
    assert [(e.id, e.class_name, e.class_id) for e in ents] == [(UNKNOWN_ENTITY_ID, "unknown", BACKGROUND)]
    assert len(ents[0].faces) == len(fb)
    assert {e.class_name for e in labelled.entities()} >= {"floor", "table", "cup"}


def _recording(folder, n=6):
    k = (60.0, 60.0, 39.5, 29.5)
    poses = [translation_pose(0.02 * i, 0.0, 0.0) for i in range(n)]
    tum(folder, n, ray_color(k, 80, 60), np.full((60, 80), 7500, np.uint16), poses)
    (folder / "camera.yaml").write_text("fx: 60\nfy: 60\ncx: 39.5\ncy: 29.5\n")


@pytest.mark.parametrize("backend", [None, "none"])
def test_mapping_without_a_segmenter_never_segments_depth(tmp_path, monkeypatch, backend):
    _recording(tmp_path / "rec")
    segmenter = None if backend is None else make_segmenter(SegmentationConfig(backend=backend))
    if segmenter is not None:
        monkeypatch.setattr(type(segmenter), "segment_frame", lambda *_a: pytest.fail("segmenter called"))
    _forbid_label_work(monkeypatch)
    mapper, run = map_recording(tmp_path / "rec", segmenter, progress=False)
    assert run.frames == 6 and run.failed_frames == 0 and run.segmentation_calls == 0
    assert set(run.stage_ms) == {"integration"} and mapper.tsdf.num_blocks > 0
    monkeypatch.undo()  # extraction regularizes and reads labels: allowed again
    ents = mapper.entities()
    assert [e.class_name for e in ents] == ["unknown"] and len(ents[0].faces) > 0


def test_in_range_matches_the_numpy_definition():
    rng = np.random.default_rng(0)
    depth = rng.uniform(-1, 6, (37, 53)).astype(np.float32)
    f32 = np.float32
    specials = [0.1, 4.0, np.nextafter(f32(0.1), f32(0)), np.nextafter(f32(4), f32(5)), np.nan, np.inf, -np.inf, 0]
    depth.ravel()[: len(specials)] = specials
    for lo, hi in ((0.1, 4.0), (0.0, 4.0), (0.1, 0.0), (0.0, 0.0), (0.35, 2.5)):
        tsdf = LabeledTSDF(TSDFConfig(min_depth_m=lo, max_depth_m=hi, initial_block_count=16))
        bad = depth > hi if hi > 0 else np.zeros(depth.shape, bool)
        if lo > 0:
            bad |= depth < lo
        want = np.where(bad, f32(0), depth)
        assert np.array_equal(tsdf.in_range(depth), want, equal_nan=True), (lo, hi)
        assert np.array_equal(tsdf.in_range(depth[:, ::2]), want[:, ::2], equal_nan=True)  # non-contiguous view
        assert np.array_equal(tsdf.in_range(depth.astype(np.float64)), want, equal_nan=True)
