"""CAD matching, alignment and articulation on synthetic ground truth (paper Sec. 4.2-4.3)."""

from __future__ import annotations

import time

import numpy as np
import pytest
from testsupport.observations import observe_model as _observe
from testsupport.observations import yaw_pose as _pose

from cad_replacement.cad import build_model
from cad_replacement.cad.model import CadModel
from cad_replacement.matching import ALL_ROTATIONS, UPRIGHT_ROTATIONS, candidate_classes, orientation_set
from cad_replacement.observation import ObjectObservation, ObservationError, front_direction_from_context
from cad_replacement.replace_config import CadReplacementConfig
from cad_replacement.replace_object import replace_object
from cad_replacement.seeded_library import SeededLibrary
from recon_core.geometry.box import GravityBox
from scene_recon.evaluation.cad_metrics import ROUND, extents_along, rotational_symmetry, symmetric_yaw_error

CLASSES = ["fridge", "cabinet", "table", "chair", "cup", "shelf", "microwave"]
LIB_CLASSES = sorted({*CLASSES, "wardrobe", "dishwasher", "desk", "sofa", "bottle", "oven"})


@pytest.fixture(scope="module")
def library(tmp_path_factory: pytest.TempPathFactory) -> SeededLibrary:
    return SeededLibrary(cache_dir=tmp_path_factory.mktemp("cad"), seeds_per_class=3, classes=LIB_CLASSES)


def _check_pose(rep, model: CadModel, pose: np.ndarray, *, t_tol: float, size_tol: float, ae_tol: float) -> None:
    ch = rep.chosen
    assert ch is not None
    sym = rotational_symmetry(model)
    gt_yaw = float(np.arctan2(pose[1, 0], pose[0, 0]))
    yaw_err = np.degrees(symmetric_yaw_error(ch.yaw, gt_yaw, sym))
    assert yaw_err <= 15.0, (ch.key, yaw_err)
    assert np.linalg.norm(ch.pose[:3, 3] - pose[:3, 3]) <= t_tol
    est = extents_along(pose[:3, :3], ch.pose[:3, :3], ch.scale * rep.model.size)
    gt = model.size.copy()
    if sym == ROUND:
        est, gt = np.r_[np.sort(est[:2]), est[2]], np.r_[np.sort(gt[:2]), gt[2]]
    assert np.all(np.abs(est - gt) / gt <= size_tol), (est, gt)
    assert ch.ae.ae <= ae_tol, ch.ae
    if sym == 1:  # the front is never flipped
        raw = abs((ch.yaw - gt_yaw + np.pi) % (2 * np.pi) - np.pi)
        assert np.degrees(raw) < 90.0
    assert np.all(np.isfinite(ch.pose)) and np.all(np.isfinite(ch.scale)) and np.isfinite(ch.ae.ae)


@pytest.mark.parametrize("cls", CLASSES)
def test_recovers_pose_in_library(cls: str, library: SeededLibrary) -> None:
    rng = np.random.default_rng(CLASSES.index(cls))
    model = build_model(cls, 1).scaled([1.03, 0.97, 1.02])
    pose = _pose(rng.uniform(-np.pi, np.pi), (rng.uniform(-2, 2), rng.uniform(-2, 2), 0.0))
    obs, _ = _observe(model, pose, None, rng)
    rep = replace_object(obs, library, CadReplacementConfig())
    # 5 mm noise on half of a 8 cm cup is 6 % of its width: sizes of small objects get 20 %.
    _check_pose(rep, model, pose, t_tol=0.05, size_tol=0.20 if cls == "cup" else 0.10, ae_tol=0.01)
    # An interchangeable class may win when its model fits better (e.g. a cabinet-like wardrobe).
    assert rep.chosen is not None and rep.chosen.class_name in candidate_classes(cls)


def _model_with(cls: str, joint_type: str, count: int = 1) -> tuple[CadModel, list]:
    """Procedural model 1 of ``cls`` (as the in-library tests), or the first of seeds 0..9 with
    ``count`` joints of ``joint_type`` (cabinet 1 has drawers only: its doors come from seed 0)."""
    for seed in (1, 0, *range(2, 10)):
        model = build_model(cls, seed)
        joints = [j for j in model.movable_joints if j.type == joint_type]
        if len(joints) >= count:
            return model, joints[:count]
    raise AssertionError(f"no {cls} with {count} {joint_type} joints")


def _replace_articulated(
    cls: str, joint_type: str, opening: list[float], seed: int, library: SeededLibrary
) -> tuple[CadModel, list, dict[str, float]]:
    """Observe the model with its first joints of ``joint_type`` opened, one-sided; replace it; check the pose."""
    model, joints = _model_with(cls, joint_type, len(opening))
    values = {j.name: v for j, v in zip(joints, opening, strict=True)}
    rng = np.random.default_rng(seed)
    pose = _pose(0.7, (0.5, -1.0, 0.0))
    obs, _ = _observe(model, pose, values, rng)
    rep = replace_object(obs, library, CadReplacementConfig())
    _check_pose(rep, model, pose, t_tol=0.05, size_tol=0.10, ae_tol=0.01)
    assert rep.chosen is not None and rep.chosen.class_name in candidate_classes(cls)
    return model, joints, rep.joint_values


@pytest.mark.parametrize("seed", [11, 12, 13])
@pytest.mark.parametrize("cls", ["fridge", "cabinet"])
def test_open_door_angle_is_estimated(cls: str, seed: int, library: SeededLibrary) -> None:
    # A door 40 deg open, seen from the front (one-sided): the body is not dragged towards the door,
    # the front is not flipped (``_check_pose``) and the door comes back at ~40 deg.
    model, (door,), est = _replace_articulated(cls, "revolute", [np.radians(40.0)], seed, library)
    assert abs(np.degrees(est[door.name]) - 40.0) <= 10.0, est
    # The other joints stay (about) closed.
    for j in model.movable_joints:
        if j.name != door.name and j.type == "revolute":
            assert abs(np.degrees(est[j.name])) <= 10.0, est


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_pulled_out_drawer_is_estimated(seed: int, library: SeededLibrary) -> None:
    model, (drawer,), est = _replace_articulated("cabinet", "prismatic", [0.20], seed, library)
    assert abs(est[drawer.name] - 0.20) <= 0.03, est
    for j in model.movable_joints:
        if j.name != drawer.name:
            assert abs(est[j.name]) <= 0.03, est


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_both_doors_open_are_estimated(seed: int, library: SeededLibrary) -> None:
    _, doors, est = _replace_articulated("cabinet", "revolute", [np.radians(40.0)] * 2, seed, library)
    for d in doors:
        assert abs(np.degrees(est[d.name]) - 40.0) <= 10.0, est


def test_unseen_library_still_aligns(library: SeededLibrary) -> None:
    rng = np.random.default_rng(5)
    assert library.seeds_for("cabinet") < 57
    model = build_model("cabinet", 57)  # not in the library
    pose = _pose(-2.0, (1.0, 1.0, 0.0))
    obs, _ = _observe(model, pose, None, rng, half=False)
    rep = replace_object(obs, library, CadReplacementConfig())
    assert rep.chosen is not None and "s0057" not in rep.chosen.key
    _check_pose(rep, model, pose, t_tol=0.10, size_tol=0.15, ae_tol=0.03)


def test_support_height_fixes_the_bottom(library: SeededLibrary) -> None:
    rng = np.random.default_rng(2)
    model = build_model("cup", 2)
    pose = _pose(0.3, (0.2, 0.1, 0.75))  # standing on a table top
    obs, _ = _observe(model, pose, None, rng)
    rep = replace_object(obs, library)
    assert rep.chosen is not None
    assert abs(rep.chosen.pose[2, 3] - 0.75) < 1e-6


@pytest.mark.parametrize(
    "points",
    [np.zeros((0, 3)), np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]]),
     np.c_[np.linspace(0, 1, 50), np.linspace(0, 1, 50), np.linspace(0, 1, 50)],
     np.r_[np.random.default_rng(0).random((20, 3)), [[np.nan, 0.0, 0.0]]]],
    ids=["empty", "three-collinear", "many-collinear", "nan"],
)
def test_degenerate_input_is_rejected(points: np.ndarray) -> None:
    with pytest.raises(ObservationError):
        ObjectObservation(1, "bad", "cup", points)


def test_orientation_sets_respect_gravity() -> None:
    assert len(ALL_ROTATIONS) == 24
    assert len(orientation_set("fridge", "ours")) == 4
    assert np.allclose(orientation_set("fridge", "ours"), UPRIGHT_ROTATIONS)
    lying = orientation_set("book", "ours")
    assert (len(lying) > 4 and np.all(lying[:, 2, 2] > -0.5)) or np.all(np.abs(lying[:, 2]).sum(axis=1) == 1)
    assert not np.any(np.all(np.isclose(lying[:, :, 2], [0.0, 0.0, -1.0]), axis=1))  # never upside down
    assert len(orientation_set("fridge", "paper")) == 24


def test_front_direction_from_wall_and_camera() -> None:
    from recon_core.geometry.plane import Plane

    box = GravityBox([0.0, 0.0, 0.5], [0.6, 0.8, 1.0], 0.0)
    wall = Plane(normal=[1.0, 0.0, 0.0], d=0.32)  # x = -0.32: just behind the -x side
    hint = front_direction_from_context(box, [], [wall])
    assert hint is not None and np.allclose(hint, [1.0, 0.0], atol=1e-9)
    assert front_direction_from_context(box) is None  # nothing distinguishes the sides
    cams = np.array([[0.0, 3.0, 1.5], [0.5, 3.0, 1.5]])
    hint = front_direction_from_context(box, camera_positions=cams)
    assert hint is not None and hint[1] > 0.9


def test_paper_method_runs_and_is_slower(library: SeededLibrary) -> None:
    rng = np.random.default_rng(3)
    model = build_model("microwave", 1)
    pose = _pose(1.0, (0.0, 0.0, 0.9))
    obs, _ = _observe(model, pose, None, rng, half=False)
    replace_object(obs, library)  # warm the caches for both
    t0 = time.perf_counter()
    ours = replace_object(obs, library, CadReplacementConfig(method="ours"))
    t_ours = time.perf_counter() - t0
    t0 = time.perf_counter()
    paper = replace_object(obs, library, CadReplacementConfig(method="paper"))
    t_paper = time.perf_counter() - t0
    assert paper.chosen is not None and ours.chosen is not None
    assert paper.method == "paper" and paper.hypotheses > ours.hypotheses
    assert np.isfinite(paper.chosen.ae.ae)
    assert t_paper > t_ours


TOP_K = 6


@pytest.mark.parametrize("seed", [21, 22])
def test_open_door_and_drawer_with_a_misleading_front_hint(seed: int, tmp_path) -> None:
    """A cabinet with a door 45 deg open and a drawer out: its box is much deeper than the cabinet,
    and free space around it points sideways (the hint is perpendicular to the true front). Box
    proportions and the hint then rank the model turned by 90 degrees first; the screening with the
    articulation envelope must still get to see (and choose) the real orientation."""
    found = None
    for s in range(10):
        m = build_model("cabinet", s)
        if {"revolute", "prismatic"} <= {j.type for j in m.movable_joints}:
            found = (s, m)
            break
    assert found is not None
    model_seed, model = found
    door = next(j for j in model.movable_joints if j.type == "revolute")
    drawer = next(j for j in model.movable_joints if j.type == "prismatic")
    values = {**model.zero_configuration(), door.name: np.radians(45.0), drawer.name: 0.6 * drawer.upper}
    rng = np.random.default_rng(seed)
    pose = _pose(np.pi, (2.0, -0.4, 0.0))
    seen, _ = _observe(model, pose, values, rng, half=False)
    front = pose[:2, 0]
    obs = ObjectObservation(1, "obj", "cabinet", seen.points, normals=seen.normals, support_z=0.0,
                            front_hint=np.array([-front[1], front[0]]))
    lib = SeededLibrary(cache_dir=tmp_path, seeds_per_class=10, classes=["cabinet", "wardrobe", "dishwasher"],
                        extra_seeds={"cabinet": [model_seed]})
    # a short candidate list (the suite's kitchen needed rank 24 of 20)
    rep = replace_object(obs, lib, CadReplacementConfig(top_k=TOP_K))
    assert rep.chosen is not None
    raw = abs((rep.chosen.yaw - np.pi + np.pi) % (2 * np.pi) - np.pi)
    assert np.degrees(raw) < 15.0, (rep.chosen.key, np.degrees(rep.chosen.yaw))
    assert rep.chosen.key.endswith(model.model_id)
