"""Stage 4 with the map's observed/unknown grid (``Entity.observed_space``, issue 22 item 4).

A table whose far half lay outside every frame is observed as its near half. Without knowing that
the far half is unknown (not absent), the fit shrinks the model onto the seen half; with the grid
the box grows into the unknown side to the model's proportions and the seen end stays put.
"""

from __future__ import annotations

import numpy as np
import pytest
from testsupport.observations import yaw_pose

from cad_replacement.cad.procedural import build_model
from cad_replacement.observation import ObjectObservation, grown_into_unknown
from cad_replacement.replace_config import CadReplacementConfig
from cad_replacement.replace_object import replace_object
from cad_replacement.seeded_library import SeededLibrary
from recon_core.geometry.box import GravityBox
from recon_core.geometry.observed_space import ObservedSpace
from recon_core.geometry.plane import Plane
from recon_core.geometry.plane_fit import sample_mesh

SEED = 3
#: The frame's edge: the camera saw the table up to this x (the table spans about -0.5..0.5 m).
CUT_X = 0.05


@pytest.fixture(scope="module")
def library(tmp_path_factory: pytest.TempPathFactory) -> SeededLibrary:
    return SeededLibrary(cache_dir=tmp_path_factory.mktemp("cad"), seeds_per_class=0, classes=["table"],
                         extra_seeds={"table": [SEED]})


def _half_seen_table(with_grid: bool) -> tuple[ObjectObservation, np.ndarray]:
    """The table's surface up to ``CUT_X`` (what the frames showed) and, optionally, the grid in which
    everything beyond ``CUT_X`` is unknown; returns the observation and the true size."""
    model = build_model("table", SEED)
    mesh = model.mesh({})
    mesh.apply_transform(yaw_pose(0.0, (0.0, 0.0, 0.0)))
    mesh.apply_translation(-np.r_[mesh.bounds.mean(axis=0)[:2], mesh.bounds[0, 2]])
    pts, nrm = sample_mesh(mesh, 8000, 0)
    seen = (pts[:, 0] < CUT_X) & (nrm[:, 2] > -0.5)  # the near part, not the top's underside
    space = None
    if with_grid:
        lo, hi = mesh.bounds[0] - 0.6, mesh.bounds[1] + 0.6
        grid = ObservedSpace.unknown(lo, hi, 40)
        space = ObservedSpace(grid.origin, grid.cell, (grid.centres()[:, 0] < CUT_X).reshape(grid.shape))
    obs = ObjectObservation(1, "table_1", "table", pts[seen], normals=nrm[seen], support_z=0.0, observed_space=space)
    return obs, np.asarray(mesh.extents)


@pytest.mark.parametrize("with_grid", [False, True])
def test_a_half_seen_table_keeps_its_size_only_where_the_grid_says_its_far_half_is_unknown(
        library: SeededLibrary, with_grid: bool) -> None:
    obs, size = _half_seen_table(with_grid)
    rep = replace_object(obs, library, CadReplacementConfig())
    best = min((c for c in rep.candidates if c.stage == "full"), key=lambda c: c.score)
    model = library.model(best.match.entry)
    extent_x = float(np.abs(best.placement.pose[:3, :3] @ (best.scale * model.size))[0])
    centre_x = float(best.placement.apply(model.features.box_center[None])[0, 0])
    if with_grid:
        assert extent_x == pytest.approx(size[0], rel=0.1)
        assert abs(centre_x) < 0.05  # the true centre: the seen end stayed where it was seen
    else:
        assert extent_x < 0.8 * size[0]  # shrunk onto the seen part: what the grid fixes


def test_the_space_in_front_of_a_surface_decides_not_its_own_cell() -> None:
    grid = ObservedSpace.unknown([-1.0, -1.0, 0.0], [1.0, 1.0, 1.0], 20)
    observed = np.abs(grid.centres()[:, 2] - 0.55) < 1e-6  # one row of 10 cm cells, z 0.5-0.6, observed
    pts = np.random.default_rng(0).uniform(-0.1, 0.1, (20, 3)) + np.array([0.0, 0.0, 0.4])
    obs = ObjectObservation(1, "t", "table", pts, observed_space=ObservedSpace(
        grid.origin, grid.cell, observed.reshape(grid.shape)))
    top = np.array([[0.0, 0.0, 0.47], [0.0, 0.0, 0.47]])
    up, down = np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, -1.0]])
    assert not obs.observed_at(top)[0]  # the surface's own cell (z 0.4-0.5) is unknown
    assert obs.observed_in_front(top[:1], up)[0]  # the cell above it was seen: a view would have seen it
    assert not obs.observed_in_front(top[:1], down)[0]
    assert obs.observed_in_front(top, np.zeros((2, 3))).tolist() == [False, False]  # no normal: its own cell
    assert ObjectObservation(1, "t", "table", pts).observed_in_front(top, np.r_[up, up]).all()  # no grid


def test_room_stops_at_observed_space_and_at_a_wall() -> None:
    grid = ObservedSpace.unknown([-1.0, -1.0, 0.0], [1.0, 1.0, 1.0], 20)
    cell = grid.cell
    unknown = grid.centres()[:, 0] > 0.2  # beyond x = 0.2 no camera looked
    space = ObservedSpace(grid.origin, cell, ~unknown.reshape(grid.shape))
    box = GravityBox(np.array([0.0, 0.0, 0.4]), np.array([0.4, 0.4, 0.8]), 0.0)
    room = space.room(box)
    assert room[0, 1] == pytest.approx(0.8, abs=cell)  # +x: unknown up to the grid's edge at x = 1
    assert room[0, 0] == 0.0 and room[1, 0] == 0.0 and room[1, 1] == 0.0
    wall = Plane(np.array([-1.0, 0.0, 0.0]), 0.5)  # the plane x = 0.5, facing the room
    pts = np.random.default_rng(0).uniform(-0.2, 0.2, (50, 3)) + np.array([0.0, 0.0, 0.4])
    obs = ObjectObservation(1, "t", "table", pts, observed_space=space, walls=(wall,))
    assert obs.room(box)[0, 1] == pytest.approx(0.3, abs=1e-9)  # stops at the wall
    grown = grown_into_unknown(box, obs.room(box), np.array([1.0, 1.0, 0.8]))
    assert grown.size[0] == pytest.approx(0.7) and grown.size[1] == pytest.approx(0.4)
    assert grown.center[0] == pytest.approx(0.15)  # grew towards +x only: the seen -x end stays
