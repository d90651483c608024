"""Fixtures for the segmentation tests: tiny ONNX models built here, synthetic and rendered frames.

No pretrained weights exist on these machines, so the model-loading code is tested on models whose
outputs are constants (known boxes, masks) or simple functions of the input (a 1x1 convolution).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

OPSET = 17
IR_VERSION = 8


def _model(nodes: list, inputs: list, outputs: list, initializers: list | None = None,
           metadata: dict[str, str] | None = None) -> bytes:
    graph = helper.make_graph(nodes, "test_model", inputs, outputs, initializer=initializers or [])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="scene_recon_tests")
    model.ir_version = IR_VERSION
    if metadata:
        helper.set_model_props(model, metadata)
    onnx.checker.check_model(model)
    return model.SerializeToString()


def make_constant_model(outputs: dict[str, np.ndarray], input_shape: tuple[int, ...] = (1, 3, 640, 640)) -> bytes:
    """A model whose named outputs are the given constants (as float32), whatever the image."""
    return make_export_like_model({k: np.asarray(v, np.float32) for k, v in outputs.items()}, input_shape)


def make_export_like_model(
    outputs: dict[str, np.ndarray],
    input_shape: Sequence[int | str] = (1, 3, 640, 640),
    output_dims: dict[str, Sequence[int | str]] | None = None,
    metadata: dict[str, str] | None = None,
    input_name: str = "images",
) -> bytes:
    """Constant outputs with the exporter's names, dtypes (int64 labels stay int64) and declared
    shapes (`output_dims` may name symbolic dimensions, as dynamic exports do), plus export metadata."""
    nodes, outs = [], []
    types = {np.dtype(np.float32): TensorProto.FLOAT, np.dtype(np.int64): TensorProto.INT64}
    for name, value in outputs.items():
        value = np.asarray(value)
        nodes.append(helper.make_node("Constant", [], [f"{name}_c"], value=numpy_helper.from_array(value)))
        nodes.append(helper.make_node("Identity", [f"{name}_c"], [name]))
        dims = list((output_dims or {}).get(name, value.shape))
        outs.append(helper.make_tensor_value_info(name, types[value.dtype], dims))
    image = helper.make_tensor_value_info(input_name, TensorProto.FLOAT, list(input_shape))
    return _model(nodes, [image], outs, metadata=metadata)


def make_conv_model(weights: np.ndarray, bias: np.ndarray, input_shape: tuple[int, ...]) -> bytes:
    """logits (1, C, h, w) = 1x1 convolution of the input channels: weights (C, 3), bias (C,)."""
    w = numpy_helper.from_array(np.asarray(weights, np.float32).reshape(-1, 3, 1, 1), "w")
    b = numpy_helper.from_array(np.asarray(bias, np.float32), "b")
    c = int(w.dims[0])
    nodes = [helper.make_node("Conv", ["images", "w", "b"], ["logits"], kernel_shape=[1, 1])]
    image = helper.make_tensor_value_info("images", TensorProto.FLOAT, list(input_shape))
    out = helper.make_tensor_value_info("logits", TensorProto.FLOAT, [1, c, input_shape[2], input_shape[3]])
    return _model(nodes, [image], [out], [w, b])


@pytest.fixture
def constant_model() -> Callable[..., bytes]:
    return make_constant_model


@pytest.fixture
def export_like_model() -> Callable[..., bytes]:
    return make_export_like_model


@pytest.fixture
def conv_model() -> Callable[..., bytes]:
    return make_conv_model


@dataclass
class RenderedFrames:
    frames: list  # RGBDFrame with extras['labels']
    scene: object  # GroundTruthScene


def render_frames(width: int, height: int, n: int, objects: int = 12, seed: int = 0) -> RenderedFrames:
    """Frames of a generated room straight from the sensor simulator (no bag written)."""
    from scene_recon.synthetic.generate import room_bounds
    from scene_recon.synthetic.scene import build_scene
    from scene_recon.synthetic.sensor import RGBDSensorSimulator, SensorConfig
    from scene_recon.synthetic.trajectory import Footprint, generate_trajectory

    scene = build_scene(objects, seed)
    things = [e for e in scene.entities if e.category != "layout"]
    poi = np.array([e.box.center for e in things])
    obstacles = [Footprint((float(e.box.center[0]), float(e.box.center[1])),
                           (float(e.box.size[0] / 2), float(e.box.size[1] / 2)), float(e.box.yaw))
                 for e in things if e.parent == "floor"]
    traj = generate_trajectory(room_bounds(scene), poi, obstacles, n, 30.0, seed)
    cfg = SensorConfig()
    f = 525.0 * width / 640
    cfg.camera.width, cfg.camera.height, cfg.camera.fx, cfg.camera.fy = width, height, f, f
    cfg.camera.cx, cfg.camera.cy = (width - 1) / 2, (height - 1) / 2
    sim = RGBDSensorSimulator(scene.render_items(seed), config=cfg)
    return RenderedFrames(list(sim.frames(traj.poses, traj.timestamps_ns, seed=seed)), scene)


@pytest.fixture(scope="session")
def small_frames() -> RenderedFrames:
    """10 frames of 160x120 from a generated room with 12 objects."""
    return render_frames(160, 120, 10)


@pytest.fixture(scope="session")
def vga_frame() -> RenderedFrames:
    """One 640x480 frame (latency measurements)."""
    return render_frames(640, 480, 1, objects=20)
