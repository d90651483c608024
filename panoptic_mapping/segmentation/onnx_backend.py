"""`onnx` backend: any exported segmentation/detection model, run with onnxruntime on the CPU.

The model and how to read it are described by a model config (`model_config.py`); this module only
runs the session and hands the outputs to the decoder of the configured convention.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from panoptic_mapping.segmentation.base import PanopticSegmenter
from panoptic_mapping.segmentation.class_map import ModelClassMap, resolve_class_names
from panoptic_mapping.segmentation.decode_common import DecodeContext
from panoptic_mapping.segmentation.decode_detection import decode_detection
from panoptic_mapping.segmentation.decode_semantic import decode_semantic
from panoptic_mapping.segmentation.decode_yolo import decode_yolo_seg
from panoptic_mapping.segmentation.letterbox import Letterbox, input_size, make_input
from panoptic_mapping.segmentation.model_config import OnnxModelConfig, load_model_config
from panoptic_mapping.segmentation.panoptic import assemble
from panoptic_mapping.segmentation.types import PanopticSegmentation, SegmentationError, SegmentCandidate
from recon_core.classes import ClassTable, load_class_table
from recon_core.frame import RGBDFrame

#: Only the CPU provider: these machines have no GPU, and results must not depend on one.
PROVIDERS = ("CPUExecutionProvider",)


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
    ) -> None:
        """model_bytes: a serialised model to use instead of the file `config.model` (tests, embedding)."""
        import onnxruntime as ort

        self.config = config
        table = class_table or load_class_table()
        self.class_map = ModelClassMap(resolve_class_names(config.class_names), table, config.class_map)
        if not self.class_map.kept.any():
            raise SegmentationError(
                f"none of the model's classes maps onto a project class; add a class_map (project classes: "
                f"{list(table.names)})"
            )
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
        try:
            self.session = ort.InferenceSession(source, sess_options=options, providers=list(PROVIDERS))
        except Exception as exc:  # onnxruntime raises its own exception types for bad files
            raise SegmentationError(f"cannot load ONNX model {config.model or '<bytes>'}: {exc}") from exc
        inp = self.session.get_inputs()[0]
        self.input_name = inp.name
        self.input_size = input_size(config.preprocess, inp.shape)
        self.output_names = [o.name for o in self.session.get_outputs()]
        self.timing = OnnxTiming()

    @classmethod
    def from_yaml(cls, path: str | Path, overrides: dict[str, Any] | None = None, threads: int = 0,
                  class_table: ClassTable | None = None) -> OnnxSegmenter:
        return cls(load_model_config(path, overrides), class_table, threads)

    def _segment(
        self, color: np.ndarray, depth: np.ndarray | None, frame: RGBDFrame | None
    ) -> PanopticSegmentation:
        t0 = time.perf_counter()
        h, w = color.shape[:2]
        pre = self.config.preprocess
        box = Letterbox.fit(w, h, *self.input_size, keep_aspect=pre.letterbox)
        tensor = make_input(color, pre, box)
        t1 = time.perf_counter()
        outputs = dict(zip(self.output_names, self.session.run(None, {self.input_name: tensor}), strict=True))
        t2 = time.perf_counter()
        ctx = DecodeContext(self.config, self.class_map, box, depth)
        result = assemble((h, w), self.decode(outputs, ctx), self.config.paint)
        t3 = time.perf_counter()
        self.timing = OnnxTiming((t1 - t0) * 1e3, (t2 - t1) * 1e3, (t3 - t2) * 1e3)
        return result

    def decode(self, outputs: dict[str, np.ndarray], ctx: DecodeContext) -> list[SegmentCandidate]:
        """Raw session outputs (by name) -> candidates, per the configured convention."""
        conv = self.config.convention
        if conv == "yolo_seg":
            y = self.config.yolo
            return decode_yolo_seg(self._output(outputs, y.predictions, 0, "yolo.predictions"),
                                   self._output(outputs, y.prototypes, 1, "yolo.prototypes"), ctx)
        if conv == "detection":
            d = self.config.detection
            return decode_detection(self._output(outputs, d.boxes, 0, "detection.boxes"),
                                    self._output(outputs, d.scores, 1, "detection.scores"),
                                    self._output(outputs, d.classes, 2, "detection.classes"), ctx)
        return decode_semantic(self._output(outputs, self.config.semantic.logits, 0, "semantic.logits"), ctx)

    def _output(self, outputs: dict[str, np.ndarray], name: str, position: int, key: str) -> np.ndarray:
        if name:
            if name not in outputs:
                raise SegmentationError(f"{key}: the model has no output {name!r}; its outputs: {self.output_names}")
            return outputs[name]
        if position >= len(self.output_names):
            raise SegmentationError(
                f"{key}: the model has only {len(self.output_names)} output(s) {self.output_names}; "
                f"the {self.config.convention} convention needs more"
            )
        return outputs[self.output_names[position]]
