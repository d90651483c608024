"""ONNX backend: the three output conventions decoded exactly on tiny models built by the tests."""

from __future__ import annotations

import numpy as np
import pytest

from panoptic_mapping.segmentation import SegmentationError, load_model_config
from panoptic_mapping.segmentation.class_map import COCO_THING_NAMES
from panoptic_mapping.segmentation.decode_common import DecodeContext
from panoptic_mapping.segmentation.letterbox import Letterbox, box_pixels, make_input
from panoptic_mapping.segmentation.model_config import OnnxModelConfig, PreprocessConfig
from panoptic_mapping.segmentation.nms import nms
from panoptic_mapping.segmentation.onnx_backend import OnnxSegmenter
from recon_core.classes import UnknownClassError
from recon_core.config import ConfigError

COCO = {name: i for i, name in enumerate(COCO_THING_NAMES)}
NM = 2  # mask prototypes of the test YOLO model


# ---------------------------------------------------------------------------------------------- YOLO
def _yolo_outputs(channels_last: bool = False) -> dict[str, np.ndarray]:
    """Six detections in input pixels (640x640 letterbox); see the expectations in the tests."""
    dets = [  # class, score, xyxy (input pixels), mask coefficients
        ("chair", 0.90, (150, 240, 250, 320), (1, 0)),   # A: kept, full box mask
        ("chair", 0.80, (155, 245, 255, 325), (1, 0)),   # B: IoU 0.8 with A, same class -> NMS drops it
        ("person", 0.95, (400, 400, 500, 500), (1, 0)),  # C: no project class -> dropped
        ("tv", 0.75, (300, 100, 500, 200), (0, 1)),      # D: monitor, mask = prototype 1 (input x < 400)
        ("bottle", 0.50, (500, 300, 550, 400), (1, 0)),  # E: below the 0.7 threshold
        ("cup", 0.85, (160, 240, 260, 320), (1, 0)),     # F: IoU 0.82 with A but other class: kept by NMS,
    ]                                                    #    then dropped by painting (90 % hidden by A)
    pred = np.zeros((4 + len(COCO) + NM, len(dets)), np.float32)
    for j, (name, score, (x0, y0, x1, y1), coeffs) in enumerate(dets):
        pred[:4, j] = ((x0 + x1) / 2, (y0 + y1) / 2, x1 - x0, y1 - y0)
        pred[4 + COCO[name], j] = score
        pred[4 + len(COCO) :, j] = coeffs
    protos = np.full((NM, 160, 160), 8.0, np.float32)
    protos[1, :, 100:] = -8.0  # prototype 1: positive left of input x = 400 (4 input pixels per cell)
    pred = pred.T if channels_last else pred
    return {"output0": pred[None], "output1": protos[None]}


def _yolo_segmenter(constant_model, channels_last: bool = False, **overrides) -> OnnxSegmenter:
    overrides.setdefault("score_threshold", 0.7)  # the paper's threshold; real detectors default to 0.4
    cfg = OnnxModelConfig(convention="yolo_seg", class_names="coco80", **overrides)
    cfg.yolo.predictions, cfg.yolo.prototypes = "output0", "output1"
    return OnnxSegmenter(cfg, model_bytes=constant_model(_yolo_outputs(channels_last)))


@pytest.mark.parametrize("channels_last", [False, True])
def test_yolo_decoding_boxes_classes_masks_exactly(constant_model, channels_last):
    seg = _yolo_segmenter(constant_model, channels_last)
    result = seg.segment(np.zeros((480, 640, 3), np.uint8))  # letterbox: scale 1, 80 rows of padding on top
    by_class = {s.class_name: s for s in result.segments}
    assert sorted(by_class) == ["chair", "monitor"]
    chair, monitor = by_class["chair"], by_class["monitor"]
    assert chair.box == (150, 160, 100, 80) and chair.area == 100 * 80 and chair.is_thing
    assert monitor.box == (300, 20, 100, 100) and monitor.area == 100 * 100  # box 300..500 cut at x = 400
    assert chair.score == pytest.approx(0.9) and monitor.score == pytest.approx(0.75)
    assert sorted(s.instance_id for s in result.segments) == [1, 2]
    expected = np.zeros((480, 640), np.int32)
    expected[160:240, 150:250] = chair.id
    expected[20:120, 300:400] = monitor.id
    np.testing.assert_array_equal(result.labels, expected)
    assert result.latency_ms > 0 and seg.timing.inference_ms > 0


def test_yolo_classwise_nms_keeps_other_class_then_painting_drops_hidden(constant_model):
    seg = _yolo_segmenter(constant_model)
    box = Letterbox.fit(640, 480, 640, 640)
    outputs = _yolo_outputs()
    candidates = seg.decode(outputs, DecodeContext(seg.config, seg.class_map, box))
    assert sorted((c.class_info.name, round(c.score, 2)) for c in candidates) == [
        ("chair", 0.9), ("cup", 0.85), ("monitor", 0.75)]


def test_yolo_letterbox_inverse_on_smaller_image(constant_model):
    seg = _yolo_segmenter(constant_model)
    result = seg.segment(np.zeros((240, 320, 3), np.uint8))  # scale 2, 80 rows of padding on top
    by_class = {s.class_name: s for s in result.segments}
    assert by_class["chair"].box == (75, 80, 50, 40)
    # monitor: box 150..250 in x, prototype 1 positive for pixel centres left of x = 200
    assert by_class["monitor"].box == (150, 10, 50, 50)
    assert by_class["monitor"].area == 50 * 50


def test_yolo_class_map_override_and_threshold(constant_model):
    seg = _yolo_segmenter(constant_model, class_map={"person": "chair", "tv": ""}, score_threshold=0.4)
    result = seg.segment(np.zeros((480, 640, 3), np.uint8))
    names = sorted(s.class_name for s in result.segments)
    assert names == ["bottle", "chair", "chair"]  # person now a chair, tv dropped, bottle above 0.4


def test_yolo_objectness_column(constant_model):
    out = _yolo_outputs()
    pred = out["output0"][0]
    obj = np.full((1, pred.shape[1]), 0.5, np.float32)  # halves every score: A (0.45) alone passes 0.44 ...
    pred = np.concatenate([pred[:4], obj, pred[4:]], axis=0)
    cfg = OnnxModelConfig(convention="yolo_seg", score_threshold=0.44)
    cfg.yolo.objectness = True
    seg = OnnxSegmenter(cfg, model_bytes=constant_model({"output0": pred[None], "output1": out["output1"]}))
    result = seg.segment(np.zeros((480, 640, 3), np.uint8))
    assert [(s.class_name, round(s.score, 3)) for s in result.segments] == [("chair", 0.45)]  # ... C is a person


def test_yolo_shape_mismatch_is_explained(constant_model):
    cfg = OnnxModelConfig(convention="yolo_seg", class_names=["chair", "cup"])
    seg = OnnxSegmenter(cfg, model_bytes=constant_model(_yolo_outputs()))
    with pytest.raises(SegmentationError, match="class scores"):
        seg.segment(np.zeros((480, 640, 3), np.uint8))


# ----------------------------------------------------------------------------------------- detection
def _depth_scene() -> np.ndarray:
    depth = np.full((480, 640), 3.0, np.float32)
    depth[200:300, 100:250] = 1.0  # object 1
    depth[205:215, 262:271] = 1.0  # same depth, inside object 1's box but not connected to it
    depth[50:100, 400:500] = 2.0   # object 2
    depth[0:10, :] = 0.0           # invalid readings
    return depth


def _detection_outputs(box_format: str, normalized: bool) -> dict[str, np.ndarray]:
    src = np.array([[90, 190, 275, 310],    # chair around object 1 (source pixels)
                    [395, 45, 505, 105],    # dining table -> table, around object 2
                    [0, 0, 100, 100],       # person -> dropped
                    [300, 300, 400, 400]],  # cup below the threshold
                   np.float64)
    xyxy = src + np.array([0, 80, 0, 80])  # letterbox 640x480 -> 640x640 pads 80 rows on top
    if box_format == "cxcywh":
        boxes = np.c_[(xyxy[:, :2] + xyxy[:, 2:]) / 2, xyxy[:, 2:] - xyxy[:, :2]]
    elif box_format == "xywh":
        boxes = np.c_[xyxy[:, :2], xyxy[:, 2:] - xyxy[:, :2]]
    else:
        boxes = xyxy
    if normalized:
        boxes = boxes / 640.0
    classes = np.array([COCO["chair"], COCO["dining table"], COCO["person"], COCO["cup"]], np.float32)
    return {"boxes": boxes[None].astype(np.float32), "scores": np.array([[0.9, 0.8, 0.99, 0.3]], np.float32),
            "classes": classes[None]}


@pytest.mark.parametrize(("box_format", "normalized"), [("xyxy", False), ("cxcywh", True), ("xywh", False)])
def test_detection_masks_from_depth(constant_model, box_format, normalized):
    cfg = OnnxModelConfig(convention="detection")
    cfg.detection.box_format, cfg.detection.normalized = box_format, normalized
    seg = OnnxSegmenter(cfg, model_bytes=constant_model(_detection_outputs(box_format, normalized)))
    depth = _depth_scene()
    result = seg.segment(np.zeros((480, 640, 3), np.uint8), depth)
    by_class = {s.class_name: s for s in result.segments}
    assert sorted(by_class) == ["chair", "table"]
    np.testing.assert_array_equal(result.mask(by_class["chair"].id), (depth == 1.0) & _in(200, 300, 100, 250))
    np.testing.assert_array_equal(result.mask(by_class["table"].id), depth == 2.0)
    assert by_class["chair"].box == (100, 200, 150, 100)


def _in(r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
    m = np.zeros((480, 640), bool)
    m[r0:r1, c0:c1] = True
    return m


def test_detection_needs_depth(constant_model):
    seg = OnnxSegmenter(OnnxModelConfig(convention="detection"),
                        model_bytes=constant_model(_detection_outputs("xyxy", False)))
    with pytest.raises(SegmentationError, match="depth"):
        seg.segment(np.zeros((480, 640, 3), np.uint8))


# ------------------------------------------------------------------------------------------ semantic
SEM_CLASSES = ["wall-other-merged", "floor-wood", "chair", "person"]  # -> wall, floor, chair, dropped


def _semantic_segmenter(conv_model, size: int = 640, color_order: str = "RGB") -> OnnxSegmenter:
    # logit_k = 10 * channel_k - 5 for the first three classes (channels in [0, 1]); person = 0
    weights = np.array([[10, 0, 0], [0, 10, 0], [0, 0, 10], [0, 0, 0]], np.float32)
    bias = np.array([-5, -5, -5, 0], np.float32)
    cfg = OnnxModelConfig(convention="semantic", class_names=list(SEM_CLASSES))
    cfg.preprocess.input_size, cfg.preprocess.pad_value = [size, size], 0
    cfg.preprocess.color_order = color_order
    cfg.semantic.min_instance_area_px = 50
    return OnnxSegmenter(cfg, model_bytes=conv_model(weights, bias, (1, 3, size, size)))


def _semantic_image() -> np.ndarray:
    img = np.zeros((480, 640, 3), np.uint8)
    img[:200, :, 0] = 255          # wall (red)
    img[200:, :, 1] = 255          # floor (green)
    img[260:300, 100:160] = (0, 0, 255)   # chair 1 (blue)
    img[320:380, 400:480] = (0, 0, 255)   # chair 2
    img[100:140, 300:340] = 0      # person (black): no project class
    img[440:444, 20:24] = (0, 0, 255)     # 16-pixel blue speck: below min_instance_area_px
    return img


@pytest.mark.parametrize("size", [640, 320])
def test_semantic_stuff_per_class_things_by_components(conv_model, size):
    seg = _semantic_segmenter(conv_model, size)
    img = _semantic_image()
    result = seg.segment(img)
    stuff = {s.class_name: s for s in result.stuff}
    chairs = sorted(result.things, key=lambda s: s.box)
    assert sorted(stuff) == ["floor", "wall"] and all(s.instance_id == 0 for s in stuff.values())
    assert [s.box for s in chairs] == [(100, 260, 60, 40), (400, 320, 80, 60)]
    assert sorted(s.instance_id for s in chairs) == [1, 2]
    blue = (img == (0, 0, 255)).all(axis=2)
    wall = (img[:, :, 0] == 255) & ~blue
    np.testing.assert_array_equal(result.mask(stuff["wall"].id), wall)
    assert (result.labels[100:140, 300:340] == 0).all() and (result.labels[440:444, 20:24] == 0).all()
    assert all(s.score > 0.99 for s in result.segments)  # softmax of (5, -5, -5, 0)


def test_semantic_color_order_bgr_swaps_channels(conv_model):
    seg = _semantic_segmenter(conv_model, color_order="BGR")
    result = seg.segment(_semantic_image())
    # red now feeds the third logit: the top band is a (huge) chair, the blue squares are wall
    top = result.segment(int(result.labels[0, 0]))
    assert top.class_name == "chair"
    assert result.segment(int(result.labels[270, 120])).class_name == "wall"


def test_semantic_channel_count_mismatch(conv_model):
    cfg = OnnxModelConfig(convention="semantic", class_names=["chair", "cup"])
    weights, bias = np.eye(3, dtype=np.float32), np.zeros(3, np.float32)
    seg = OnnxSegmenter(cfg, model_bytes=conv_model(weights, bias, (1, 3, 640, 640)))
    with pytest.raises(SegmentationError, match="3 channels"):
        seg.segment(np.zeros((48, 64, 3), np.uint8))


# ------------------------------------------------------------------------ pre-processing, geometry
def test_make_input_normalisation_order_and_layout():
    rgb = np.zeros((2, 4, 3), np.uint8)
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 10, 20, 30
    cfg = PreprocessConfig(input_size=[4, 4], pad_value=0, color_order="BGR", scale=1.0,
                           mean=[1.0, 2.0, 3.0], std=[2.0, 2.0, 2.0], layout="NHWC")
    box = Letterbox.fit(4, 2, 4, 4)
    x = make_input(rgb, cfg, box)
    assert x.shape == (1, 4, 4, 3) and x.dtype == np.float32 and (box.pad_x, box.pad_y) == (0, 1)
    np.testing.assert_allclose(x[0, 1, 0], [(30 - 1) / 2, (20 - 2) / 2, (10 - 3) / 2])  # BGR order
    np.testing.assert_allclose(x[0, 0, 0], [-0.5, -1.0, -1.5])  # padding row: pad 0 normalised
    nchw = make_input(rgb, PreprocessConfig(input_size=[4, 4]), box)
    assert nchw.shape == (1, 3, 4, 4)
    assert nchw[0, 0, 1, 0] == pytest.approx(10 / 255) and nchw[0, 0, 0, 0] == pytest.approx(114 / 255)


def test_letterbox_geometry_and_box_pixels():
    box = Letterbox.fit(640, 480, 320, 320)
    assert (box.scale_x, box.scale_y, box.pad_x, box.pad_y) == (0.5, 0.5, 0, 40)
    np.testing.assert_allclose(box.boxes_to_source(np.array([[10.0, 50.0, 20.0, 60.0]])), [[20, 20, 40, 40]])
    assert box.content_in_grid(80, 80) == (0, 10, 80, 70)  # a quarter-resolution map
    stretch = Letterbox.fit(640, 480, 320, 320, keep_aspect=False)
    assert (stretch.scale_y, stretch.pad_y) == (320 / 480, 0)
    np.testing.assert_array_equal(box_pixels(np.array([100.0, 10.2, 200.0, 19.6]), 640, 480), [[100, 10, 200, 20]])


def test_nms_greedy_classwise():
    boxes = np.array([[0, 0, 10, 10], [1, 1, 11, 11], [0, 0, 10, 10], [50, 50, 60, 60]], np.float64)
    scores = np.array([0.9, 0.8, 0.7, 0.6])
    assert nms(boxes, scores, 0.5).tolist() == [0, 3]
    assert nms(boxes, scores, 0.5, class_ids=np.array([0, 0, 1, 0])).tolist() == [0, 2, 3]
    assert nms(boxes, scores, 0.5, max_keep=1).tolist() == [0]
    assert nms(np.zeros((0, 4)), np.zeros(0), 0.5).size == 0


# ------------------------------------------------------------------------------ configs and errors
def test_example_model_configs_load_and_run(tmp_path, constant_model, conv_model):
    for name in ("yolo_seg", "detection", "semantic", "yolox", "torchvision"):
        cfg = load_model_config(f"config/segmentation/{name}.yaml")
        assert cfg.convention == name and cfg.model.endswith(".onnx")
        assert 0.35 <= cfg.score_threshold <= 0.5  # real detectors, not the paper's 0.7
    model = tmp_path / "yolo.onnx"
    model.write_bytes(constant_model(_yolo_outputs()))
    seg = OnnxSegmenter.from_yaml("config/segmentation/yolo_seg.yaml", overrides={"model": str(model)})
    # at 0.4 the bottle (0.5) is in; the cup stays hidden behind the chair
    assert sorted(s.class_name for s in seg.segment(np.zeros((480, 640, 3), np.uint8)).segments) == [
        "bottle", "chair", "monitor"]


def test_clear_errors(tmp_path, constant_model):
    with pytest.raises(ConfigError, match="valid values"):
        OnnxModelConfig(convention="mask_rcnn")
    with pytest.raises(UnknownClassError, match="known"):
        OnnxSegmenter(OnnxModelConfig(class_map={"chair": "throne"}), model_bytes=constant_model(_yolo_outputs()))
    with pytest.raises(SegmentationError, match="does not have"):
        OnnxSegmenter(OnnxModelConfig(class_map={"throne": "chair"}), model_bytes=constant_model(_yolo_outputs()))
    with pytest.raises(SegmentationError, match="not found"):
        OnnxSegmenter(OnnxModelConfig(model=str(tmp_path / "missing.onnx")))
    with pytest.raises(SegmentationError, match="valid presets"):
        OnnxSegmenter(OnnxModelConfig(class_names="imagenet"), model_bytes=constant_model(_yolo_outputs()))
    cfg = OnnxModelConfig()
    cfg.yolo.predictions = "detections"
    with pytest.raises(SegmentationError, match=r"yolo.predictions: the model has no output 'detections'.*output0"):
        OnnxSegmenter(cfg, model_bytes=constant_model(_yolo_outputs()))  # checked when the model is loaded
    seg = OnnxSegmenter(OnnxModelConfig(), model_bytes=constant_model(_yolo_outputs()))
    with pytest.raises(SegmentationError, match="uint8"):
        seg.segment(np.zeros((48, 64, 3), np.float32))
