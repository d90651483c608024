"""`onnx` backend: any exported detection/segmentation model, run with onnxruntime.

The model and how to read it are described by a model config (`model_config.py`), whose `auto`
values are read off the graph when the model is loaded (`autodetect.py`); this module runs the
session and hands the outputs to the decoder of the convention. onnxruntime runs on the GPU when
it offers the CUDA provider (the `onnxruntime-gpu` package on a machine with CUDA), else on the CPU.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from panoptic_mapping.segmentation.autodetect import ModelSignature, resolve_model
from panoptic_mapping.segmentation.base import PanopticSegmenter
from panoptic_mapping.segmentation.class_map import ModelClassMap
from panoptic_mapping.segmentation.decode_common import DecodeContext
from panoptic_mapping.segmentation.decode_detection import decode_detection
from panoptic_mapping.segmentation.decode_semantic import decode_semantic
from panoptic_mapping.segmentation.decode_yolo import decode_yolo_seg
from panoptic_mapping.segmentation.decode_yolo_det import decode_yolo_detection
from panoptic_mapping.segmentation.letterbox import Letterbox, make_input
from panoptic_mapping.segmentation.model_config import OnnxModelConfig, load_model_config
from panoptic_mapping.segmentation.panoptic import assemble
from panoptic_mapping.segmentation.types import PanopticSegmentation, SegmentationError, SegmentCandidate
from recon_core.classes import ClassTable, load_class_table
from recon_core.frame import RGBDFrame

_log = logging.getLogger(__name__)

CPU_PROVIDER = "CPUExecutionProvider"
CUDA_PROVIDER = "CUDAExecutionProvider"
#: `device` values: `auto` (CUDA when onnxruntime offers it, else CPU), `cpu`, `cuda` (fail without it).
DEVICES: tuple[str, ...] = ("auto", "cpu", "cuda")


def select_providers(device: str = "auto", available: Sequence[str] | None = None) -> list[str]:
    """onnxruntime execution providers for `device`, best first; `available` defaults to
    `onnxruntime.get_available_providers()`."""
    if device not in DEVICES:
        raise SegmentationError(f"unknown onnx device {device!r}; valid values: {list(DEVICES)}")
    if available is None:
        import onnxruntime as ort

        available = ort.get_available_providers()
    if device != "cpu" and CUDA_PROVIDER in available:
        return [CUDA_PROVIDER, CPU_PROVIDER]
    if device == "cuda":
        raise SegmentationError(
            f"onnx device 'cuda': onnxruntime offers no {CUDA_PROVIDER} (available: {list(available)}); install "
            "onnxruntime-gpu matching the CUDA version, or use device 'auto'"
        )
    return [CPU_PROVIDER]


@dataclass
class OnnxTiming:
    """Where the time of the last call went (ms): the decode share is this project's overhead."""

    preprocess_ms: float = 0.0
    inference_ms: float = 0.0
    decode_ms: float = 0.0


class OnnxSegmenter(PanopticSegmenter):
    """Runs an ONNX model and decodes its outputs into a panoptic segmentation."""

    name = "onnx"

    def __init__(
        self,
        config: OnnxModelConfig,
        class_table: ClassTable | None = None,
        threads: int = 0,
        model_bytes: bytes | None = None,
        device: str = "auto",
    ) -> None:
        """model_bytes: a serialised model to use instead of the file `config.model` (tests, embedding).

        `config` may leave the convention, the pre-processing and the class names to `auto`:
        `self.config` is the resolved copy, `self.description` says what was detected.
        """
        import onnxruntime as ort

        table = class_table or load_class_table()
        options = ort.SessionOptions()
        if threads > 0:
            options.intra_op_num_threads = threads
        source: Any = model_bytes
        if source is None:
            path = Path(config.model)
            if not config.model or not path.is_file():
                raise SegmentationError(
                    f"ONNX model file {config.model!r} not found; set `model` in the model config "
                    "(no weights ship with the project: export your own model)"
                )
            source = str(path)
        providers = select_providers(device)
        try:
            self.session = ort.InferenceSession(source, sess_options=options, providers=providers)
        except Exception as exc:  # onnxruntime raises its own exception types for bad files
            raise SegmentationError(f"cannot load ONNX model {config.model or '<bytes>'}: {exc}") from exc
        #: The provider the session runs on (onnxruntime falls back to the CPU when CUDA fails to load).
        self.provider: str = self.session.get_providers()[0]
        if providers[0] != self.provider:
            _log.warning("onnxruntime could not start %s; running on %s", providers[0], self.provider)
        inp = self.session.get_inputs()[0]
        self.input_name = inp.name
        self.output_names = [o.name for o in self.session.get_outputs()]
        self._layout = config.preprocess.layout
        resolved = resolve_model(config, ModelSignature.from_session(self.session), probe=self._probe)
        self.config = resolved.config
        self.input_size = resolved.input_size
        self.batched = resolved.batched
        self.description = resolved.description
        cfg = self.config
        self.class_map = ModelClassMap(cfg.class_names, table, cfg.class_map, cfg.fallback_class,
                                       cfg.ignore_classes)
        if not self.class_map.kept.any():
            raise SegmentationError(
                f"none of the model's classes maps onto a project class; add a class_map (project classes: "
                f"{list(table.names)})"
            )
        self._warned: set[str] = set()
        self.timing = OnnxTiming()
        _log.info("ONNX model %s on %s: %s; %s", Path(config.model).name if config.model else "<bytes>",
                  self.provider, self.description, self.class_map.describe())

    @classmethod
    def from_yaml(cls, path: str | Path, overrides: dict[str, Any] | None = None, threads: int = 0,
                  class_table: ClassTable | None = None, device: str = "auto") -> OnnxSegmenter:
        return cls(load_model_config(path, overrides), class_table, threads, device=device)

    def _probe(self, size: tuple[int, int]) -> ModelSignature:
        """Output shapes of one run on a blank (width, height) image, for graphs that leave them symbolic."""
        w, h = size
        shape: tuple[int, ...] = (h, w, 3) if self._layout == "NHWC" else (3, h, w)
        if len(self.session.get_inputs()[0].shape or []) != 3:
            shape = (1, *shape)
        try:
            arrays = self.session.run(None, {self.input_name: np.zeros(shape, np.float32)})
        except Exception as exc:
            raise SegmentationError(
                f"the model's output shapes are dynamic and a trial run at {w}x{h} failed ({exc}); set "
                "`convention` and preprocess.input_size in a model config"
            ) from exc
        return ModelSignature.from_session(self.session).with_output_shapes(arrays)

    def _segment(
        self, color: np.ndarray, depth: np.ndarray | None, frame: RGBDFrame | None
    ) -> PanopticSegmentation:
        t0 = time.perf_counter()
        h, w = color.shape[:2]
        pre = self.config.preprocess
        size = self.input_size or (w, h)
        box = Letterbox.for_config(w, h, size[0], size[1], pre)
        tensor = make_input(color, pre, box)
        if not self.batched:
            tensor = tensor[0]
        t1 = time.perf_counter()
        outputs = dict(zip(self.output_names, self.session.run(None, {self.input_name: tensor}), strict=True))
        t2 = time.perf_counter()
        ctx = DecodeContext(self.config, self.class_map, box, depth, self._warned)
        result = assemble((h, w), self.decode(outputs, ctx), self.config.paint)
        t3 = time.perf_counter()
        self.timing = OnnxTiming((t1 - t0) * 1e3, (t2 - t1) * 1e3, (t3 - t2) * 1e3)
        return result

    def decode(self, outputs: dict[str, np.ndarray], ctx: DecodeContext) -> list[SegmentCandidate]:
        """Raw session outputs (by name) -> candidates, per the (resolved) convention."""
        conv = self.config.convention
        if conv == "yolo_seg":
            y = self.config.yolo
            return decode_yolo_seg(self._output(outputs, y.predictions, 0, "yolo.predictions"),
                                   self._output(outputs, y.prototypes, 1, "yolo.prototypes"), ctx)
        if conv in ("yolov5", "yolov8"):
            return decode_yolo_detection(self._output(outputs, self.config.yolo.predictions, 0, "yolo.predictions"),
                                         ctx)
        if conv == "yolox":
            return decode_yolo_detection(self._output(outputs, self.config.yolox.predictions, 0,
                                                      "yolox.predictions"), ctx)
        if conv in ("detection", "torchvision"):
            d = self.config.detection
            order = (0, 2, 1) if conv == "torchvision" else (0, 1, 2)  # torchvision: boxes, labels, scores
            masks = self._output(outputs, d.masks, -1, "detection.masks") if d.masks else None
            return decode_detection(self._output(outputs, d.boxes, order[0], "detection.boxes"),
                                    self._output(outputs, d.scores, order[1], "detection.scores"),
                                    self._output(outputs, d.classes, order[2], "detection.classes"), ctx, masks)
        return decode_semantic(self._output(outputs, self.config.semantic.logits, 0, "semantic.logits"), ctx)

    def _output(self, outputs: dict[str, np.ndarray], name: str, position: int, key: str) -> np.ndarray:
        if name:
            if name not in outputs:
                raise SegmentationError(f"{key}: the model has no output {name!r}; its outputs: {self.output_names}")
            return outputs[name]
        if not 0 <= position < len(self.output_names):
            raise SegmentationError(
                f"{key}: the model has only {len(self.output_names)} output(s) {self.output_names}; "
                f"the {self.config.convention} convention needs more"
            )
        return outputs[self.output_names[position]]

