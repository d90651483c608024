"""`scene-recon map`: which segmenter `auto` picks, and a run with only an ONNX model file and a class table."""

from __future__ import annotations

import argparse
import json

import numpy as np
import onnx
import yaml
from onnx import TensorProto, helper, numpy_helper

from panoptic_mapping.dataio import CameraIntrinsics
from panoptic_mapping.dataio.bag_writer import RGBDBagWriter
from panoptic_mapping.segmentation.class_map import COCO_THING_NAMES
from scene_recon.cli import main
from scene_recon.commands.map_cmd import choose_segmenter


def _bag(tmp_path, n=4):
    """A box 0.5 m in front of a wall 1.5 m away, seen from a still camera."""
    intr = CameraIntrinsics(100, 100, 31.5, 23.5, 64, 48)
    depth = np.full((48, 64), 1.5, np.float32)
    depth[12:36, 20:44] = 1.0
    path = tmp_path / "rec"
    with RGBDBagWriter(path, storage="db3") as w:
        for i in range(n):
            w.write_frame(10**9 + i * 100_000_000, np.zeros((48, 64, 3), np.uint8), depth, intr, np.eye(4))
    return path


def _yolov8_model(path):
    """An ultralytics-shaped YOLOv8 detection export at 96x96 (1, 84, 189): one sink in the middle."""
    pred = np.zeros((1, 84, 144 + 36 + 9), np.float32)
    pred[0, :4, 0] = (48, 48, 42, 42)  # input box 27..69: source 18..46 x 10..38 (scale 1.5, 12 rows padding)
    pred[0, 4 + COCO_THING_NAMES.index("sink"), 0] = 0.9
    nodes = [helper.make_node("Constant", [], ["c"], value=numpy_helper.from_array(pred)),
             helper.make_node("Identity", ["c"], ["output0"])]
    graph = helper.make_graph(nodes, "yolov8", [helper.make_tensor_value_info("images", TensorProto.FLOAT,
                                                                               [1, 3, 96, 96])],
                              [helper.make_tensor_value_info("output0", TensorProto.FLOAT, list(pred.shape))])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.save(model, path)


def _ns(source, **kw) -> argparse.Namespace:
    base = {"segmenter": "auto", "model": None, "model_config": None, "ground_truth": None}
    return argparse.Namespace(source=str(source), **{**base, **kw})


def test_auto_picks_the_oracle_only_with_ground_truth(tmp_path):
    bag = tmp_path / "rec"
    bag.mkdir()
    assert choose_segmenter(_ns(bag))[0] == "none"  # a real recording: no oracle
    assert choose_segmenter(_ns(bag, model="m.onnx"))[0] == "onnx"
    assert choose_segmenter(_ns(bag, model_config="m.yaml"))[0] == "onnx"
    assert choose_segmenter(_ns(bag, ground_truth="gt"))[0] == "oracle"
    assert choose_segmenter(_ns(bag, segmenter="none", model="m.onnx"))[0] == "none"
    gt = tmp_path / "rec_groundtruth"
    gt.mkdir()
    (gt / "scene.json").write_text("{}")
    assert choose_segmenter(_ns(bag)) == ("oracle", "the recording has ground truth beside it")
    assert choose_segmenter(_ns(bag, model="m.onnx"))[0] == "onnx"  # a model beats the oracle


def test_map_with_only_a_model_file_and_a_class_table(tmp_path, capsys):
    bag = _bag(tmp_path)
    model = tmp_path / "yolov8n.onnx"
    _yolov8_model(model)
    table = tmp_path / "classes.yaml"
    table.write_text(yaml.safe_dump({"classes": [
        {"id": 1, "name": "floor", "category": "layout", "is_thing": False, "movable": False, "density": None,
         "coco": []},
        {"id": 7, "name": "basin", "category": "rigid", "is_thing": True, "movable": False, "density": 900,
         "coco": ["sink"]}]}))
    out = tmp_path / "map"
    assert main(["map", str(bag), "--out", str(out), "--model", str(model), "--classes", str(table),
                 "--no-keyframes"]) == 0
    printed = capsys.readouterr().out
    assert "segmenter: onnx (a model was given)" in printed
    assert "YOLOv8/11 detection detected" in printed and "CPUExecutionProvider" in printed
    summary = json.loads((out / "summary.json").read_text())
    assert summary["segmenter"] == "onnx" and summary["model"] == str(model) and "noise" not in summary
    # every frame read is segmented (--no-keyframes) except what a still camera adds nothing with: the
    # recording's 4 views are from one place, the 4th is skipped whole (static.min_views = 3)
    assert summary["run"]["segmentation_calls"] == 3 and summary["run"]["static_frames"] == 1
    entities = json.loads((out / "entities.json").read_text())
    names = {e["class_name"] for e in (entities["entities"] if isinstance(entities, dict) else entities)}
    assert "basin" in names  # the custom table's class for a COCO sink


def test_map_auto_without_ground_truth_maps_geometry_only(tmp_path, capsys):
    bag = _bag(tmp_path)
    assert main(["map", str(bag), "--out", str(tmp_path / "map")]) == 0
    assert "segmenter: none (no model and no ground truth: geometry only)" in capsys.readouterr().out
