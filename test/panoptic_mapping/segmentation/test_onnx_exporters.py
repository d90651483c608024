"""A model file alone: tiny ONNX models laid out exactly like each exporter's, auto-detected and decoded.

Each model ignores its image and outputs constants encoding known detections (for YOLOX, raw grid
predictions at known cells and strides), at the exporters' real sizes (YOLOX 416x416 -> 1x3549x85,
YOLOv5 640 -> 1x25200x85, YOLOv8 640 -> 1x84x8400, YOLOv8-seg 1x116x8400 + 1x32x160x160, torchvision
3xHxW -> boxes/labels/scores/masks). The tests check the detected convention and that classes, boxes,
scores and masks come out exactly.
"""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from panoptic_mapping.segmentation import SegmentationError
from panoptic_mapping.segmentation.class_map import COCO91_NAMES, COCO_PANOPTIC_NAMES, COCO_THING_NAMES, ModelClassMap
from panoptic_mapping.segmentation.letterbox import Letterbox, make_input
from panoptic_mapping.segmentation.model_config import OnnxModelConfig
from panoptic_mapping.segmentation.onnx_backend import OnnxSegmenter, select_providers
from recon_core.classes import load_class_table, parse_class_table

COCO = {name: i for i, name in enumerate(COCO_THING_NAMES)}
COCO91 = {name: i for i, name in enumerate(COCO91_NAMES) if name != "N/A"}
TABLE = load_class_table()


def _rect(shape: tuple[int, int], x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
    m = np.zeros(shape, bool)
    m[y0:y1, x0:x1] = True
    return m


def _depth(shape: tuple[int, int], objects: list[tuple[tuple[int, int, int, int], float]]) -> np.ndarray:
    """3 m background with box-shaped objects (x0, y0, x1, y1) at the given depths."""
    depth = np.full(shape, 3.0, np.float32)
    for (x0, y0, x1, y1), z in objects:
        depth[y0:y1, x0:x1] = z
    return depth


def _by_class(result) -> dict:
    out: dict = {}
    for s in result.segments:
        assert s.class_name not in out, f"two {s.class_name} segments"
        out[s.class_name] = s
    return out


# ---------------------------------------------------------------------------------------------- YOLOX
YOLOX_SIZE = 416
YOLOX_LEVELS = [(s, YOLOX_SIZE // s) for s in (8, 16, 32)]  # 52x52, 26x26, 13x13 -> 3549 rows


def _yolox_row(stride: int, cx: int, cy: int) -> int:
    """Row of grid cell (cx, cy) of a level: levels in stride order, rows y-major (demo_postprocess)."""
    offset = 0
    for s, n in YOLOX_LEVELS:
        if s == stride:
            return offset + cy * n + cx
        offset += n * n
    raise ValueError(stride)


# stride, cell, raw (dx, dy, log w/s, log h/s), objectness, class, class prob, box in the 832x624 image
YOLOX_DETS = [
    (16, (10, 7), (0.5, 0.25, math.log(5), math.log(4)), 0.9, "cup", 0.8, (256, 168, 416, 296)),
    (32, (10, 1), (0.5, 0.5, math.log(2), math.log(1.5)), 0.95, "sink", 0.6, (608, 48, 736, 144)),
    (8, (5, 30), (0.5, 0.5, math.log(4), math.log(8)), 0.99, "person", 0.99, (56, 424, 120, 552)),
    (8, (40, 40), (0.5, 0.5, math.log(4), math.log(4)), 0.9, "chair", 0.3, None),  # 0.27: below 0.4
    (16, (2, 20), (0.5, 0.5, math.log(4), math.log(4)), 0.3, "chair", 1.0, None),  # 0.30: below 0.4
]
# objects inside their boxes (10 px margin) in the depth image
YOLOX_OBJECTS = [((266, 178, 406, 286), 1.0), ((618, 58, 726, 134), 1.5), ((66, 434, 110, 542), 2.0)]


def _yolox_output(decoded: bool = False, logits: bool = False) -> np.ndarray:
    rows = np.zeros((sum(n * n for _, n in YOLOX_LEVELS), 85), np.float32)
    if logits:
        rows[:, 4:] = -20.0  # sigmoid ~ 0
    for stride, (cx, cy), raw, obj, name, prob, _ in YOLOX_DETS:
        r = _yolox_row(stride, cx, cy)
        if decoded:  # --decode_in_inference: what demo_postprocess would have computed
            rows[r, :4] = ((raw[0] + cx) * stride, (raw[1] + cy) * stride, math.exp(raw[2]) * stride,
                           math.exp(raw[3]) * stride)
        else:
            rows[r, :4] = raw
        to = (lambda p: math.log(p / (1 - p))) if logits else (lambda p: p)
        rows[r, 4] = to(obj)
        rows[r, 5 + COCO[name]] = to(prob) if prob < 1 else (20.0 if logits else 1.0)
    return rows[None]


def _yolox_segmenter(export_like_model, cfg: OnnxModelConfig | None = None, dynamic: bool = False,
                     **kw) -> OnnxSegmenter:
    size: tuple[int | str, ...] = ("h", "w") if dynamic else (YOLOX_SIZE, YOLOX_SIZE)
    model = export_like_model({"output": _yolox_output(**kw)}, (1, 3, *size))
    return OnnxSegmenter(cfg or OnnxModelConfig(), model_bytes=model)


def _check_yolox(result, shape) -> None:
    by_class = _by_class(result)
    assert sorted(by_class) == ["cup", "object"]  # sink -> generic object, person ignored, two below 0.4
    cup, sink = by_class["cup"], by_class["object"]
    np.testing.assert_array_equal(result.mask(cup.id), _rect(shape, 266, 178, 406, 286))
    np.testing.assert_array_equal(result.mask(sink.id), _rect(shape, 618, 58, 726, 134))
    assert cup.score == pytest.approx(0.9 * 0.8, abs=1e-6) and sink.score == pytest.approx(0.95 * 0.6, abs=1e-6)


@pytest.mark.parametrize("decoded", [False, True])
def test_yolox_raw_grid_detected_and_decoded_exactly(export_like_model, decoded):
    seg = _yolox_segmenter(export_like_model, decoded=decoded)
    cfg = seg.config
    assert cfg.convention == "yolox" and seg.input_size == (416, 416)
    assert cfg.yolox.decoded == "auto" and cfg.class_names == list(COCO_THING_NAMES)
    shape = (624, 832)  # scale 0.5 into 416x312, at the top-left corner of the 416x416 input
    result = seg.segment(np.zeros((*shape, 3), np.uint8), _depth(shape, YOLOX_OBJECTS))
    _check_yolox(result, shape)


def test_yolox_input_is_bgr_0_255_top_left_114(export_like_model):
    seg = _yolox_segmenter(export_like_model)
    img = np.zeros((624, 832, 3), np.uint8)
    img[..., 0], img[..., 1], img[..., 2] = 10, 20, 30
    box = Letterbox.for_config(832, 624, 416, 416, seg.config.preprocess)
    assert (box.pad_x, box.pad_y, box.scale_x) == (0, 0, 0.5)
    x = make_input(img, seg.config.preprocess, box)
    assert x.shape == (1, 3, 416, 416)
    np.testing.assert_array_equal(x[0, :, 0, 0], [30, 20, 10])       # BGR, 0-255, image from the top-left
    np.testing.assert_array_equal(x[0, :, 311, 415], [30, 20, 10])   # last content row (624 * 0.5 = 312 rows)
    np.testing.assert_array_equal(x[0, :, 312, 0], [114, 114, 114])  # padding below
    # YOLOX preproc floors the resized size: 640x481 at r = 0.65 -> 416x312 (round would give 313 rows)
    odd = Letterbox.for_config(640, 481, 416, 416, seg.config.preprocess)
    assert odd.content_size == (416, 312) and (odd.pad_x, odd.pad_y) == (0, 0)


def test_yolox_logit_scores_need_apply_sigmoid(export_like_model, caplog):
    shape = (624, 832)
    depth = _depth(shape, YOLOX_OBJECTS)
    cfg = OnnxModelConfig()
    cfg.yolox.apply_sigmoid = True
    _check_yolox(_yolox_segmenter(export_like_model, cfg, logits=True).segment(
        np.zeros((*shape, 3), np.uint8), depth), shape)
    seg = _yolox_segmenter(export_like_model, logits=True)
    with caplog.at_level(logging.WARNING):
        seg.segment(np.zeros((*shape, 3), np.uint8), depth)
        seg.segment(np.zeros((*shape, 3), np.uint8), depth)
    warnings = [r for r in caplog.records if "apply_sigmoid" in r.getMessage()]
    assert len(warnings) == 1  # once per segmenter, not per frame


def test_yolox_wrong_input_size_is_explained(export_like_model):
    cfg = OnnxModelConfig(convention="yolox")
    cfg.yolox.decoded = "false"
    cfg.preprocess.input_size = [640, 640]  # the export is 416x416 (its input exported as dynamic)
    seg = _yolox_segmenter(export_like_model, cfg, dynamic=True)
    shape = (624, 832)
    with pytest.raises(SegmentationError, match="3549 predictions but a 640x640 input has 8400 grid cells"):
        seg.segment(np.zeros((*shape, 3), np.uint8), _depth(shape, YOLOX_OBJECTS))


# --------------------------------------------------------------------------------------------- YOLOv5
# class, objectness, class prob, box in the 640x480 image (80 rows of letterbox padding on top), row
V5_DETS = [
    ("chair", 0.95, 0.9, (100, 150, 220, 330), 100),
    ("chair", 0.90, 0.9, (104, 154, 224, 334), 101),   # IoU 0.9 with the first: NMS drops it
    ("laptop", 0.80, 0.7, (400, 50, 560, 150), 5000),  # no project class -> object
    ("tv", 0.60, 0.5, (300, 300, 380, 380), 17000),    # 0.30: below 0.4
    ("dog", 0.99, 0.99, (20, 20, 60, 60), 25199),      # ignored: animals move
]
V5_OBJECTS = [((110, 160, 210, 320), 1.0), ((410, 60, 550, 140), 1.2), ((25, 25, 55, 55), 2.0)]


def _v5_output() -> np.ndarray:
    rows = np.zeros((25200, 85), np.float32)
    for name, obj, prob, (x0, y0, x1, y1), r in V5_DETS:
        rows[r, :4] = ((x0 + x1) / 2, (y0 + y1) / 2 + 80, x1 - x0, y1 - y0)
        rows[r, 4], rows[r, 5 + COCO[name]] = obj, prob
    return rows[None]


def test_yolov5_decoded_boxes_with_objectness(export_like_model):
    seg = OnnxSegmenter(OnnxModelConfig(), model_bytes=export_like_model({"output0": _v5_output()}))
    assert seg.config.convention == "yolov5" and seg.config.preprocess.color_order == "RGB"
    shape = (480, 640)
    result = seg.segment(np.zeros((*shape, 3), np.uint8), _depth(shape, V5_OBJECTS))
    by_class = _by_class(result)
    assert sorted(by_class) == ["chair", "object"]
    np.testing.assert_array_equal(result.mask(by_class["chair"].id), _rect(shape, 110, 160, 210, 320))
    np.testing.assert_array_equal(result.mask(by_class["object"].id), _rect(shape, 410, 60, 550, 140))
    assert by_class["chair"].score == pytest.approx(0.95 * 0.9, abs=1e-6)
    assert by_class["object"].score == pytest.approx(0.8 * 0.7, abs=1e-6)


def test_yolov5_rows_read_as_yolox_would_be_wrong(export_like_model):
    """The convention decides the decoding: forcing `yolox` on a YOLOv5 output is caught by N."""
    cfg = OnnxModelConfig(convention="yolox")
    cfg.yolox.decoded = "false"
    seg = OnnxSegmenter(cfg, model_bytes=export_like_model({"output0": _v5_output()}))
    shape = (480, 640)
    with pytest.raises(SegmentationError, match="25200 predictions"):
        seg.segment(np.zeros((*shape, 3), np.uint8), _depth(shape, V5_OBJECTS))


# --------------------------------------------------------------------------------------------- YOLOv8
V8_DETS = [  # class, score, box in the 640x480 image, column
    ("dining table", 0.6, (50, 250, 350, 450), 7),
    ("bowl", 0.5, (400, 300, 480, 360), 4000),       # -> object
    ("cat", 0.9, (500, 20, 600, 100), 8000),         # ignored
    ("bottle", 0.3, (200, 20, 240, 100), 8399),      # below 0.4
]
V8_OBJECTS = [((60, 260, 340, 440), 0.8), ((410, 310, 470, 350), 1.1), ((510, 30, 590, 90), 2.0)]


def test_yolov8_channels_first_without_objectness(export_like_model):
    pred = np.zeros((84, 8400), np.float32)
    for name, score, (x0, y0, x1, y1), j in V8_DETS:
        pred[:4, j] = ((x0 + x1) / 2, (y0 + y1) / 2 + 80, x1 - x0, y1 - y0)
        pred[4 + COCO[name], j] = score
    meta = {"names": str(dict(enumerate(COCO_THING_NAMES))), "task": "detect", "imgsz": "[640, 640]"}
    seg = OnnxSegmenter(OnnxModelConfig(), model_bytes=export_like_model({"output0": pred[None]}, metadata=meta))
    assert seg.config.convention == "yolov8" and not seg.config.yolo.has_objectness("yolov8")
    shape = (480, 640)
    result = seg.segment(np.zeros((*shape, 3), np.uint8), _depth(shape, V8_OBJECTS))
    by_class = _by_class(result)
    assert sorted(by_class) == ["object", "table"]
    np.testing.assert_array_equal(result.mask(by_class["table"].id), _rect(shape, 60, 260, 340, 440))
    np.testing.assert_array_equal(result.mask(by_class["object"].id), _rect(shape, 410, 310, 470, 350))
    assert by_class["table"].score == pytest.approx(0.6) and by_class["object"].score == pytest.approx(0.5)
    with pytest.raises(SegmentationError, match="depth"):  # detection-only: masks come from depth
        seg.segment(np.zeros((*shape, 3), np.uint8))


# ----------------------------------------------------------------------------------------- YOLOv8-seg
def test_yolov8_seg_masks_from_prototypes(export_like_model):
    pred = np.zeros((116, 8400), np.float32)
    dets = [("chair", 0.9, (100, 100, 300, 200), 0), ("sink", 0.7, (250, 250, 450, 350), 1),
            ("person", 0.95, (0, 0, 50, 50), 0)]
    for j, (name, score, (x0, y0, x1, y1), proto) in enumerate(dets):
        pred[:4, 10 * j] = ((x0 + x1) / 2, (y0 + y1) / 2 + 80, x1 - x0, y1 - y0)
        pred[4 + COCO[name], 10 * j] = score
        pred[84 + proto, 10 * j] = 1.0
    protos = np.zeros((32, 160, 160), np.float32)
    protos[0] = 8.0
    protos[1] = np.where(np.arange(160)[None, :] < 80, 8.0, -8.0)  # positive left of input x = 320
    seg = OnnxSegmenter(OnnxModelConfig(), model_bytes=export_like_model(
        {"output0": pred[None], "output1": protos[None]}))
    assert seg.config.convention == "yolo_seg"
    shape = (480, 640)
    result = seg.segment(np.zeros((*shape, 3), np.uint8))  # no depth needed
    by_class = _by_class(result)
    assert sorted(by_class) == ["chair", "object"]
    np.testing.assert_array_equal(result.mask(by_class["chair"].id), _rect(shape, 100, 100, 300, 200))
    np.testing.assert_array_equal(result.mask(by_class["object"].id), _rect(shape, 250, 250, 320, 350))
    assert by_class["object"].score == pytest.approx(0.7)


# ---------------------------------------------------------------------------------------- torchvision
def _torchvision_model(export_like_model, with_masks: bool, shape=(480, 640)) -> tuple[bytes, np.ndarray]:
    h, w = shape
    boxes = np.array([[100, 100, 300, 260], [400, 50, 520, 150], [0, 300, 80, 470], [500, 300, 600, 400]],
                     np.float32)
    labels = np.array([COCO91["chair"], COCO91["sink"], COCO91["person"], COCO91["cup"]], np.int64)
    scores = np.array([0.9, 0.6, 0.99, 0.3], np.float32)
    masks = np.zeros((4, 1, h, w), np.float32)
    yy, xx = np.mgrid[0:h, 0:w]
    masks[0, 0] = np.where(((xx - 200) / 90.0) ** 2 + ((yy - 180) / 70.0) ** 2 <= 1.0, 0.9, 0.2)  # an ellipse
    masks[1, 0, 60:140, 410:500] = 0.7
    masks[1, 0, 60:140, 500:520] = 0.4  # below the 0.5 mask threshold
    masks[2, 0, 300:470, 0:80] = 1.0
    outputs = {"boxes": boxes, "labels": labels, "scores": scores}
    dims = {"boxes": ["N", 4], "labels": ["N"], "scores": ["N"], "masks": ["N", 1, "H", "W"]}
    if with_masks:
        outputs["masks"] = masks
    model = export_like_model(outputs, (3, "H", "W"), dims, input_name="images_tensors")
    return model, masks


def test_torchvision_mask_rcnn(export_like_model):
    model, masks = _torchvision_model(export_like_model, with_masks=True)
    seg = OnnxSegmenter(OnnxModelConfig(), model_bytes=model)
    assert seg.config.convention == "torchvision" and seg.input_size is None and not seg.batched
    assert seg.config.detection.masks == "masks"
    shape = (480, 640)
    result = seg.segment(np.zeros((*shape, 3), np.uint8))  # fed at its own size, no depth needed
    by_class = _by_class(result)
    assert sorted(by_class) == ["chair", "object"]  # COCO id 62 chair, 81 sink -> object; person, cup dropped
    np.testing.assert_array_equal(result.mask(by_class["chair"].id),
                                  (masks[0, 0] > 0.5) & _rect(shape, 100, 100, 300, 260))
    np.testing.assert_array_equal(result.mask(by_class["object"].id), _rect(shape, 410, 60, 500, 140))
    assert by_class["chair"].score == pytest.approx(0.9) and by_class["object"].score == pytest.approx(0.6)


def test_faster_rcnn_masks_from_depth(export_like_model):
    model, _ = _torchvision_model(export_like_model, with_masks=False)
    seg = OnnxSegmenter(OnnxModelConfig(), model_bytes=model)
    assert seg.config.convention == "torchvision" and not seg.config.detection.masks
    shape = (480, 640)
    depth = _depth(shape, [((120, 120, 280, 240), 1.0), ((420, 70, 500, 130), 1.3)])
    by_class = _by_class(result := seg.segment(np.zeros((*shape, 3), np.uint8), depth))
    assert sorted(by_class) == ["chair", "object"]
    np.testing.assert_array_equal(result.mask(by_class["chair"].id), _rect(shape, 120, 120, 280, 240))
    np.testing.assert_array_equal(result.mask(by_class["object"].id), _rect(shape, 420, 70, 500, 130))


def test_torchvision_label_outside_coco91_is_explained(export_like_model):
    outputs = {"boxes": np.array([[0, 0, 10, 10]], np.float32), "labels": np.array([95], np.int64),
               "scores": np.array([0.9], np.float32)}
    seg = OnnxSegmenter(OnnxModelConfig(), model_bytes=export_like_model(outputs, (3, "H", "W"),
                                                                          {"boxes": ["N", 4]}))
    with pytest.raises(SegmentationError, match=r"\[95\] are outside the model's 91 class names"):
        seg.segment(np.zeros((48, 64, 3), np.uint8), np.ones((48, 64), np.float32))


# -------------------------------------------------------------------------------- semantic, detection
def test_semantic_logits_detected(conv_model):
    weights = np.zeros((133, 3), np.float32)
    bias = np.zeros(133, np.float32)
    for name, channel in (("wall-other-merged", 0), ("floor-wood", 1), ("chair", 2)):
        k = COCO_PANOPTIC_NAMES.index(name)
        weights[k, channel], bias[k] = 10.0, -5.0
    seg = OnnxSegmenter(OnnxModelConfig(), model_bytes=conv_model(weights, bias, (1, 3, 256, 256)))
    assert seg.config.convention == "semantic" and seg.config.class_names == list(COCO_PANOPTIC_NAMES)
    img = np.zeros((240, 320, 3), np.uint8)
    img[:100, :, 0] = 255
    img[100:, :, 1] = 255
    img[130:150, 50:80] = (0, 0, 255)
    result = seg.segment(img)
    assert sorted(s.class_name for s in result.segments) == ["chair", "floor", "wall"]
    chair = next(s for s in result.segments if s.class_name == "chair")
    assert abs(chair.box[0] - 50) <= 1 and abs(chair.box[1] - 130) <= 1 and abs(chair.box[2] - 30) <= 2


def test_generic_detection_outputs_detected(export_like_model):
    outputs = {"boxes": np.array([[[100, 180, 200, 280]]], np.float32), "scores": np.array([[0.5]], np.float32),
               "classes": np.array([[COCO["chair"]]], np.float32)}
    seg = OnnxSegmenter(OnnxModelConfig(), model_bytes=export_like_model(outputs))
    assert seg.config.convention == "detection"
    shape = (480, 640)
    result = seg.segment(np.zeros((*shape, 3), np.uint8), _depth(shape, [((110, 110, 190, 190), 1.0)]))
    assert [s.class_name for s in result.segments] == ["chair"]
    np.testing.assert_array_equal(result.mask(result.segments[0].id), _rect(shape, 110, 110, 190, 190))


# ------------------------------------------------------------------------------------ classes, device
def test_fallback_class_ignore_list_and_placeholders():
    names = ["chair", "sink", "person", "N/A", "__background__", "sky-other-merged", "widget"]
    cm = ModelClassMap(names, TABLE, fallback="object", ignore=["person"])
    assert [c.name if c else None for c in cm.classes] == ["chair", "object", None, None, None, None, "object"]
    assert cm.fallback_names == ("sink", "widget")
    assert [c.name if c else None for c in ModelClassMap(names, TABLE, fallback="").classes] == [
        "chair", None, None, None, None, None, None]
    assert [c.name if c else None for c in ModelClassMap(names, TABLE, {"sink": ""}, "object").classes][:2] == [
        "chair", None]
    small = parse_class_table({"classes": [{"id": 1, "name": "chair", "category": "rigid", "is_thing": True,
                                            "movable": True, "density": 100, "coco": []}]})
    assert [c.name if c else None for c in ModelClassMap(names, small, fallback="object").classes] == [
        "chair", None, None, None, None, None, None]  # a table without `object`: unmapped classes drop


def test_custom_class_table(export_like_model):
    table = parse_class_table({"classes": [
        {"id": 5, "name": "basin", "category": "rigid", "is_thing": True, "movable": False, "density": 900,
         "coco": ["sink"]},
        {"id": 6, "name": "object", "category": "rigid", "is_thing": True, "movable": True, "density": 300,
         "coco": []}]})
    model = export_like_model({"output0": _v5_output()})
    seg = OnnxSegmenter(OnnxModelConfig(), class_table=table, model_bytes=model)
    assert seg.class_map.mapping()["sink"] == "basin" and seg.class_map.mapping()["chair"] == "object"
    shape = (480, 640)
    result = seg.segment(np.zeros((*shape, 3), np.uint8), _depth(shape, V5_OBJECTS))
    assert sorted((s.class_name, s.class_id) for s in result.segments) == [("object", 6), ("object", 6)]


def test_provider_selection():
    cpu_only = ["AzureExecutionProvider", "CPUExecutionProvider"]
    with_cuda = ["CUDAExecutionProvider", "CPUExecutionProvider"]
    assert select_providers("auto", cpu_only) == ["CPUExecutionProvider"]
    assert select_providers("auto", with_cuda) == ["CUDAExecutionProvider", "CPUExecutionProvider"]
    assert select_providers("cpu", with_cuda) == ["CPUExecutionProvider"]
    assert select_providers("cuda", with_cuda)[0] == "CUDAExecutionProvider"
    with pytest.raises(SegmentationError, match="onnxruntime-gpu"):
        select_providers("cuda", cpu_only)
    with pytest.raises(SegmentationError, match="valid values"):
        select_providers("tpu", cpu_only)


def test_cuda_falls_back_to_cpu(export_like_model, monkeypatch, caplog):
    """onnxruntime claims CUDA (as onnxruntime-gpu does without a usable GPU): the session still runs, on the CPU."""
    import onnxruntime as ort

    monkeypatch.setattr(ort, "get_available_providers",
                        lambda: ["CUDAExecutionProvider", "CPUExecutionProvider"])
    model = export_like_model({"output0": _v5_output()})
    with caplog.at_level(logging.INFO, logger="panoptic_mapping.segmentation.onnx_backend"):
        seg = OnnxSegmenter(OnnxModelConfig(), model_bytes=model)
    assert seg.provider == "CPUExecutionProvider"
    assert seg.session.get_providers() == ["CPUExecutionProvider"]
    messages = [r.getMessage() for r in caplog.records]
    assert any("could not start CUDAExecutionProvider; running on CPUExecutionProvider" in m for m in messages)
    assert any("on CPUExecutionProvider: YOLOv5 detected" in m for m in messages)
    shape = (480, 640)
    assert len(seg.segment(np.zeros((*shape, 3), np.uint8), _depth(shape, V5_OBJECTS)).segments) == 2
    monkeypatch.setattr(ort, "get_available_providers", lambda: ["CPUExecutionProvider"])
    assert OnnxSegmenter(OnnxModelConfig(), model_bytes=model).provider == "CPUExecutionProvider"
