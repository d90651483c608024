"""Drawers pulled out do not stretch the carcass over them (issue 23).

Failure case of the stage-4 protocol (``benchmarks/bench_cad_protocol.py``, unseen library): bench-office's
four-drawer cabinet, drawers 10-22 cm out. The fit facing its handles started from the observed box, which
the open drawers make deeper than the carcass: it stretched the carcass over them (front 11 cm too far
forward) and read them closed (AE 33 mm), so the library model turned sideways won (a front flip). The
carcass's side panels end where the carcass does: a fit reaching beyond them is refitted shorter.
"""

from __future__ import annotations

import numpy as np
import pytest
from testsupport.observations import complete_observation, yaw_pose

from cad_replacement.cad.procedural import build_model
from cad_replacement.replace_config import CadReplacementConfig
from cad_replacement.replace_object import _side_front, replace_object
from cad_replacement.seeded_library import SeededLibrary
from scene_recon.evaluation.cad_metrics import evaluate_object

#: bench-office's cabinet_1 (seed and joint values of the suite scene's ground truth).
SEED = 1344184201
VALUES = {"drawer_0_slide": 0.125, "drawer_1_slide": 0.129, "drawer_2_slide": 0.098, "drawer_3_slide": 0.220}


def test_open_drawers_are_read_open_and_the_cabinet_faces_its_handles(
        tmp_path_factory: pytest.TempPathFactory) -> None:
    library = SeededLibrary(cache_dir=tmp_path_factory.mktemp("cab6"), seeds_per_class=0, classes=["cabinet"],
                            extra_seeds={"cabinet": [6]})
    model = build_model("cabinet", SEED)
    pose = yaw_pose(-np.pi / 2, (0.728, 1.982, 0.0))
    obs, _mesh = complete_observation(model, pose, VALUES, "cabinet_1")  # as the protocol's entities
    rep = replace_object(obs, library, CadReplacementConfig(workers=1))
    ev = evaluate_object(rep, model, pose, VALUES)
    assert ev.front_flip is False and ev.pose_success, (ev.chosen, ev.yaw_error_deg, ev.size_error)
    assert ev.axis_ok == 4 and ev.value_ok >= 3, (ev.chosen, ev.value_ok)


def test_side_front_is_where_the_outer_side_faces_end() -> None:
    """The side panels' outer faces, not the drawer boxes inside them, give the carcass's front."""
    rng = np.random.default_rng(1)
    # side panels: y = +-0.3, x in [-0.25, 0.25]; drawer sides inside them (y = +-0.27) reach x = 0.45
    panel = np.c_[rng.uniform(-0.25, 0.25, 400), np.repeat([0.3, -0.3], 200), rng.uniform(0, 0.8, 400)]
    drawer = np.c_[rng.uniform(0.0, 0.45, 400), np.repeat([0.27, -0.27], 200), rng.uniform(0, 0.8, 400)]
    normals = np.zeros((800, 3))
    normals[:, 1] = np.sign(np.r_[panel[:, 1], drawer[:, 1]])
    front = _side_front(np.r_[panel, drawer], normals)
    assert 0.24 < front <= 0.25
    assert np.isnan(_side_front(panel[:5], normals[:5]))
