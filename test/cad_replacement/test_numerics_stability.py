"""Numerical stability of stage-4 kernels (hypothesis): mass properties of collision shapes and their
affine maps, and CAD matching + LM alignment on extreme observations (far from the origin, small
and large objects, float32 points, one face seen only, few points).

Bounded and derandomized; the alignment properties use few examples (each is a full
`replace_object`, ~0.3-1 s).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cad_replacement.cad import build_model
from cad_replacement.collision import inertial_from_shapes, shape_mass_properties, transform_inertial
from cad_replacement.observation import ObjectObservation, ObservationError
from cad_replacement.replace_config import CadReplacementConfig
from cad_replacement.replace_object import replace_object
from cad_replacement.seeded_library import SeededLibrary
from recon_core.kinematic_tree import CollisionShape

STABILITY = settings(max_examples=25, deadline=None, derandomize=True,
                     suppress_health_check=[HealthCheck.too_slow])
FEW = settings(max_examples=5, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])


def _principal_ok(inertia: np.ndarray) -> bool:
    """Finite, symmetric, positive (semi)definite, principal moments obey the triangle inequality."""
    if not np.all(np.isfinite(inertia)) or not np.allclose(inertia, inertia.T, rtol=1e-9, atol=0):
        return False
    ev = np.linalg.eigvalsh(inertia)
    tol = 1e-9 * ev.max()
    return bool(ev.min() >= -tol and ev[0] + ev[1] >= ev[2] - tol)


def _pose(yaw: float, xyz) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    t = np.eye(4)
    t[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    t[:3, 3] = xyz
    return t


# ---------------------------------------------------------------------------- inertia
size3 = st.tuples(*[st.floats(1e-4, 1e2)] * 3)


@STABILITY
@given(sizes=st.lists(size3, min_size=1, max_size=4), offset=st.tuples(*[st.floats(-1e3, 1e3)] * 3),
       density=st.floats(1e-3, 2e4), radius=st.floats(1e-4, 10.0))
def test_mass_properties_of_any_shapes_are_finite_and_physical(sizes, offset, density, radius):
    shapes = []
    for k, s in enumerate(sizes):
        origin = _pose(0.7 * k, np.asarray(offset) + np.array([k * 2.0 * max(s), 0.0, 0.0]))
        shapes.append(CollisionShape("box", origin=origin, size=np.asarray(s)))
    shapes.append(CollisionShape("cylinder", origin=_pose(0.0, offset), radius=radius, length=2 * radius))
    shapes.append(CollisionShape("sphere", origin=_pose(0.0, offset), radius=radius))
    inertial = inertial_from_shapes(shapes, density)
    vol = sum(shape_mass_properties(s)[0] for s in shapes)
    assert inertial.mass == pytest.approx(vol * density, rel=1e-9)
    assert np.all(np.isfinite(inertial.center_of_mass)) and _principal_ok(inertial.inertia)


@STABILITY
@given(size=size3, scale=st.tuples(*[st.floats(1e-3, 1e3)] * 3), yaw=st.floats(-np.pi, np.pi),
       shift=st.tuples(*[st.floats(-1e3, 1e3)] * 3))
def test_affine_map_of_an_inertial_matches_the_mapped_box(size, scale, yaw, shift):
    box = CollisionShape("box", size=np.asarray(size))
    inertial = inertial_from_shapes([box], 500.0)
    affine = _pose(yaw, shift) @ np.diag([*scale, 1.0])
    mapped = transform_inertial(inertial, affine)
    direct = inertial_from_shapes([CollisionShape("box", origin=_pose(yaw, shift), size=np.asarray(size) * scale)],
                                  500.0)
    assert mapped.mass == pytest.approx(direct.mass, rel=1e-9)
    np.testing.assert_allclose(mapped.center_of_mass, direct.center_of_mass, atol=1e-9 * (1 + np.abs(shift).max()))
    np.testing.assert_allclose(mapped.inertia, direct.inertia, rtol=1e-6, atol=1e-9 * np.abs(direct.inertia).max())
    assert _principal_ok(mapped.inertia)


@pytest.mark.parametrize("density", [0.0, -1.0, np.nan, np.inf])
def test_inertial_refuses_non_physical_density(density):
    with pytest.raises(ValueError):
        inertial_from_shapes([CollisionShape("box", size=np.ones(3))], density)


def test_inertial_of_a_flat_or_singular_map_is_refused_not_nan():
    inertial = inertial_from_shapes([CollisionShape("box", size=np.ones(3))], 1.0)
    with pytest.raises(ValueError):
        transform_inertial(inertial, np.diag([1.0, 1.0, 0.0, 1.0]))
    with pytest.raises(ValueError):
        inertial_from_shapes([CollisionShape("box", size=np.array([1.0, 1.0, 0.0]))], 1.0)


# ---------------------------------------------------------------------------- matching + LM alignment
@pytest.fixture(scope="module")
def library(tmp_path_factory: pytest.TempPathFactory) -> SeededLibrary:
    return SeededLibrary(cache_dir=tmp_path_factory.mktemp("cad"), seeds_per_class=2, classes=["box", "cabinet"])


def _observation(cls: str, seed: int, pose: np.ndarray, scale: float = 1.0, *, top_only: bool = False,
                 n: int = 1500, dtype=np.float64) -> tuple[ObjectObservation, np.ndarray]:
    model = build_model(cls, seed).scaled([scale] * 3)
    mesh = model.mesh()
    pts, fidx = trimesh.sample.sample_surface(mesh, n, seed=seed)
    nrm = mesh.face_normals[fidx]
    keep = nrm[:, 2] > 0.9 if top_only else (nrm @ [1.0, 0.3, 0.5]) > -0.2  # a camera's half, or the top face
    pts, nrm = pts[keep] @ pose[:3, :3].T + pose[:3, 3], nrm[keep] @ pose[:3, :3].T
    rng = np.random.default_rng(seed)
    pts = pts + rng.normal(0.0, 0.002 * scale, pts.shape)
    obs = ObjectObservation(1, f"{cls}_1", cls, pts.astype(dtype), normals=nrm.astype(dtype),
                            support_z=float(pose[2, 3]))
    return obs, model.size


def _check_finite(rep) -> None:
    ch = rep.chosen
    assert ch is not None
    assert np.all(np.isfinite(ch.pose)) and np.all(np.isfinite(ch.scale)) and np.isfinite(ch.ae.ae)


@FEW
@given(distance=st.floats(0.0, 1000.0), yaw=st.floats(-np.pi, np.pi), heading=st.floats(-np.pi, np.pi),
       f32=st.booleans())
def test_alignment_far_from_origin_and_in_float32(library, distance, yaw, heading, f32):
    # up to 1 km: where the mapper re-centres its map (README: far-away poses)
    xyz = (distance * np.cos(heading), distance * np.sin(heading), 0.0)
    pose = _pose(yaw, xyz)
    obs, size = _observation("box", 0, pose, dtype=np.float32 if f32 else np.float64)
    rep = replace_object(obs, library, CadReplacementConfig())
    _check_finite(rep)
    # float32 points at 1 km are rounded to 61 um: the fit stays within a few mm of the truth
    assert np.linalg.norm(rep.chosen.pose[:2, 3] - np.asarray(xyz[:2])) < 0.02 + 0.05 * max(size[:2])


@FEW
@given(scale=st.sampled_from([0.05, 0.2, 5.0, 20.0]), yaw=st.floats(-np.pi, np.pi))
def test_alignment_of_tiny_and_huge_objects_is_finite_and_clipped_to_the_scale_range(library, scale, yaw):
    cfg = CadReplacementConfig()
    obs, _size = _observation("cabinet", 1, _pose(yaw, (1.0, 2.0, 0.0)), scale=scale)
    rep = replace_object(obs, library, cfg)
    _check_finite(rep)
    assert np.all(rep.chosen.scale >= cfg.min_scale - 1e-9) and np.all(rep.chosen.scale <= cfg.max_scale + 1e-9)


@FEW
@given(yaw=st.floats(-np.pi, np.pi), n=st.integers(40, 400))
def test_alignment_of_a_coplanar_observation_top_face_only(library, yaw, n):
    # only the top of a box seen (coplanar points): no height information at all; a finite fit or a clear error
    try:
        obs, _ = _observation("box", 0, _pose(yaw, (0.5, -0.5, 0.7)), top_only=True, n=n)
    except ObservationError as exc:
        assert "points" in str(exc)
        return
    rep = replace_object(obs, library, CadReplacementConfig())
    _check_finite(rep)
    assert abs(rep.chosen.pose[2, 3] - 0.7) < 1e-6  # the support height holds the bottom


@pytest.mark.parametrize("points", [
    np.zeros((5, 3)),                                        # one point repeated
    np.c_[np.linspace(0, 1, 100), np.zeros(100), np.zeros(100)],  # collinear
    np.full((50, 3), 1e6) + np.c_[np.zeros(50), np.linspace(0, 1e-9, 50), np.zeros(50)],  # collinear far away
])
def test_degenerate_observations_are_refused_with_a_clear_error(points):
    with pytest.raises(ObservationError, match=r"degenerate|at least"):
        ObjectObservation(1, "bad", "box", points)
