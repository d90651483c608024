"""Configuration of the segmentation stage; mirrors `config/segmentation.yaml`.

`SegmentationConfig.backend` picks the backend; each backend has its own section. The oracle's noise
levels (`clean`, `default`, `hard`) are named presets of `OracleNoiseConfig`; the dataclass defaults
are the `default` level, `default_noise_levels()` builds all three, and the YAML file lists them in
full so that a level can be tuned without touching code. ONNX models are described by their own
YAML files (`config/segmentation/*.yaml`, see `model_config.py`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from recon_core.config import CONFIG_DIR, ConfigError, Settings, load_config, setting

#: Backend names accepted by `make_segmenter` (and the ROS parameter `backend`).
BACKENDS: tuple[str, ...] = ("onnx", "oracle", "none")
#: Default location of the stage's YAML file in a source checkout.
DEFAULT_SEGMENTATION_YAML = CONFIG_DIR / "segmentation.yaml"
#: Paper (Sec. 5 / REFERENCE.md): Detectron2 detections are kept above this confidence.
PAPER_SCORE_THRESHOLD = 0.7


@dataclass
class PaintConfig(Settings):
    """How overlapping candidates become one non-overlapping label image (Detectron2's rule).

    Things are painted in order of decreasing score; a thing that keeps less than
    `overlap_threshold` of its own pixels visible is dropped (it is mostly a duplicate). Stuff then
    fills the pixels left free, one segment per class.
    """

    overlap_threshold: float = setting(0.5, min=0.0, max=1.0)
    #: Segments with fewer pixels than this (after painting) are dropped; 0 keeps everything.
    min_area_px: int = setting(0, min=0)


@dataclass
class OracleNoiseConfig(Settings):
    """One noise level of the oracle backend: how ground truth is spoiled to look like a network.

    Every event is drawn per frame from a generator seeded by (seed, frame key), so a frame always
    looks the same for a seed while consecutive frames flicker independently. Pixel sizes are given
    for an image `reference_height_px` high and scale with the actual image height (areas with its
    square), so a 160x120 test frame is spoiled like a 640x480 one.
    """

    #: Missed instances: per-instance, per-frame drop probability ...
    miss_prob: float = setting(0.05, min=0.0, max=1.0)
    #: ... plus this much for tiny instances (ramps linearly from 0 at `small_area_px` to full at 0 px) ...
    miss_prob_small: float = setting(0.3, min=0.0, max=1.0)
    #: ... plus this much when the instance is cut off by the image border (partially visible).
    miss_prob_truncated: float = setting(0.1, min=0.0, max=1.0)
    small_area_px: int = setting(1500, min=0)
    #: Spurious instances: expected number of random blobs per frame (Poisson), with a random thing
    #: class; blob half-axes are drawn from this range (pixels).
    spurious_rate: float = setting(0.3, min=0)
    spurious_axes_px: list[float] = field(default_factory=lambda: [10.0, 50.0])
    #: Class confusion: probability that an instance takes another class of one of its confusion
    #: groups (`config/classes.yaml`); classes in no group are never confused.
    confusion_prob: float = setting(0.05, min=0.0, max=1.0)
    #: Over-segmentation: probability of splitting an instance of at least `split_min_area_px`
    #: along a random line through its centroid.
    split_prob: float = setting(0.03, min=0.0, max=1.0)
    split_min_area_px: int = setting(2000, min=0)
    #: Under-segmentation: probability of merging a pair of touching same-class instances.
    merge_prob: float = setting(0.1, min=0.0, max=1.0)
    #: Boundary noise: probability that a segment's outline is eroded or dilated (50/50) by a
    #: random radius in [1, boundary_max_radius_px].
    boundary_prob: float = setting(0.7, min=0.0, max=1.0)
    boundary_max_radius_px: int = setting(3, min=0)
    #: Background bleeding: probability that a thing mask spills, within `bleed_radius_px` of its
    #: outline, onto pixels at least `bleed_depth_gap_m` farther than the object's median depth
    #: (the chair that takes the floor behind it, paper Fig. 2A). Needs the depth image.
    bleed_prob: float = setting(0.05, min=0.0, max=1.0)
    bleed_radius_px: int = setting(8, min=0)
    bleed_depth_gap_m: float = setting(0.5, min=0)
    #: Scores: things ~ N(score_mean, score_std) clipped to [score_min, 1]; spurious blobs are
    #: centred on `spurious_score_mean` instead (a real detector is less sure of its mistakes).
    score_mean: float = setting(0.9, min=0.0, max=1.0)
    score_std: float = setting(0.05, min=0)
    score_min: float = setting(PAPER_SCORE_THRESHOLD, min=0.0, max=1.0)
    spurious_score_mean: float = setting(0.75, min=0.0, max=1.0)
    #: Frame-to-frame flicker: every event probability of a frame is scaled by a factor drawn
    #: uniformly from [1 - flicker, 1 + flicker], so some frames are worse than others.
    flicker: float = setting(0.3, min=0.0, max=1.0)
    #: Also perturb the outline of stuff segments (floor, wall, ceiling).
    stuff_boundary_noise: bool = True
    #: Image height the pixel sizes above are given for.
    reference_height_px: int = setting(480, min=0, min_exclusive=True)
    paint: PaintConfig = field(default_factory=PaintConfig)

    def __post_init__(self) -> None:
        """Ranges are checked by `Settings`; this is the one condition across values of a field."""
        super().__post_init__()
        lo_hi = self.spurious_axes_px
        if len(lo_hi) != 2 or not 0 < lo_hi[0] <= lo_hi[1]:
            raise ConfigError(f"spurious_axes_px must be [min, max] with 0 < min <= max, got {lo_hi}")


def clean_noise() -> OracleNoiseConfig:
    """`clean`: exact ground truth (stuff merged per class; ids still drawn per frame), score 1."""
    return OracleNoiseConfig(
        miss_prob=0.0, miss_prob_small=0.0, miss_prob_truncated=0.0, spurious_rate=0.0, confusion_prob=0.0,
        split_prob=0.0, merge_prob=0.0, boundary_prob=0.0, bleed_prob=0.0, score_mean=1.0, score_std=0.0,
        score_min=1.0, spurious_score_mean=1.0, flicker=0.0, stuff_boundary_noise=False,
    )


def hard_noise() -> OracleNoiseConfig:
    """`hard`: a weak network on a cluttered scene."""
    return OracleNoiseConfig(
        miss_prob=0.15, miss_prob_small=0.5, miss_prob_truncated=0.25, spurious_rate=1.5,
        spurious_axes_px=[15.0, 80.0], confusion_prob=0.2, split_prob=0.12, merge_prob=0.35,
        boundary_prob=0.9, boundary_max_radius_px=7, bleed_prob=0.2, bleed_radius_px=16, score_mean=0.82,
        score_std=0.08, spurious_score_mean=0.74, flicker=0.5,
    )


def default_noise_levels() -> dict[str, OracleNoiseConfig]:
    return {"clean": clean_noise(), "default": OracleNoiseConfig(), "hard": hard_noise()}


@dataclass
class OracleConfig(Settings):
    """Ground-truth backend for generated scenes (no network needed, noise imitates one)."""

    #: Ground truth of a generated scene: the `*_groundtruth` folder (scene.json), or the bag
    #: folder it sits beside. Needed to know each entity id's class.
    ground_truth: str = ""
    #: Name of the noise level in `levels`.
    level: str = "default"
    seed: int = 0
    levels: dict[str, OracleNoiseConfig] = field(default_factory=default_noise_levels)

    def noise(self) -> OracleNoiseConfig:
        try:
            return self.levels[self.level]
        except KeyError:
            raise ConfigError(
                f"unknown oracle noise level {self.level!r}; valid levels: {sorted(self.levels)}"
            ) from None


@dataclass
class OnnxConfig(Settings):
    """Model-based backend: an exported model, described by its own graph or a model YAML file."""

    #: The exported .onnx file; its convention, pre-processing and classes are read off the graph
    #: (`autodetect.py`). Overrides the `model` of `model_config` when both are set.
    model: str = setting("", doc="exported .onnx model (convention detected from the graph)")
    #: Model config YAML (`config/segmentation/*.yaml`) pinning what detection cannot know; relative
    #: paths are looked up from the working directory, then from the repository root.
    model_config: str = setting("", doc="model config YAML (config/segmentation/*.yaml); optional with `model`")
    #: Class table YAML (default: config/classes.yaml); the mapper must use the same table.
    class_table: str = setting("", doc="class table YAML (default config/classes.yaml)")
    #: auto: CUDA when onnxruntime offers it, else CPU; cpu; cuda (fail without it).
    device: str = setting("auto", choices=("auto", "cpu", "cuda"), doc="onnxruntime device: auto | cpu | cuda")
    #: onnxruntime intra-op threads; 0 lets onnxruntime decide.
    threads: int = setting(0, min=0, doc="onnxruntime intra-op threads; 0 = its default")


@dataclass
class SegmentationConfig(Settings):
    """Stage 1: per-frame 2D panoptic segmentation."""

    #: onnx | oracle | none. `none` (geometry only) is the default because it works on any input;
    #: `oracle` needs a generated scene's ground truth and `onnx` needs a model the user brings.
    backend: str = setting("none", choices=BACKENDS)
    onnx: OnnxConfig = field(default_factory=OnnxConfig)
    oracle: OracleConfig = field(default_factory=OracleConfig)


def load_segmentation_config(
    path: str | Path | None = DEFAULT_SEGMENTATION_YAML, overrides: dict[str, Any] | None = None
) -> SegmentationConfig:
    """Read `config/segmentation.yaml` (or another file; None: defaults) with dotted overrides."""
    return load_config(SegmentationConfig, path, overrides)


def resolve_path(path: str | Path, base: Path | None = None) -> Path:
    """Find a configured file: absolute as is; relative to `base` (default: the working directory),
    then to the installed default configuration (so `config/segmentation/x.yaml` works from anywhere)."""
    p = Path(path).expanduser()
    if p.is_absolute():
        return p
    first = (base or Path.cwd()) / p
    if first.exists():
        return first
    parts = p.parts[1:] if p.parts and p.parts[0] == "config" else p.parts
    installed = CONFIG_DIR.joinpath(*parts) if parts else CONFIG_DIR
    return installed if installed.exists() else first


__all__ = [
    "BACKENDS",
    "DEFAULT_SEGMENTATION_YAML",
    "OnnxConfig",
    "OracleConfig",
    "OracleNoiseConfig",
    "PaintConfig",
    "SegmentationConfig",
    "clean_noise",
    "default_noise_levels",
    "hard_noise",
    "load_segmentation_config",
    "resolve_path",
]
