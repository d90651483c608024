"""Panoptic painting, mask crops, the `none` backend, the factory and the stage's YAML file."""

from __future__ import annotations

import numpy as np
import pytest

from panoptic_mapping.segmentation import (
    MaskCrop,
    NoneSegmenter,
    PaintConfig,
    PanopticSegmentation,
    SegmentationConfig,
    SegmentationError,
    SegmentCandidate,
    assemble,
    load_segmentation_config,
    make_segmenter,
)
from panoptic_mapping.segmentation.config import DEFAULT_SEGMENTATION_YAML, default_noise_levels
from recon_core.classes import load_class_table
from recon_core.config import ConfigError

TABLE = load_class_table()


def _rect(x: int, y: int, w: int, h: int) -> MaskCrop:
    return MaskCrop(x, y, np.ones((h, w), bool))


def _cand(name: str, mask: MaskCrop, score: float) -> SegmentCandidate:
    return SegmentCandidate(mask, TABLE.by_name(name), score)


def test_assemble_things_by_score_overlap_rule_then_stuff():
    cands = [
        _cand("chair", _rect(15, 15, 20, 20), 0.8),     # a quarter under the table: kept
        _cand("table", _rect(5, 5, 20, 20), 0.9),      # higher score: painted first, keeps everything
        _cand("cup", _rect(6, 6, 10, 10), 0.85),       # fully inside the table: hidden -> dropped
        _cand("wall", _rect(0, 0, 40, 10), 0.7),       # two wall candidates -> one segment
        _cand("wall", _rect(0, 30, 40, 10), 0.95),
        _cand("book", _rect(35, 35, 10, 10), 0.9),     # reaches past the 40x40 image: clipped
    ]
    r = assemble((40, 40), cands)
    by_name = {s.class_name: s for s in r.segments}
    assert sorted(by_name) == ["book", "chair", "table", "wall"]
    assert [s.id for s in r.segments] == [1, 2, 3, 4]  # painting order without rng: table, book, chair, wall
    table, chair, wall, book = by_name["table"], by_name["chair"], by_name["wall"], by_name["book"]
    assert table.box == (5, 5, 20, 20) and table.area == 400
    assert chair.area == 400 - 10 * 10 and chair.box == (15, 15, 20, 20)
    assert book.box == (35, 35, 5, 5) and book.area == 25
    assert wall.instance_id == 0 and wall.score == 0.95 and wall.box == (0, 0, 40, 40)
    assert wall.area == int((r.labels == wall.id).sum())
    assert sorted(s.instance_id for s in r.things) == [1, 2, 3]
    for s in r.segments:
        assert s.area == int((r.labels == s.id).sum())


def test_assemble_valid_mask_min_area_and_random_ids():
    cands = [_cand("chair", _rect(0, 0, 10, 10), 0.9), _cand("cup", _rect(20, 20, 2, 2), 0.9)]
    valid = np.ones((30, 30), bool)
    valid[:5] = False
    r = assemble((30, 30), cands, PaintConfig(min_area_px=5), valid=valid)
    assert [(s.class_name, s.area, s.box) for s in r.segments] == [("chair", 50, (0, 5, 10, 5))]
    ids = {tuple(s.id for s in assemble((30, 30), cands * 3, rng=np.random.default_rng(k)).segments)
           for k in range(5)}
    assert all(sorted(i) == [1, 2] for i in ids)


def test_mask_crop_helpers():
    full = np.zeros((10, 12), bool)
    full[2:5, 3:9] = True
    crop = MaskCrop.from_full(full)
    assert (crop.x, crop.y, crop.width, crop.height, crop.area) == (3, 2, 6, 3, 18)
    np.testing.assert_array_equal(crop.to_full((10, 12)), full)
    assert MaskCrop.from_full(np.zeros((3, 3), bool)) is None
    padded = crop.padded(4, (10, 12))
    assert (padded.x, padded.y, padded.width, padded.height) == (0, 0, 12, 9) and padded.area == 18
    assert padded.tight().slices == crop.slices
    assert not crop.touches_border((10, 12)) and padded.padded(1, (10, 12)).area == 18
    edge = _rect(0, 4, 2, 2)
    assert edge.touches_border((10, 12)) and edge.union(crop).area == 22


def test_none_backend_and_input_checks():
    seg = make_segmenter(SegmentationConfig())
    assert isinstance(seg, NoneSegmenter)
    r = seg.segment(np.zeros((4, 5, 3), np.uint8), np.zeros((4, 5), np.float32))
    assert r.labels.shape == (4, 5) and not r.labels.any() and r.segments == [] and r.latency_ms >= 0
    with pytest.raises(SegmentationError, match="registered"):
        seg.segment(np.zeros((4, 5, 3), np.uint8), np.zeros((5, 4), np.float32))
    with pytest.raises(SegmentationError, match="empty"):
        seg.segment(np.zeros((0, 5, 3), np.uint8))
    with pytest.raises(SegmentationError, match="int32"):
        PanopticSegmentation(np.zeros((2, 2), np.int64))


def test_factory_and_config_errors():
    with pytest.raises(ConfigError, match=r"backend: got 'detectron'; valid values"):
        SegmentationConfig(backend="detectron")
    cfg = SegmentationConfig()
    cfg.backend = "detectron"  # bypasses validation: the factory still names the options
    with pytest.raises(SegmentationError, match="valid backends"):
        make_segmenter(cfg)
    with pytest.raises(ConfigError, match="valid keys"):
        load_segmentation_config(overrides={"oracle.noise_level": "hard"})
    cfg = load_segmentation_config(overrides={"backend": "onnx", "onnx.model_config": "nowhere.yaml"})
    with pytest.raises(SegmentationError, match="not found"):
        make_segmenter(cfg)
    cfg.onnx.model_config = "config/segmentation/yolo_seg.yaml"  # exists, but the model file it names does not
    with pytest.raises(SegmentationError, match="export your own"):
        make_segmenter(cfg)


def test_yaml_mirrors_the_dataclass_defaults():
    assert load_segmentation_config(DEFAULT_SEGMENTATION_YAML) == SegmentationConfig()
    assert load_segmentation_config().oracle.levels == default_noise_levels()
    hard = load_segmentation_config(overrides={"oracle.level": "hard"}).oracle.noise()
    assert hard == default_noise_levels()["hard"]
