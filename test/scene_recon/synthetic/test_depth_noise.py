"""Depth-noise model: each effect behaves as configured and is reproducible for a seed."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from scene_recon.synthetic import DepthNoiseConfig, apply_depth_noise, axial_sigma
from scene_recon.synthetic.depth_noise import edge_shadow_mask, quantize_depth

OFF = DepthNoiseConfig(
    gaussian=False, quantization="none", grazing_dropout=False, edge_dropout=False, random_dropout=False,
    min_range_m=0.0, max_range_m=100.0,
)


def only(**kwargs) -> DepthNoiseConfig:
    """All effects off except the given ones."""
    return dataclasses.replace(OFF, **kwargs)


def test_noise_free_returns_exact_depth():
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.2, 9.0, (60, 80)).astype(np.float32)
    depth[::7, ::5] = 0
    out = apply_depth_noise(depth, DepthNoiseConfig(noise_free=True), rng, incidence_cos=np.zeros_like(depth))
    np.testing.assert_array_equal(out, depth)
    assert out is not depth and out.dtype == np.float32
    # All effects switched off is also exact.
    np.testing.assert_array_equal(apply_depth_noise(depth, OFF, rng), depth)


def test_gaussian_noise_grows_with_distance():
    cfg = only(gaussian=True, sigma_angle_m=0.0)
    stds = []
    for z in (0.8, 2.0, 4.0):
        depth = np.full((200, 200), z, np.float32)
        noisy = apply_depth_noise(depth, cfg, np.random.default_rng(1))
        err = noisy - depth
        assert abs(err.mean()) < 0.1 * err.std() + 1e-4  # unbiased
        stds.append(err.std())
        expected = cfg.sigma_a_m + cfg.sigma_b_per_m * (z - cfg.sigma_c_m) ** 2
        assert err.std() == pytest.approx(expected, rel=0.05)
    assert stds[0] < stds[1] < stds[2]


def test_incidence_angle_increases_noise():
    cfg = only(gaussian=True)
    depth = np.full((10, 10), 2.0, np.float32)
    head_on = axial_sigma(depth, cfg, np.ones_like(depth))
    oblique = axial_sigma(depth, cfg, np.full_like(depth, np.cos(np.radians(70))))
    assert (oblique > head_on).all()
    assert (axial_sigma(depth, cfg, np.zeros_like(depth)) <= cfg.max_sigma_m).all()


def test_step_quantization():
    cfg = only(quantization="step", quantization_step_m=0.001)
    depth = np.random.default_rng(2).uniform(0.5, 5.0, (50, 50)).astype(np.float32)
    out = apply_depth_noise(depth, cfg, np.random.default_rng(0))
    mm = out.astype(np.float64) * 1000
    np.testing.assert_allclose(mm, np.round(mm), atol=1e-3)
    assert np.abs(out - depth).max() <= 0.0005 + 1e-6


def test_disparity_quantization_steps_grow_quadratically():
    cfg = only(quantization="disparity", baseline_m=0.075, disparity_step_px=0.125)
    f = 525.0
    z = np.linspace(0.5, 5.0, 20000, dtype=np.float32)[None, :]
    q = quantize_depth(z, cfg, f)[0]
    levels = np.unique(q)
    # Levels are exactly f b / (k * step) for integers k.
    k = f * cfg.baseline_m / (levels.astype(np.float64) * cfg.disparity_step_px)
    np.testing.assert_allclose(k, np.round(k), atol=1e-3)
    near = np.diff(levels[(levels > 0.9) & (levels < 1.1)]).mean()
    far = np.diff(levels[(levels > 3.8) & (levels < 4.2)]).mean()
    assert far / near == pytest.approx(16.0, rel=0.15)  # step ~ z^2
    assert np.abs(q - z[0]).max() <= 0.5 * 5.0**2 / (f * cfg.baseline_m) * cfg.disparity_step_px * 1.05
    with pytest.raises(ValueError, match="focal"):
        apply_depth_noise(z, cfg, np.random.default_rng(0))


def test_grazing_angle_dropouts():
    cfg = only(grazing_dropout=True, grazing_start_deg=70.0, grazing_full_deg=85.0)
    depth = np.full((100, 300), 2.0, np.float32)
    angles = np.repeat(np.array([30.0, 77.5, 88.0]), 100)[None, :].repeat(100, axis=0)
    out = apply_depth_noise(depth, cfg, np.random.default_rng(3), incidence_cos=np.cos(np.radians(angles)))
    dropped = out == 0
    assert dropped[:, :100].mean() == 0.0
    assert dropped[:, 100:200].mean() == pytest.approx(0.5, abs=0.05)
    assert dropped[:, 200:].mean() == 1.0


def test_edge_dropouts_on_far_side_only():
    depth = np.full((40, 40), 3.0, np.float32)
    depth[:, :20] = 1.0  # near object on the left
    mask = edge_shadow_mask(depth, only(edge_dropout=True, edge_width_px=2))
    assert mask[:, 20:22].all() and not mask[:, 22:].any() and not mask[:, :20].any()
    out = apply_depth_noise(depth, only(edge_dropout=True, edge_dropout_prob=1.0, edge_width_px=2),
                            np.random.default_rng(0))
    assert (out[:, 20:22] == 0).all() and (out[:, :20] == 1.0).all() and (out[:, 22:] == 3.0).all()
    # A smooth slope is not an edge.
    ramp = np.tile(np.linspace(1.0, 1.5, 40, dtype=np.float32), (40, 1))
    assert not edge_shadow_mask(ramp, only(edge_dropout=True)).any()


def test_random_dropouts_and_range_cut():
    depth = np.full((300, 300), 2.0, np.float32)
    out = apply_depth_noise(depth, only(random_dropout=True, random_dropout_prob=0.05), np.random.default_rng(4))
    assert (out == 0).mean() == pytest.approx(0.05, abs=0.005)
    ramp = np.tile(np.linspace(0.1, 9.0, 100, dtype=np.float32), (5, 1))
    cut = apply_depth_noise(ramp, only(min_range_m=0.4, max_range_m=6.0), np.random.default_rng(0))
    assert ((cut == 0) == ((ramp < 0.4) | (ramp > 6.0))).all()
    # Invalid input stays invalid, noise never makes negative depth.
    z = np.zeros((50, 50), np.float32)
    z[:, 25:] = 0.35
    noisy = apply_depth_noise(z, DepthNoiseConfig(min_range_m=0.0), np.random.default_rng(0), focal_px=525.0)
    assert (noisy[:, :25] == 0).all() and (noisy >= 0).all()


def test_deterministic_for_a_seed():
    rng = np.random.default_rng(5)
    depth = rng.uniform(0.5, 5, (80, 80)).astype(np.float32)
    cos = rng.uniform(0, 1, (80, 80)).astype(np.float32)
    cfg = DepthNoiseConfig()
    a = apply_depth_noise(depth, cfg, np.random.default_rng(9), incidence_cos=cos, focal_px=525.0)
    b = apply_depth_noise(depth, cfg, np.random.default_rng(9), incidence_cos=cos, focal_px=525.0)
    c = apply_depth_noise(depth, cfg, np.random.default_rng(10), incidence_cos=cos, focal_px=525.0)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_config_validation():
    with pytest.raises(ValueError):
        DepthNoiseConfig(quantization="cubic")  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        DepthNoiseConfig(grazing_start_deg=80, grazing_full_deg=70)
