"""Perturbed inputs of the full suite's degradation curves: extra depth noise, camera pose drift, CAD models
at the wrong scale (segmentation noise: the oracle's levels, no new input needed).

Depth noise and pose drift are applied to a generated recording's frames, written once into a new bag in
the suite cache (``$SCENE_RECON_CACHE/suite/perturb-*``) beside the same ground truth, so that a curve's
points differ in the perturbation only: same frames, same labels, same settings.

* depth noise k: extra zero-mean Gaussian depth noise of k times the sensor model's own axial sigma
  sigma(z) (`scene_recon.synthetic.depth_noise.axial_sigma`, Kinect-v1 class) on every valid pixel, on
  top of the noise the recording already has; 0 = the recording as generated.
* pose drift k: the poses the mapper is given carry k times the default odometry error of
  `PoseNoiseConfig` (random-walk drift 5 mm/sqrt(s), yaw 0.1 deg/sqrt(s), tilt 0.01 deg/sqrt(s), plus
  per-frame jitter 2 mm / 0.1 deg); 0 = the true poses (as generated).
* CAD scale s: every model of the CAD library is s times its size (`ScaledLibrary`), so the objects in the
  room are 1/s of their CAD models: the alignment must recover the scale (its fit clips the scale to
  [0.3, 3], so 4x lies beyond what it can absorb); 1 = the library as it is.
"""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

PERTURB_VERSION = 1
#: Levels of each curve (the first is the unperturbed input).
DEPTH_NOISE = (0.0, 1.0, 2.0, 4.0)
POSE_DRIFT = (0.0, 1.0, 3.0, 10.0)
CAD_SCALE = (1.0, 1.5, 2.5, 4.0)


def perturbed_recording(bag: Path, gt: Path, kind: str, level: float, seed: int = 0) -> tuple[Path, Path]:
    """(bag, ground truth) of the generated recording `bag` (its ground truth `gt`) with perturbation `kind`
    (depth_noise | pose_drift) at `level`; level 0 is the recording itself. Written once into the suite
    cache (beside the recording's own cache folder name), then reused."""
    from panoptic_mapping.dataio.bag_writer import RGBDBagWriter
    from scene_recon.synthetic.depth_noise import DepthNoiseConfig, axial_sigma
    from scene_recon.synthetic.suite import cache_root
    from scene_recon.synthetic.trajectory import PoseNoiseConfig, add_pose_noise

    if kind not in ("depth_noise", "pose_drift"):
        raise ValueError(f"unknown perturbation {kind!r}")
    if level == 0:
        return bag, gt
    folder = cache_root() / f"perturb-v{PERTURB_VERSION}-{bag.parent.name}-{kind}-{level:g}-s{seed}"
    out = folder / bag.name
    done = folder / "done"
    if done.is_file():
        return out, gt
    shutil.rmtree(folder, ignore_errors=True)
    from scene_recon.bench.scaling import _frames_of

    frames = _frames_of(bag)
    rng = np.random.default_rng(seed)
    if kind == "pose_drift":
        base = PoseNoiseConfig()
        cfg = PoseNoiseConfig(**{k: v * level for k, v in vars(base).items()})
        poses = add_pose_noise(np.stack([f.pose for f in frames]), cfg, rng)
        frames = [replace(f, pose=p) for f, p in zip(frames, poses, strict=True)]
    else:
        noise_cfg = DepthNoiseConfig()
        noisy = []
        for f in frames:
            depth = np.asarray(f.depth, np.float32).copy()
            valid = depth > 0
            sigma = axial_sigma(depth[valid], noise_cfg)
            depth[valid] = np.maximum(depth[valid] + level * sigma * rng.standard_normal(sigma.shape), 0.0)
            noisy.append(replace(f, depth=depth))
        frames = noisy
    folder.mkdir(parents=True, exist_ok=True)
    with RGBDBagWriter(out) as writer:
        for f in frames:
            writer.write_frame(f.timestamp_ns, f.color, f.depth, f.intrinsics, f.pose, f.extras.get("labels"))
    done.write_text("ok\n")
    return out, gt


class ScaledLibrary:
    """A CAD library whose every model (and its matching features) is `factor` times its size; everything
    else is the wrapped library's. Its digest differs, so no cached geometry of the true size is reused."""

    def __init__(self, base: Any, factor: float) -> None:
        self.base, self.factor = base, float(factor)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.base, name)

    def digest(self, entry: Any) -> str:
        return f"{self.base.digest(entry)}-x{self.factor:g}"

    def features(self, entry: Any) -> Any:
        return self.base.features(entry).scaled(self.factor)

    def candidates(self, class_name: str) -> list[tuple[Any, Any]]:
        return [(e, f.scaled(self.factor)) for e, f in self.base.candidates(class_name)]

    def model(self, entry: Any) -> Any:
        return self.base.model(entry).scaled(self.factor)


__all__ = ["CAD_SCALE", "DEPTH_NOISE", "POSE_DRIFT", "ScaledLibrary", "perturbed_recording"]
