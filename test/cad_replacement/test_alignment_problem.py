"""The dense alignment problem (Eqs. 11-14): its analytic Jacobian matches finite differences, and
scoring without the Jacobian gives exactly the residuals of the full evaluation."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cad_replacement.alignment import AlignmentProblem, ModelGeometry, PreparedObservation
from cad_replacement.cad.procedural import build_model
from cad_replacement.observation import ObjectObservation
from cad_replacement.replace_config import CadReplacementConfig
from recon_core.geometry.transforms import rotation_about


def _problem(cls: str, seed: int, two_sided: bool, robust: bool) -> tuple[AlignmentProblem, np.ndarray]:
    model = build_model(cls, seed)
    geom = ModelGeometry.build(f"{cls}_{seed}", model, samples=400)
    # the observation: the model's surface, scaled, turned by 20 degrees and moved (a generic pose)
    mesh = model.mesh().copy()
    mesh.apply_scale(1.1)
    mesh.apply_transform(rotation_about([0.0, 0.0, 1.0], np.radians(20.0)))
    mesh.apply_translation([0.4, -0.2, 0.05])
    pts, fidx = trimesh.sample.sample_surface(mesh, 800, seed=3)
    obs = ObjectObservation(1, "object_1", cls, np.asarray(pts), normals=np.asarray(mesh.face_normals[fidx]),
                            support_z=0.05)
    cfg = CadReplacementConfig()
    prepared = PreparedObservation.build(obs, cfg)
    prob = AlignmentProblem(geom, np.eye(3), 0.05, prepared.fit_points, cfg, prepared=prepared if two_sided else None,
                            robust=robust, two_sided=two_sided, anisotropy_weight=0.05, height_target=0.5,
                            height_weight=0.1, point_normals=prepared.fit_normals)
    # Isotropic scale: the closest point is found in the model frame and mapped back, which is the
    # closest point of the scaled surface only when the scale is isotropic (anisotropic scales make
    # the Jacobian a Gauss-Newton approximation on curved parts, by design).
    x = np.array([np.log(1.08), np.log(1.08), np.log(1.08), np.radians(14.0), 0.38, -0.17])
    return prob, x


@pytest.mark.parametrize(("cls", "two_sided", "robust"), [("table", True, True), ("cabinet", True, False),
                                                           ("cup", False, True)])
def test_jacobian_matches_finite_differences(cls: str, two_sided: bool, robust: bool) -> None:
    prob, x = _problem(cls, 1, two_sided, robust)
    jac = prob.jacobian(x)
    r0 = prob.residuals(x)
    assert jac.shape == (len(r0), len(x))
    assert np.all(np.isfinite(jac))
    h = 1e-4  # float32 closest points: a smaller step differentiates rounding noise
    num = np.empty_like(jac)
    for k in range(len(x)):
        step = np.zeros(len(x))
        step[k] = h
        num[:, k] = (prob.residuals(x + step) - prob.residuals(x - step)) / (2.0 * h)
    # closest points jump between faces for a few residuals (the distance is not smooth there):
    # the columns must agree for the bulk of the rows
    err = np.abs(num - jac)
    tol = 1e-3 + 1e-2 * np.abs(num)
    assert np.mean(err <= tol) > 0.95


def test_score_without_jacobian_equals_full_evaluation() -> None:
    prob, x = _problem("cabinet", 2, True, True)
    score_light = prob.score(x)  # residuals only
    assert prob._cache is not None and prob._cache[1] is None
    jac = prob.jacobian(x)  # the cached light evaluation is upgraded, not returned without a Jacobian
    assert jac.shape[1] == len(x)
    r_full = prob.residuals(x)
    prob2, _ = _problem("cabinet", 2, True, True)
    r_light = prob2._evaluate(x, with_jac=False)[0]
    np.testing.assert_array_equal(r_full, r_light)
    assert prob.score(x) == score_light


def test_a_wild_trial_step_gives_finite_residuals_not_an_index_error() -> None:
    """Levenberg-Marquardt may try a huge step on a weakly constrained scale (a round object's radius seen
    over a quarter turn, no anisotropy prior): exp(800) overflowed to infinite points, and the nearest-
    surfel query answered them with an index one past the end (IndexError in a saved-map run)."""
    from cad_replacement.alignment import LOG_SCALE_GUARD, nearest_surfel

    prob, x = _problem("bottle", 1, True, True)
    for wild in (800.0, -800.0):
        xw = x.copy()
        xw[0] = wild
        r, jac = prob._evaluate(xw)
        assert np.all(np.isfinite(r)) and jac is not None and np.all(np.isfinite(jac))
        assert prob.scales(xw)[0] == pytest.approx(np.exp(np.sign(wild) * LOG_SCALE_GUARD))
    prepared = prob.prepared
    assert prepared is not None
    bad = np.array([[np.nan, 0.0, 0.0], [np.inf, 1.0, 0.0]])
    with np.errstate(invalid="ignore"):  # its distances are NaN; its index must still be one
        nn = nearest_surfel(prepared, bad, np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]))
    assert np.all((nn >= 0) & (nn < len(prepared.surfel_points)))


def test_an_observation_without_normals_gets_estimated_ones() -> None:
    """Observations hand out read-only points; the PCA normals (Open3D) work on a copy, oriented outwards."""
    rng = np.random.default_rng(0)
    d = rng.normal(size=(400, 3))
    pts = 0.2 * d / np.linalg.norm(d, axis=1, keepdims=True) + np.array([1.0, 2.0, 0.5])
    obs = ObjectObservation(1, "ball", "object", pts)
    assert not obs.points.flags.writeable
    prep = PreparedObservation.build(obs, CadReplacementConfig())
    assert np.allclose(np.linalg.norm(prep.normals, axis=1), 1.0)
    outward = np.einsum("ij,ij->i", prep.normals, prep.points - np.array([1.0, 2.0, 0.5]))
    assert np.mean(outward > 0.0) > 0.95
