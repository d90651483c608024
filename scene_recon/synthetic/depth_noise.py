"""Depth-sensor noise model applied to clean ray-cast depth.

A structured-light / active-stereo camera does not return the exact z-depth. The effects modelled
here are the ones that matter for volumetric mapping, each switchable:

* axial Gaussian noise growing quadratically with distance, plus an incidence-angle term
  (Nguyen, Izadi, Lovell, 3DIMPVT 2012, Kinect v1: sigma_z = 0.0012 + 0.0019 (z - 0.4)^2
  + 0.0001 / sqrt(z) * theta^2 / (pi/2 - theta)^2, metres);
* quantization: either in disparity (depth = f b / d with d on a sub-pixel lattice, so steps grow
  with z^2 like real stereo/structured-light) or in fixed depth steps (1 mm = 16UC1 images);
* dropouts at grazing incidence (the projected pattern is too stretched to match), with a
  probability ramp between two angles;
* dropouts on the far side of depth discontinuities (occlusion "shadows" of the projector);
* sparse random dropouts;
* a minimum and maximum range.

`noise_free=True` returns the clean depth unchanged, bypassing every effect (ground truth).
All randomness comes from the `rng` argument, so a seed reproduces the same noisy image.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

Quantization = Literal["none", "step", "disparity"]


@dataclass
class DepthNoiseConfig:
    """Tunables of `apply_depth_noise`; defaults resemble a Kinect-v1-class structured-light camera."""

    #: Return the clean depth untouched (all other settings ignored).
    noise_free: bool = False
    #: Valid sensing range in metres; readings outside become 0 (invalid).
    min_range_m: float = 0.3
    max_range_m: float = 6.0

    #: Axial Gaussian noise sigma(z) = a + b (z - c)^2 (Nguyen et al. 2012, Kinect v1).
    gaussian: bool = True
    sigma_a_m: float = 0.0012
    sigma_b_per_m: float = 0.0019
    sigma_c_m: float = 0.4
    #: Incidence-angle term coefficient (metres * sqrt(m)): k / sqrt(z) * theta^2 / (pi/2 - theta)^2.
    #: 0 disables; the term diverges at 90 deg, hence `max_sigma_m`.
    sigma_angle_m: float = 0.0001
    max_sigma_m: float = 0.05

    #: "disparity": depth from disparity on a lattice of `disparity_step_px` sub-pixels with focal
    #: length fx and `baseline_m` (step = z^2 / (f b) * step_px); "step": round depth to
    #: `quantization_step_m`; "none": keep float depth.
    quantization: Quantization = "disparity"
    baseline_m: float = 0.075
    disparity_step_px: float = 0.125
    #: Focal length (px) of the sensor's native resolution for disparity quantization; 0 = the
    #: rendered camera's fx. Set it when rendering at a reduced resolution, where the image fx
    #: would exaggerate the steps.
    disparity_focal_px: float = 0.0
    quantization_step_m: float = 0.001

    #: Grazing-angle dropouts: probability ramps linearly from 0 at `grazing_start_deg` (angle
    #: between surface normal and viewing ray) to `grazing_max_prob` at `grazing_full_deg`.
    grazing_dropout: bool = True
    grazing_start_deg: float = 70.0
    grazing_full_deg: float = 85.0
    grazing_max_prob: float = 1.0

    #: Depth-edge dropouts: a pixel is on the far side of an edge when some pixel within
    #: `edge_width_px` is nearer by more than `edge_jump_abs_m + edge_jump_rel * z`; such pixels
    #: drop with `edge_dropout_prob` (the near object keeps its silhouette, as with real shadows).
    edge_dropout: bool = True
    edge_jump_abs_m: float = 0.03
    edge_jump_rel: float = 0.03
    edge_width_px: int = 2
    edge_dropout_prob: float = 0.8

    #: Independent per-pixel dropouts (specularities, dark spots).
    random_dropout: bool = True
    random_dropout_prob: float = 0.002

    def __post_init__(self) -> None:
        if self.quantization not in ("none", "step", "disparity"):
            raise ValueError(f"depth_noise.quantization must be none|step|disparity, got {self.quantization!r}")
        if self.grazing_full_deg <= self.grazing_start_deg:
            raise ValueError("depth_noise.grazing_full_deg must be larger than grazing_start_deg")
        if self.edge_width_px < 1:
            raise ValueError("depth_noise.edge_width_px must be >= 1")


def axial_sigma(depth: np.ndarray, config: DepthNoiseConfig, incidence_cos: np.ndarray | None = None) -> np.ndarray:
    """Per-pixel std (metres) of the axial noise for true depth `depth` (and incidence cosines)."""
    z = np.asarray(depth, dtype=np.float32)
    sigma = z - np.float32(config.sigma_c_m)
    sigma *= sigma
    sigma *= np.float32(config.sigma_b_per_m)
    sigma += np.float32(config.sigma_a_m)
    if incidence_cos is not None and config.sigma_angle_m > 0:
        theta = np.arccos(np.clip(np.asarray(incidence_cos, dtype=np.float32), 0.0, 1.0))
        rest = np.maximum(np.float32(np.pi / 2) - theta, np.float32(1e-3))
        ratio = theta / rest
        ratio *= ratio
        ratio *= np.float32(config.sigma_angle_m)
        ratio /= np.sqrt(np.maximum(z, np.float32(1e-3)))
        sigma += ratio
    np.minimum(sigma, np.float32(config.max_sigma_m), out=sigma)
    return sigma


def quantize_depth(depth: np.ndarray, config: DepthNoiseConfig, focal_px: float) -> np.ndarray:
    """Quantize positive depths as configured (zeros stay zero)."""
    z = np.asarray(depth, dtype=np.float32)
    if config.quantization == "none":
        return z
    pos = z > 0
    if config.quantization == "step":
        step = np.float32(config.quantization_step_m)
        q = np.round(z / step) * step
    else:
        fb = np.float32(float(focal_px) * config.baseline_m)
        step = np.float32(config.disparity_step_px)
        disparity = fb / np.maximum(z, np.float32(1e-6))
        d_q = np.round(disparity / step) * step
        q = fb / np.maximum(d_q, step)  # d_q = 0 would be "infinitely far"
    q *= pos
    return q.astype(np.float32, copy=False)


def edge_shadow_mask(depth: np.ndarray, config: DepthNoiseConfig) -> np.ndarray:
    """Pixels with a markedly nearer valid pixel within `edge_width_px` (far side of an edge)."""
    z = np.asarray(depth, dtype=np.float32)
    valid = z > 0
    z_inf = np.where(valid, z, np.float32(np.inf))
    k = 2 * config.edge_width_px + 1
    nearest = cv2.erode(z_inf, np.ones((k, k), np.uint8), borderType=cv2.BORDER_REPLICATE)
    return valid & (z - nearest > config.edge_jump_abs_m + config.edge_jump_rel * z)


def grazing_dropout_prob(incidence_cos: np.ndarray, config: DepthNoiseConfig) -> np.ndarray:
    """Dropout probability from the angle between surface normal and viewing ray."""
    angle = np.degrees(np.arccos(np.clip(incidence_cos, 0.0, 1.0)))
    ramp = (angle - config.grazing_start_deg) / (config.grazing_full_deg - config.grazing_start_deg)
    return (np.clip(ramp, 0.0, 1.0) * config.grazing_max_prob).astype(np.float32)


def apply_depth_noise(
    depth: np.ndarray,
    config: DepthNoiseConfig,
    rng: np.random.Generator,
    *,
    incidence_cos: np.ndarray | None = None,
    focal_px: float | None = None,
) -> np.ndarray:
    """Noisy float32 depth (metres, 0 = invalid) from clean z-depth.

    depth: (H, W) clean z-depth, 0 = no surface. incidence_cos: (H, W) cosine of the angle between
    surface normal and the reversed viewing ray (1 = head-on); without it the angle term and the
    grazing dropouts are skipped. focal_px: the camera's focal length, used for disparity
    quantization unless `config.disparity_focal_px` is set.
    """
    clean = np.asarray(depth, dtype=np.float32)
    if config.noise_free:
        return clean.copy()
    valid = clean > 0
    z = clean.copy()

    # Masks are applied by multiplication / boolean assignment: np.where costs ~10x more here.
    if config.gaussian:
        sigma = axial_sigma(clean, config, incidence_cos)
        z += sigma * rng.standard_normal(z.shape, dtype=np.float32)
        z *= valid & (z > 0)

    focal = config.disparity_focal_px if config.disparity_focal_px > 0 else focal_px
    if config.quantization == "disparity" and focal is None:
        raise ValueError("disparity quantization needs the focal length (focal_px or disparity_focal_px)")
    z = quantize_depth(z, config, focal or 1.0)

    keep = np.ones(z.shape, dtype=np.float32)
    if config.grazing_dropout and incidence_cos is not None:
        keep -= grazing_dropout_prob(incidence_cos, config)
    if config.edge_dropout and config.edge_dropout_prob > 0:
        keep[edge_shadow_mask(clean, config)] *= np.float32(1.0 - config.edge_dropout_prob)
    if config.random_dropout and config.random_dropout_prob > 0:
        keep *= np.float32(1.0 - config.random_dropout_prob)
    good = rng.random(z.shape, dtype=np.float32) < keep
    good &= valid
    good &= z >= config.min_range_m
    good &= z <= config.max_range_m
    z *= good
    return z
