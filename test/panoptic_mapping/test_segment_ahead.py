"""Depth segmentation ahead on a worker process (issue 26): the label frames' segments computed while earlier
frames are mapped give the map of segmenting each frame when it is integrated, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

import panoptic_mapping.pipeline as pipeline
from panoptic_mapping.config import MapperConfig
from panoptic_mapping.dataio import DataInputConfig
from panoptic_mapping.dataio.registry import open_dataset
from panoptic_mapping.depth_segmentation import SegmentationWorker, segment_depth_labels
from panoptic_mapping.pipeline import map_recording
from panoptic_mapping.segmentation.config import SegmentationConfig
from panoptic_mapping.segmentation.factory import make_segmenter
from recon_core.config import CONFIG_DIR, load_config
from scene_recon.synthetic.generate import GenerateConfig, generate_recording, ground_truth_path

FRAMES = 30


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ahead")
    cfg = GenerateConfig(objects=6, frames=FRAMES, seed=3)
    cfg.sensor.camera.width, cfg.sensor.camera.height = 160, 120
    cfg.sensor.camera.fx = cfg.sensor.camera.fy = 131.25
    cfg.sensor.camera.cx, cfg.sensor.camera.cy = 79.5, 59.5
    generate_recording(folder / "rec.db3", cfg, progress=False)
    return folder / "rec"


def _map(bag, ahead: int):
    cfg = load_config(MapperConfig, CONFIG_DIR / "mapper.yaml")
    cfg.depth_segmentation.min_segment_pixels = 30  # 160x120 frames
    cfg.fusion.min_segment_points = 40
    # label propagation on every 3rd frame (the default is keyframes only): many label frames to segment ahead
    cfg.keyframes.label_every_n_frames = 3
    seg = SegmentationConfig(backend="oracle")
    seg.oracle.ground_truth, seg.oracle.level, seg.oracle.seed = str(ground_truth_path(bag)), "default", 0
    data = DataInputConfig()
    data.topics.labels = "/ground_truth/panoptic_labels"
    return map_recording(bag, make_segmenter(seg), cfg, data, progress=False, segment_ahead=ahead)


def _state(mapper) -> dict[str, np.ndarray]:
    """The map's arrays, voxel blocks in key order (Open3D hands out block slots in thread-timing order)."""
    snap = mapper.snapshot()
    order = np.lexsort(snap.arrays["tsdf_block_keys"].T[::-1])
    return {k: (v[order] if k.startswith("tsdf_") else v) for k, v in snap.arrays.items()}


def _assert_same_map(a, b) -> None:
    sa, sb = _state(a), _state(b)
    assert sa.keys() == sb.keys()
    for k in sa:
        np.testing.assert_array_equal(sa[k], sb[k], err_msg=k)
    ea, eb = a.entities(), b.entities()
    assert [(e.id, e.class_id, len(e.faces)) for e in ea] == [(e.id, e.class_id, len(e.faces)) for e in eb]
    for x, y in zip(ea, eb, strict=True):
        np.testing.assert_array_equal(x.vertices, y.vertices)


def test_segmenting_ahead_gives_the_same_map(recording):
    inline, run0 = _map(recording, 0)
    ahead, run3 = _map(recording, 3)
    assert run0.ahead_used == 0 and run0.ahead_cpu_s == 0.0
    # every label frame but the first (nothing is read ahead of it) was segmented on the worker, none in vain
    label_frames = run3.stage_frames["depth_segmentation"]
    assert label_frames > FRAMES // 3 and run3.ahead_used == label_frames - 1 and run3.ahead_unused == 0
    assert run3.ahead_cpu_s > 0
    assert run0.frames == run3.frames == FRAMES and run0.keyframes == run3.keyframes
    _assert_same_map(inline, ahead)


def test_a_worker_that_dies_leaves_the_map_as_it_was(recording, monkeypatch):
    inline, _ = _map(recording, 0)
    worker = SegmentationWorker()
    submit = worker.submit
    calls = []

    def dying_submit(*args, **kwargs):  # the process is killed after its second job
        fut = submit(*args, **kwargs)
        calls.append(fut)
        if len(calls) == 2:
            assert worker._proc is not None
            worker._proc.kill()
        return fut

    monkeypatch.setattr(worker, "submit", dying_submit)
    monkeypatch.setattr(pipeline, "segmentation_worker", lambda: worker)
    try:
        ahead, run = _map(recording, 3)
    finally:
        worker.close()
    assert len(calls) > 2 and run.ahead_used < run.stage_frames["depth_segmentation"] - 1
    _assert_same_map(inline, ahead)


def test_the_worker_returns_the_labels_computed_here(recording):
    cfg = load_config(MapperConfig, CONFIG_DIR / "mapper.yaml").depth_segmentation
    cfg.min_segment_pixels = 30
    with open_dataset(recording) as loader:
        frames = [f for i, f in enumerate(loader) if i in (0, 7, 15)]
    worker = SegmentationWorker()
    try:
        futures = [worker.submit(f.depth.astype(np.float32), f.intrinsics, cfg, 1.0) for f in frames]
        for f, fut in zip(frames, futures, strict=True):
            labels, cpu = fut.result(timeout=60)
            np.testing.assert_array_equal(labels, segment_depth_labels(f.depth.astype(np.float32), f.intrinsics, cfg))
            assert labels.max() > 1 and cpu > 0
        worker.close()
        # closed: the next job starts a new process
        labels, _ = worker.submit(frames[0].depth.astype(np.float32), frames[0].intrinsics, cfg).result(timeout=60)
        np.testing.assert_array_equal(labels, futures[0].result()[0])
    finally:
        worker.close()


def test_a_keyframe_segmented_while_its_masks_are_computed_maps_the_same(recording):
    """The mapper node's use: `segment_ahead` when a keyframe is sent for labels, `ahead_segments` when they came."""
    from panoptic_mapping.mapper import PanopticMapper
    from panoptic_mapping.pipeline import ahead_segments, class_metas, segment_ahead

    cfg = load_config(MapperConfig, CONFIG_DIR / "mapper.yaml")
    cfg.depth_segmentation.min_segment_pixels = 30
    with open_dataset(recording) as loader:
        frames = [f for i, f in enumerate(loader) if i < 4]
    inline, ahead = PanopticMapper(cfg, class_metas()), PanopticMapper(cfg, class_metas())
    for f in frames:
        started = segment_ahead(ahead, f)
        other_map = PanopticMapper(load_config(MapperConfig, CONFIG_DIR / "mapper.yaml"), class_metas())
        assert ahead_segments(started, other_map) is None  # a map loaded since: its own config
        assert ahead_segments(started, ahead, needed=False) is None
        segments = ahead_segments(started, ahead, ahead.fuses_labels(None))
        assert (segments is not None) == ahead.fuses_labels(None)
        inline.integrate(f, None)
        ahead.integrate(f, None, segments)
    _assert_same_map(inline, ahead)


def test_a_worker_started_before_its_first_job_runs_it(recording, monkeypatch):
    """`start()` (the mapper node calls it at start-up) starts the process without a job; the first job then
    goes to that process. A worker that cannot start says so and is marked broken (segment on this thread)."""
    cfg = load_config(MapperConfig, CONFIG_DIR / "mapper.yaml").depth_segmentation
    with open_dataset(recording) as loader:
        frame = next(iter(loader))
    worker = SegmentationWorker()
    try:
        assert worker.start()
        proc = worker._proc
        assert proc is not None and proc.poll() is None
        depth = frame.depth.astype(np.float32)
        labels, _ = worker.submit(depth, frame.intrinsics, cfg).result(timeout=60)
        assert worker._proc is proc  # no second process
        np.testing.assert_array_equal(labels, segment_depth_labels(depth, frame.intrinsics, cfg))
    finally:
        worker.close()

    def no_process(*_a, **_k):
        raise OSError("no process for you")

    monkeypatch.setattr("panoptic_mapping.depth_segmentation.subprocess.Popen", no_process)
    broken = SegmentationWorker()
    assert not broken.start() and broken.broken
