"""Output convention, pre-processing and classes read off a model's graph (`autodetect.py`).

Signatures here have the exact names, ranks and shapes the exporters write (YOLOX tools/export_onnx.py,
YOLOv5 export.py, ultralytics YOLOv8/11 and -seg, torchvision Mask/Faster R-CNN); no model is run.
"""

from __future__ import annotations

import pytest

from panoptic_mapping.segmentation import SegmentationError
from panoptic_mapping.segmentation.autodetect import (
    ModelSignature,
    TensorInfo,
    grid_cells,
    metadata_names,
    resolve_model,
)
from panoptic_mapping.segmentation.class_map import COCO91_NAMES, COCO_PANOPTIC_NAMES, COCO_THING_NAMES
from panoptic_mapping.segmentation.model_config import IMAGENET_MEAN, OnnxModelConfig


def _sig(inputs, *outputs, metadata=None) -> ModelSignature:
    return ModelSignature(tuple(TensorInfo(*i) for i in inputs), tuple(TensorInfo(*o) for o in outputs),
                          metadata or {})


def _yolo_sig(out_shape, size=(640, 640), name="output0", metadata=None) -> ModelSignature:
    w, h = size
    return _sig([("images", (1, 3, h, w))], (name, out_shape), metadata=metadata)


def test_grid_cells_match_the_exports():
    assert grid_cells(640, 640, (8, 16, 32)) == 8400      # YOLOv8 / YOLOX-S at 640
    assert grid_cells(416, 416, (8, 16, 32)) == 3549      # YOLOX-Nano/Tiny at 416
    assert 3 * grid_cells(640, 640, (8, 16, 32)) == 25200  # YOLOv5 at 640: 3 anchors per location


@pytest.mark.parametrize(("shape", "size", "convention"), [
    ((1, 3549, 85), (416, 416), "yolox"),     # YOLOX nano/tiny, raw grid
    ((1, 8400, 85), (640, 640), "yolox"),     # YOLOX-S..X
    ((1, 25200, 85), (640, 640), "yolov5"),   # YOLOv5 s..x at 640
    ((1, 10647, 85), (416, 416), "yolov5"),   # YOLOv5 at 416: 85 columns like YOLOX, N tells them apart
    ((1, 84, 8400), (640, 640), "yolov8"),    # YOLOv8 / YOLO11 detection
    ((1, 84, 3549), (416, 416), "yolov8"),
    ((1, 102000, 85), (1280, 1280), "yolov5"),  # YOLOv5-P6 (strides 8..64) at 1280
])
def test_yolo_family_told_apart_by_prediction_count(shape, size, convention):
    r = resolve_model(OnnxModelConfig(), _yolo_sig(shape, size))
    cfg = r.config
    assert r.detected and cfg.convention == convention
    assert cfg.class_names == list(COCO_THING_NAMES)
    assert r.input_size == size and r.batched
    if convention == "yolox":
        p = cfg.preprocess
        assert (p.color_order, p.scale, p.pad_position, p.pad_value) == ("BGR", 1.0, "top_left", 114)
        assert cfg.yolox.predictions == "output0" and cfg.yolox.strides == [8, 16, 32]
    else:
        p = cfg.preprocess
        assert (p.color_order, p.scale, p.pad_position, p.pad_value) == ("RGB", 1 / 255, "center", 114)
        assert cfg.yolo.predictions == "output0"
        assert cfg.yolo.has_objectness(convention) == (convention == "yolov5")
    title = {"yolox": "YOLOX ", "yolov5": "YOLOv5 ", "yolov8": "YOLOv8/11 detection "}[convention]
    assert r.description.startswith(title + "detected") and "masks from depth" in r.description
    reason = {"yolox": "(1, N, 5+nc) with N = ", "yolov5": "(1, N, 5+nc) with N = 3 anchors x ",
              "yolov8": "(1, 4+nc, N) with N = "}[convention]
    assert reason in r.description and "matches no YOLO grid" not in r.description  # matched, not guessed


def test_yolo_seg_and_yolov5_seg():
    seg = _sig([("images", (1, 3, 640, 640))], ("output0", (1, 116, 8400)), ("output1", (1, 32, 160, 160)))
    r = resolve_model(OnnxModelConfig(), seg)
    assert r.config.convention == "yolo_seg" and r.config.yolo.objectness is False
    assert (r.config.yolo.predictions, r.config.yolo.prototypes) == ("output0", "output1")
    assert r.config.class_names == list(COCO_THING_NAMES)
    v5 = _sig([("images", (1, 3, 640, 640))], ("output0", (1, 25200, 117)), ("output1", (1, 32, 160, 160)))
    r = resolve_model(OnnxModelConfig(), v5)
    assert r.config.convention == "yolo_seg" and r.config.yolo.objectness is True  # 4 + 1 + 80 + 32 = 117
    assert len(r.config.class_names) == 80
    # prototypes first in the graph: bound by rank, not position
    swapped = _sig([("images", (1, 3, 640, 640))], ("protos", (1, 32, 160, 160)), ("preds", (1, 116, 8400)))
    r = resolve_model(OnnxModelConfig(), swapped)
    assert (r.config.yolo.predictions, r.config.yolo.prototypes) == ("preds", "protos")


@pytest.mark.parametrize("named", [True, False])
@pytest.mark.parametrize("with_masks", [True, False])
def test_torchvision_mask_and_faster_rcnn(named, with_masks):
    names = ["boxes", "labels", "scores", "masks"] if named else ["3210", "3211", "3212", "3213"]
    outs = [(names[0], (None, 4)), (names[1], (None,), "int64"), (names[2], (None,))]
    if with_masks:
        outs.append((names[3], (None, 1, None, None)))
    r = resolve_model(OnnxModelConfig(), _sig([("images_tensors", (3, None, None))], *outs))
    cfg = r.config
    assert cfg.convention == "torchvision" and r.input_size is None and not r.batched  # fed at the image's size
    d = cfg.detection
    assert (d.boxes, d.classes, d.scores) == (names[0], names[1], names[2])
    assert d.masks == (names[3] if with_masks else "")
    assert cfg.class_names == list(COCO91_NAMES) and cfg.class_names[62] == "chair"
    p = cfg.preprocess
    assert (p.color_order, p.scale, p.mean, p.std) == ("RGB", 1 / 255, [0.0] * 3, [1.0] * 3)
    assert ("masks from depth" in r.description) == (not with_masks)


def test_torchvision_static_input_keeps_its_size():
    sig = _sig([("images", (3, 480, 640))], ("boxes", (None, 4)), ("labels", (None,), "int64"), ("scores", (None,)))
    r = resolve_model(OnnxModelConfig(), sig)
    assert r.input_size == (640, 480) and r.config.preprocess.pad_position == "top_left"


def test_generic_detection_and_semantic():
    det = _sig([("images", (1, 3, 640, 640))], ("boxes", (1, 100, 4)), ("scores", (1, 100)),
               ("classes", (1, 100)))
    r = resolve_model(OnnxModelConfig(), det)
    assert r.config.convention == "detection" and r.config.class_names == list(COCO_THING_NAMES)
    assert (r.config.detection.boxes, r.config.detection.scores, r.config.detection.classes) == (
        "boxes", "scores", "classes")
    sem = _sig([("input", (1, 3, 512, 512))], ("logits", (1, 133, 128, 128)))
    r = resolve_model(OnnxModelConfig(), sem)
    assert r.config.convention == "semantic" and r.config.class_names == list(COCO_PANOPTIC_NAMES)
    assert r.config.preprocess.mean == list(IMAGENET_MEAN) and r.input_size == (512, 512)
    with pytest.raises(SegmentationError, match="21 classes"):  # e.g. VOC: the names must be given
        resolve_model(OnnxModelConfig(), _sig([("input", (1, 3, 512, 512))], ("out", (1, 21, 512, 512))))


def test_ultralytics_metadata_names_size_and_dynamic_shapes():
    meta = {"names": "{0: 'cup', 1: 'sink'}", "imgsz": "[480, 640]", "task": "detect", "stride": "32"}
    sig = _sig([("images", (1, 3, None, None))], ("output0", (1, 6, None)), metadata=meta)
    probed = []

    def probe(size):
        probed.append(size)
        return _sig([("images", (1, 3, None, None))], ("output0", (1, 6, grid_cells(*size, (8, 16, 32)))),
                    metadata=meta)

    r = resolve_model(OnnxModelConfig(), sig, probe)
    assert probed == [(640, 480)]  # the export size (imgsz is [h, w])
    assert r.config.convention == "yolov8" and r.config.class_names == ["cup", "sink"]
    assert r.input_size == (640, 480)
    assert metadata_names({"names": "['a', 'b']"}) == ("a", "b")
    assert metadata_names({"names": "{1: 'a'}"}) is None and metadata_names({"names": "not python"}) is None


def test_explicit_values_win():
    sig = _yolo_sig((1, 8400, 85))
    cfg = OnnxModelConfig(convention="yolov5", class_names=[f"c{i}" for i in range(80)])
    cfg.preprocess.color_order = "BGR"
    cfg.preprocess.input_size = [640, 640]
    r = resolve_model(cfg, sig)
    assert not r.detected and r.config.convention == "yolov5"
    assert r.config.preprocess.color_order == "BGR" and r.config.preprocess.pad_position == "center"
    assert r.config.class_names[0] == "c0"
    assert cfg.convention == "yolov5" and cfg.preprocess.scale is None  # the caller's config is not modified
    # A YOLOX export at another size than the graph says is still told apart by the configured size.
    cfg = OnnxModelConfig()
    cfg.preprocess.input_size = [416, 416]
    assert resolve_model(cfg, _sig([("images", (1, 3, None, None))], ("output", (1, 3549, 85)))).config.convention \
        == "yolox"


def test_a_dynamic_yolo_export_without_metadata_defaults_to_640():
    sig = _sig([("images", (1, 3, None, None))], ("output0", (1, 25200, 85)))
    r = resolve_model(OnnxModelConfig(), sig)
    assert r.config.convention == "yolov5" and r.input_size == (640, 640)


def test_unreadable_graphs_are_explained():
    odd = _sig([("x", (1, 3, 64, 64))], ("a", (1, 10)), ("b", (1, 10)))
    with pytest.raises(SegmentationError, match=r"cannot tell the output convention.*'a' 1x10.*set\s+`convention`"):
        resolve_model(OnnxModelConfig(), odd)
    dynamic = _sig([("x", (1, 3, 640, 640))], ("out", (1, None, None)))
    with pytest.raises(SegmentationError, match="dynamic dimensions"):
        resolve_model(OnnxModelConfig(), dynamic)  # no probe to measure them
    r = resolve_model(OnnxModelConfig(), _sig([("x", (1, 3, None, None))], ("logits", (1, 133, None, None))))
    assert r.input_size == (640, 640) and "dynamic input: fed at 640x640" in r.description  # said, not silent
    with pytest.raises(SegmentationError, match="no output 'detections'"):
        cfg = OnnxModelConfig()
        cfg.yolox.predictions = "detections"
        resolve_model(cfg, _yolo_sig((1, 8400, 85)))
