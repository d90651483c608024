"""Scaling points of the full suite beyond one room on one host: segmentation latency of an ONNX model on
onnxruntime's CPU (and CUDA, where it exists), and a projection for a multi-room building and for nodes
split across hosts over DDS, computed from measured message sizes, rates and per-room figures.

No pretrained weights exist here: the latency model is a small convolutional network built in-process
(random weights; the cost of a convolution does not depend on its weights) whose multiply-adds are
counted, so the measured throughput (GMAC/s) can be set against a real network's published size.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

#: The latency network: (out channels, stride) of its 3x3 convolutions (ReLU after each), then a 1x1
#: convolution to the class logits: a semantic head at 1/8 of the input, the `semantic` convention.
LATENCY_LAYERS = ((16, 2), (32, 2), (64, 2), (64, 1), (128, 1))
LATENCY_INPUT = 640
LATENCY_CLASSES = 133  # COCO panoptic: the class list autodetect picks for 133 channels


def latency_model(size: int = LATENCY_INPUT, classes: int = LATENCY_CLASSES, seed: int = 0) -> tuple[bytes, float]:
    """(ONNX bytes, GMACs per image) of the latency network at size x size."""
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(seed)
    nodes, inits = [], []
    prev, cin, hw, macs = "images", 3, size, 0.0
    for i, (cout, stride) in enumerate(LATENCY_LAYERS):
        w = numpy_helper.from_array((rng.standard_normal((cout, cin, 3, 3)) * 0.1).astype(np.float32), f"w{i}")
        b = numpy_helper.from_array(np.zeros(cout, np.float32), f"b{i}")
        inits += [w, b]
        nodes.append(helper.make_node("Conv", [prev, f"w{i}", f"b{i}"], [f"c{i}"], kernel_shape=[3, 3],
                                      strides=[stride, stride], pads=[1, 1, 1, 1]))
        nodes.append(helper.make_node("Relu", [f"c{i}"], [f"r{i}"]))
        hw //= stride
        macs += hw * hw * cout * cin * 9
        prev, cin = f"r{i}", cout
    w = numpy_helper.from_array((rng.standard_normal((classes, cin, 1, 1)) * 0.1).astype(np.float32), "wh")
    bias = np.zeros(classes, np.float32)
    bias[0] = 1.0  # one class dominates the random logits: segments of a plausible count, not noise
    inits += [w, numpy_helper.from_array(bias, "bh")]
    nodes.append(helper.make_node("Conv", [prev, "wh", "bh"], ["logits"], kernel_shape=[1, 1]))
    macs += hw * hw * classes * cin
    graph = helper.make_graph(nodes, "latency", [helper.make_tensor_value_info("images", TensorProto.FLOAT,
                                                                               [1, 3, size, size])],
                              [helper.make_tensor_value_info("logits", TensorProto.FLOAT, [1, classes, hw, hw])],
                              initializer=inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="scene_recon_bench")
    model.ir_version = 8
    return model.SerializeToString(), macs / 1e9


def segmentation_latency(frames: list[Any], repeats: int = 20) -> dict[str, Any]:
    """Per-frame latency of the `onnx` backend (pre-processing, network, decoding into panoptic masks) and
    of the network alone, on every execution provider of {CPU, CUDA} that onnxruntime offers here."""
    import onnxruntime as ort

    from panoptic_mapping.segmentation.config import SegmentationConfig
    from panoptic_mapping.segmentation.factory import make_segmenter

    model, gmacs = latency_model()
    available = ort.get_available_providers()
    out: dict[str, Any] = {"gmacs": round(gmacs, 3), "input": LATENCY_INPUT, "available_providers": available,
                           "threads": os.cpu_count(), "devices": {}}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "latency.onnx"
        path.write_bytes(model)
        for device, provider in (("cpu", "CPUExecutionProvider"), ("cuda", "CUDAExecutionProvider")):
            if provider not in available:
                note = f"{provider} not offered by this onnxruntime ({', '.join(available)})"
                out["devices"][device] = {"available": False, "note": note}
                continue
            cfg = SegmentationConfig(backend="onnx")
            cfg.onnx.model, cfg.onnx.device = str(path), device
            seg = make_segmenter(cfg)
            seg.segment_frame(frames[0])  # warm-up: session start, first allocation
            full, cpu = [], []
            for i in range(repeats):
                f = frames[i % len(frames)]
                c0, t0 = time.process_time(), time.perf_counter()
                seg.segment_frame(f)
                full.append((time.perf_counter() - t0) * 1000)
                cpu.append((time.process_time() - c0) * 1000)
            sess = ort.InferenceSession(str(path), providers=[provider])
            x = np.zeros((1, 3, LATENCY_INPUT, LATENCY_INPUT), np.float32)
            sess.run(None, {"images": x})
            net = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                sess.run(None, {"images": x})
                net.append((time.perf_counter() - t0) * 1000)
            med_net = float(np.median(net))
            out["devices"][device] = {"available": True, "frame_ms_median": round(float(np.median(full)), 2),
                                      "frame_cpu_ms_median": round(float(np.median(cpu)), 2),
                                      "network_ms_median": round(med_net, 2),
                                      "gmac_per_s": round(gmacs / (med_net / 1000), 2)}
    return out


def message_sizes(map_dir: Path | None, urdf: Path | None) -> dict[str, Any]:
    """Serialized sizes (bytes) of the graph's messages, measured by `python -m ros_nodes.message_sizes` in a
    child process (the nodes' own conversions); an error text when it cannot run."""
    cmd = [sys.executable, "-m", "ros_nodes.message_sizes"]
    if map_dir is not None:
        cmd += ["--map", str(map_dir)]
    if urdf is not None:
        cmd += ["--urdf", str(urdf)]
    try:
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return {"error": str(exc)}
    if res.returncode != 0:
        return {"error": (res.stderr or res.stdout).strip().splitlines()[-1:] or ["failed"]}
    return json.loads(res.stdout.strip().splitlines()[-1])


def dds_projection(sizes: dict[str, Any], room: dict[str, Any], rooms: tuple[int, ...] = (1, 5, 20),
                   camera_hz: float = 30.0, entity_period_s: float = 2.0) -> dict[str, Any]:
    """The computed table: per link between hosts, bytes/s from the measured message sizes and rates; per
    building size, what grows with the number of rooms (from one measured room, linear in the rooms).

    `room`: measured figures of one room: `map_mb`, `objects`, `replace_s` (stage 4), `segmentation_hz`
    (segmentation calls per second of recording), `urdf_updates` (URDF messages per replacement)."""
    mb = 1e6
    seg_hz = float(room["segmentation_hz"])
    links = [
        ("camera -> mapper (color + depth, every frame)", (sizes["color"] + sizes["depth"]) * camera_hz,
         f"{camera_hz:.0f} Hz x ({sizes['color'] / mb:.2f} + {sizes['depth'] / mb:.2f}) MB"),
        ("mapper <-> segmentation (color + depth out, labels back, per segmented frame)",
         (sizes["color"] + sizes["depth"] + sizes["labels"]) * seg_hz,
         f"{seg_hz:.1f} Hz x ({sizes['color'] / mb:.2f} + {sizes['depth'] / mb:.2f} + {sizes['labels'] / mb:.2f}) MB"),
        ("mapper -> contact graph / replacer (entity array with meshes)",
         sizes["entities_with_meshes"] / entity_period_s,
         f"{sizes['entities_with_meshes'] / mb:.2f} MB every {entity_period_s:.0f} s ({sizes['entities']} entities)"),
        ("replacer -> planners (URDF)", sizes["urdf"] * room["urdf_updates"] / max(room["replace_s"], 1e-3),
         f"{sizes['urdf'] / 1e3:.1f} kB per update"),
    ]
    link_rows = [{"link": name, "MB_per_s": round(bps / mb, 3), "Mbit_per_s": round(8 * bps / mb, 1), "basis": basis}
                 for name, bps, basis in links]
    building = []
    for n in rooms:
        ent_mb = n * sizes["entities_with_meshes"] / mb
        building.append({"rooms": n, "map_memory_mb": round(n * room["map_mb"], 1),
                         "objects": n * room["objects"],
                         "entity_array_mb": round(ent_mb, 2),
                         "entity_stream_mbit_s": round(8 * ent_mb / entity_period_s, 1),
                         "entity_array_ms_at_1gbit": round(1000 * 8 * ent_mb / 1000, 1),
                         "stage4_full_s": round(n * room["replace_s"], 1),
                         "urdf_kb": round(n * sizes["urdf"] / 1e3, 1)})
    return {"links": link_rows, "building": building}


__all__ = ["dds_projection", "latency_model", "message_sizes", "segmentation_latency"]
