"""Oracle backend: exact at `clean`, each noise effect measurable on its own, levels ordered."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from panoptic_mapping.segmentation import (
    OracleConfig,
    OracleNoiseConfig,
    OracleSegmenter,
    SegmentationError,
    make_segmenter,
)
from panoptic_mapping.segmentation.config import SegmentationConfig, clean_noise, default_noise_levels
from recon_core.classes import load_class_table
from recon_core.config import ConfigError

TABLE = load_class_table()
H, W = 240, 320  # half of 480: pixel sizes of the noise config scale by 0.5, areas by 0.25
# entity id -> (class name, rows, cols)
LAYOUT = {
    1: ("floor", (150, 240), (0, 320)),
    2: ("wall", (0, 150), (0, 160)),
    3: ("wall", (0, 150), (160, 320)),
    4: ("table", (100, 170), (20, 100)),
    5: ("table", (100, 170), (100, 180)),   # touches table 4: may be merged with it
    6: ("chair", (160, 230), (200, 260)),   # stands in front of the (far) floor
    7: ("cup", (80, 90), (40, 50)),         # 100 px: small
    8: ("monitor", (0, 50), (270, 320)),    # cut off by the image border; in no confusion group
    9: ("fridge", (20, 140), (190, 250)),
    10: ("book", (60, 70), (280, 300)),     # in no confusion group
}
THINGS = [eid for eid, (name, _, _) in LAYOUT.items() if TABLE.by_name(name).is_thing]


def _scene() -> tuple[np.ndarray, np.ndarray]:
    labels = np.zeros((H, W), np.int32)
    depth = np.full((H, W), 4.0, np.float32)
    for eid, (_, (r0, r1), (c0, c1)) in LAYOUT.items():
        labels[r0:r1, c0:c1] = eid
    depth[labels == 1] = 3.0
    depth[labels >= 4] = 1.5
    depth[labels == 6] = 1.0
    labels[230:, :20] = 0  # no entity (no return from the sensor)
    depth[230:, :20] = 0.0
    return labels, depth


def _entities() -> dict[int, tuple[str, int, bool]]:
    return {eid: (name, TABLE.by_name(name).id, TABLE.by_name(name).is_thing) for eid, (name, _, _) in LAYOUT.items()}


def _oracle(noise: OracleNoiseConfig | None = None, seed: int = 0, **changes) -> OracleSegmenter:
    base = noise if noise is not None else clean_noise()
    return OracleSegmenter(_entities(), dataclasses.replace(base, **changes), seed=seed)


def _best_iou(gt: np.ndarray, pred: np.ndarray, ids: list[int]) -> dict[int, float]:
    """For each ground-truth entity: IoU with its best-matching predicted segment (0 if none)."""
    m = int(pred.max()) + 1
    joint = np.bincount(gt.ravel().astype(np.int64) * m + pred.ravel(), minlength=(int(gt.max()) + 1) * m)
    joint = joint.reshape(-1, m)
    g, p = joint.sum(1), joint.sum(0)
    out = {}
    for eid in ids:
        inter = joint[eid, 1:]
        union = g[eid] + p[1:] - inter
        out[eid] = float((inter / np.maximum(union, 1)).max()) if inter.size else 0.0
    return out


def test_clean_is_the_exact_partition_with_per_frame_ids():
    labels, depth = _scene()
    seg = _oracle()
    ids_of_table = set()
    for key in range(6):
        r = seg.segment_labels(labels, depth, key=key)
        assert r.labels.dtype == np.int32 and r.labels.shape == (H, W)
        for eid in THINGS:
            sid = int(r.labels[labels == eid][0])
            np.testing.assert_array_equal(r.labels == sid, labels == eid)  # same pixels, nothing else
            s = r.segment(sid)
            assert (s.class_name, s.is_thing, s.score) == (LAYOUT[eid][0], True, 1.0)
            assert s.class_id == TABLE.by_name(LAYOUT[eid][0]).id
        wall = r.segment(int(r.labels[0, 0]))
        np.testing.assert_array_equal(r.labels == wall.id, (labels == 2) | (labels == 3))  # one per class
        assert (wall.class_name, wall.instance_id, wall.is_thing) == ("wall", 0, False)
        assert sorted(s.class_name for s in r.stuff) == ["floor", "wall"]
        assert (r.labels[labels == 0] == 0).all()
        assert sorted(s.instance_id for s in r.things) == list(range(1, len(THINGS) + 1))
        assert all(s.box == _box(r.labels == s.id) and s.area == int((r.labels == s.id).sum()) for s in r.segments)
        ids_of_table.add(int(r.labels[labels == 4][0]))
    assert len(ids_of_table) > 1  # ids carry no identity across frames


def _box(mask: np.ndarray) -> tuple[int, int, int, int]:
    ys, xs = np.nonzero(mask)
    return int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)


def test_deterministic_per_seed_and_frame_key():
    labels, depth = _scene()
    hard = default_noise_levels()["hard"]
    a = _oracle(hard, seed=3).segment_labels(labels, depth, key=7)
    b = _oracle(hard, seed=3).segment_labels(labels, depth, key=7)
    np.testing.assert_array_equal(a.labels, b.labels)
    assert [dataclasses.replace(s) for s in a.segments] == b.segments
    assert not np.array_equal(a.labels, _oracle(hard, seed=3).segment_labels(labels, depth, key=8).labels)
    assert not np.array_equal(a.labels, _oracle(hard, seed=4).segment_labels(labels, depth, key=7).labels)


def test_levels_order_mask_iou():
    labels, depth = _scene()
    levels = default_noise_levels()
    mean_iou = {}
    for name in ("clean", "default", "hard"):
        seg = _oracle(levels[name], seed=1)
        ious = [v for k in range(30) for v in _best_iou(labels, seg.segment_labels(labels, depth, key=k).labels,
                                                         THINGS).values()]
        mean_iou[name] = float(np.mean(ious))
    assert mean_iou["clean"] == 1.0
    assert 0.5 < mean_iou["default"] < 0.97
    assert mean_iou["hard"] < mean_iou["default"] - 0.05
    assert mean_iou["hard"] > 0.2  # still a segmentation, not noise


def test_missed_instances_small_and_truncated_more_often():
    labels, depth = _scene()
    assert not _oracle(miss_prob=1.0).segment_labels(labels, depth).things
    seg = _oracle(miss_prob_small=1.0, miss_prob_truncated=1.0)
    seen = {eid: 0 for eid in THINGS}
    for k in range(40):
        r = seg.segment_labels(labels, depth, key=k)
        for eid in THINGS:
            seen[eid] += int(r.labels[labels == eid].any())
    assert seen[8] == 0  # truncated by the border: always missed at probability 1
    assert 0 < seen[7] < 25  # cup: 100 px of a 375 px "small" threshold -> missed ~73 % of frames
    assert all(seen[eid] == 40 for eid in (4, 5, 6, 9))  # large, fully visible: never missed


def test_class_confusion_only_within_groups():
    labels, depth = _scene()
    always = _oracle(confusion_prob=1.0).segment_labels(labels, depth)
    for eid in THINGS:
        own = TABLE.by_name(LAYOUT[eid][0])
        got = always.segment(int(always.labels[labels == eid][0])).class_name
        assert got in own.confusable_with if own.confusable_with else got == own.name
    seg = _oracle(confusion_prob=0.5)
    seen: dict[int, set[str]] = {eid: set() for eid in THINGS}
    for k in range(30):
        r = seg.segment_labels(labels, depth, key=k)
        for eid in THINGS:
            seen[eid].add(r.segment(int(r.labels[labels == eid][0])).class_name)
    for eid, names in seen.items():
        own = TABLE.by_name(LAYOUT[eid][0])
        assert names <= {own.name, *own.confusable_with}
    assert len(seen[4]) == 2  # table <-> desk both occur


def test_over_segmentation_splits_along_a_line():
    labels, depth = _scene()
    r = _oracle(split_prob=1.0, split_min_area_px=1000).segment_labels(labels, depth)  # 250 px at this size
    for eid in THINGS:
        parts = np.unique(r.labels[labels == eid])
        assert np.array_equal(np.isin(r.labels, parts), labels == eid)  # the parts tile the instance exactly
        assert len(parts) == (1 if eid in (7, 10) else 2)  # cup (100 px), book (200 px) are too small
        assert {r.segment(int(p)).class_name for p in parts} == {LAYOUT[eid][0]}


def test_under_segmentation_merges_touching_same_class():
    labels, depth = _scene()
    r = _oracle(merge_prob=1.0).segment_labels(labels, depth)
    merged = r.labels == r.labels[labels == 4][0]
    np.testing.assert_array_equal(merged, (labels == 4) | (labels == 5))
    assert len(r.things) == len(THINGS) - 1


def test_boundary_noise_erodes_or_dilates():
    labels, depth = _scene()
    seg = _oracle(boundary_prob=1.0, boundary_max_radius_px=8, stuff_boundary_noise=True)
    areas = {"grew": 0, "shrank": 0}
    for k in range(10):
        r = seg.segment_labels(labels, depth, key=k)
        iou = _best_iou(labels, r.labels, [4, 6, 9])
        assert all(0.6 < v < 1.0 for v in iou.values())
        n = int((r.labels == r.labels[labels == 9][0]).sum())  # the fridge: nothing in front of it
        areas["grew" if n > (labels == 9).sum() else "shrank"] += 1
    assert areas["grew"] and areas["shrank"]


def test_mask_bleeds_onto_far_background_only_with_depth():
    labels, depth = _scene()
    seg = _oracle(bleed_prob=1.0)
    with_depth = seg.segment_labels(labels, depth)
    chair = with_depth.labels == with_depth.labels[labels == 6][0]
    extra = chair & (labels != 6)
    assert (chair >= (labels == 6)).all() and extra.any()
    assert (depth[extra] >= 1.0 + 0.5).all() and set(np.unique(labels[extra])) == {1}  # onto the floor only
    no_depth = seg.segment_labels(labels, None)
    np.testing.assert_array_equal(no_depth.labels == no_depth.labels[labels == 6][0], labels == 6)


def test_spurious_blobs_and_scores():
    labels, depth = _scene()
    r = _oracle(spurious_rate=6.0, spurious_axes_px=[20.0, 40.0]).segment_labels(labels, depth)
    assert len(r.things) > len(THINGS)
    assert all(s.is_thing for s in r.segments if s.class_name not in ("floor", "wall"))
    assert (r.labels[labels == 0] == 0).all()
    scores = [s.score for k in range(10) for s in
              _oracle(OracleNoiseConfig()).segment_labels(labels, depth, key=k).segments]
    assert min(scores) >= 0.7 and max(scores) <= 1.0 and len(set(scores)) > 10


def test_no_entity_pixels_stay_empty_at_every_level():
    labels, depth = _scene()
    for name, noise in default_noise_levels().items():
        for k in range(5):
            r = _oracle(noise).segment_labels(labels, depth, key=k)
            assert (r.labels[labels == 0] == 0).all(), name


def test_frames_from_the_simulator(small_frames):
    seg = OracleSegmenter.from_ground_truth(small_frames.scene, OracleConfig(level="default", seed=2))
    for f in small_frames.frames[:5]:
        a, b = seg.segment_frame(f), seg.segment(f.color, f.depth, f)
        np.testing.assert_array_equal(a.labels, b.labels)  # keyed by the frame's stamp
        assert {s.class_name for s in a.stuff} <= {"floor", "wall", "ceiling"}
        assert all(s.instance_id == 0 for s in a.stuff) and a.latency_ms > 0
    with pytest.raises(SegmentationError, match="extras"):
        seg.segment(f.color, f.depth)


def test_latency_640x480_default(vga_frame):
    seg = OracleSegmenter.from_ground_truth(vga_frame.scene, OracleConfig(level="default"))
    f = vga_frame.frames[0]
    times = [seg.segment(f.color, f.depth, f).latency_ms for _ in range(7)]
    assert min(times) < 20.0, times  # min: robust to other processes on the 2 cores


def test_ground_truth_from_folders(tmp_path):
    from scene_recon.synthetic.scene import build_scene

    scene = build_scene(4, 1)
    scene.save(tmp_path / "rec_groundtruth")
    (tmp_path / "rec").mkdir()
    cfg = SegmentationConfig(backend="oracle")
    for source in (tmp_path / "rec_groundtruth", tmp_path / "rec", tmp_path / "rec_groundtruth" / "scene.json"):
        seg = make_segmenter(cfg, ground_truth=source)
        assert isinstance(seg, OracleSegmenter) and set(seg.entities) == {e.id for e in scene.entities}
    cfg.oracle.ground_truth = str(tmp_path / "rec")
    assert isinstance(make_segmenter(cfg), OracleSegmenter)
    with pytest.raises(SegmentationError, match="no ground truth"):
        make_segmenter(cfg, ground_truth=tmp_path / "nowhere")
    with pytest.raises(SegmentationError, match=r"oracle\.ground_truth"):
        make_segmenter(SegmentationConfig(backend="oracle"))


def test_clear_errors():
    labels, _ = _scene()
    seg = _oracle()
    bad = labels.copy()
    bad[0, 0] = 99
    with pytest.raises(SegmentationError, match="99"):
        seg.segment_labels(bad)
    with pytest.raises(SegmentationError, match="class table says"):
        OracleSegmenter({1: ("chair", 10, True)})
    with pytest.raises(KeyError, match="known"):
        OracleSegmenter({1: ("throne", 10, True)})
    with pytest.raises(ConfigError, match="valid levels"):
        OracleConfig(level="extreme").noise()
    with pytest.raises(ConfigError, match="miss_prob"):
        OracleNoiseConfig(miss_prob=1.5)


def test_flicker_varies_the_error_rate_between_frames():
    labels, depth = _scene()

    def missed_per_frame(flicker: float) -> np.ndarray:
        seg = _oracle(miss_prob=0.5, flicker=flicker)
        return np.array([len(THINGS) - len(seg.segment_labels(labels, depth, key=k).things) for k in range(80)])

    steady, flickering = missed_per_frame(0.0), missed_per_frame(1.0)
    assert abs(steady.mean() - flickering.mean()) < 1.0  # same average rate ...
    assert flickering.var() > 1.5 * steady.var()  # ... but some frames are much worse than others
