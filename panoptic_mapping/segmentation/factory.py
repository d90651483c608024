"""`make_segmenter`: the backend named in the config, built with what it needs."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from panoptic_mapping.segmentation.base import PanopticSegmenter
from panoptic_mapping.segmentation.config import BACKENDS, SegmentationConfig, resolve_path
from panoptic_mapping.segmentation.none_backend import NoneSegmenter
from panoptic_mapping.segmentation.types import SegmentationError
from recon_core.classes import ClassTable, load_class_table


def _make_onnx(config: SegmentationConfig, ground_truth: Any, table: ClassTable | None) -> PanopticSegmenter:
    from panoptic_mapping.segmentation.model_config import OnnxModelConfig, load_model_config
    from panoptic_mapping.segmentation.onnx_backend import (
        OnnxSegmenter,  # onnxruntime is imported only when a model is used
    )

    onnx = config.onnx
    if onnx.model_config:
        path = resolve_path(onnx.model_config)
        if not path.is_file():
            raise SegmentationError(f"onnx backend: model config {onnx.model_config!r} not found")
        model_cfg = load_model_config(path)
    elif onnx.model:
        model_cfg = OnnxModelConfig()  # everything `auto`: read off the graph
    else:
        raise SegmentationError(
            "onnx backend: set onnx.model to an exported .onnx file (and optionally onnx.model_config to a "
            "model config YAML, see config/segmentation/)"
        )
    if onnx.model:
        model_cfg.model = str(Path(onnx.model).expanduser().resolve())
    if table is None and onnx.class_table:
        table = load_class_table(resolve_path(onnx.class_table))
    return OnnxSegmenter(model_cfg, class_table=table, threads=onnx.threads, device=onnx.device)


def _make_oracle(config: SegmentationConfig, ground_truth: Any, table: ClassTable | None) -> PanopticSegmenter:
    from panoptic_mapping.segmentation.oracle import OracleSegmenter

    source = ground_truth if ground_truth is not None else config.oracle.ground_truth
    if not source:
        raise SegmentationError(
            "oracle backend: no ground truth; set oracle.ground_truth to a generated scene's "
            "<bag>_groundtruth folder (or pass ground_truth= to make_segmenter)"
        )
    return OracleSegmenter.from_ground_truth(source, config.oracle, table)


def _make_none(config: SegmentationConfig, ground_truth: Any, table: ClassTable | None) -> PanopticSegmenter:
    return NoneSegmenter()


_BUILDERS: dict[str, Callable[[SegmentationConfig, Any, ClassTable | None], PanopticSegmenter]] = {
    "onnx": _make_onnx,
    "oracle": _make_oracle,
    "none": _make_none,
}


def make_segmenter(
    config: SegmentationConfig | None = None, ground_truth: Any = None, class_table: ClassTable | None = None
) -> PanopticSegmenter:
    """Build the backend `config.backend` names.

    ground_truth: for `oracle`, a GroundTruthScene or folder overriding `config.oracle.ground_truth`.
    """
    cfg = config or SegmentationConfig()
    try:
        builder = _BUILDERS[cfg.backend]
    except KeyError:
        raise SegmentationError(
            f"unknown segmentation backend {cfg.backend!r}; valid backends: {list(BACKENDS)}"
        ) from None
    return builder(cfg, ground_truth, class_table)
