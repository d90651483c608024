"""The observed/unknown grid around an entity (``recon_core.geometry.observed_space``): lookups,
serialisation (entities.json, messages) and its validation."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from recon_core.entity import Entity, load_entities, save_entities
from recon_core.errors import InputError
from recon_core.geometry.observed_space import ObservedSpace


def _space() -> ObservedSpace:
    empty = ObservedSpace.unknown([0.0, 0.0, 0.0], [1.0, 0.5, 0.25], 8)
    assert empty.cell == 0.125 and empty.shape == (8, 4, 2) and not empty.observed.any()
    grid = np.zeros(empty.shape, bool)
    grid[:4] = True  # x < 0.5 observed
    return ObservedSpace(empty.origin, empty.cell, grid)


def test_lookups_inside_and_outside_the_grid():
    space = _space()
    pts = np.array([[0.1, 0.1, 0.1], [0.9, 0.1, 0.1], [2.0, 0.1, 0.1], [np.nan, 0.0, 0.0]])
    # outside the grid (and for a non-finite point) nothing is known about the views: observed, as
    # stage 4 assumed before the grid existed
    assert space.observed_at(pts).tolist() == [True, False, True, True]
    assert space.observed_share == 0.5
    assert np.allclose(space.upper, [1.0, 0.5, 0.25])
    assert len(space.centres()) == 64 and np.allclose(space.centres()[0], [0.0625, 0.0625, 0.0625])


def test_other_surface_marks_its_cells_observed():
    space = _space().with_surface(np.array([[0.9, 0.1, 0.1], [5.0, 5.0, 5.0]]))
    assert space.observed_at(np.array([[0.9, 0.1, 0.1], [0.9, 0.4, 0.1]])).tolist() == [True, False]
    assert _space().with_surface(np.zeros((0, 3))).observed_share == 0.5


def test_round_trips_and_malformed_grids():
    space = _space()
    back = ObservedSpace.from_dict(space.to_dict())
    assert np.array_equal(back.observed, space.observed) and back.cell == space.cell
    with pytest.raises(InputError, match="bytes for"):
        ObservedSpace.from_packed(space.origin, space.cell, space.shape, space.packed()[:-1])
    with pytest.raises(InputError, match="cannot read"):
        ObservedSpace.from_dict({"origin": [0, 0, 0], "cell": 0.1})
    with pytest.raises(InputError, match="cell size"):
        ObservedSpace(np.zeros(3), 0.0, np.ones((2, 2, 2), bool))
    with pytest.raises(InputError, match="empty or not finite"):
        ObservedSpace.unknown([0, 0, 0], [1, 1, 0], 8)


def test_an_entity_keeps_its_grid_through_its_folder(tmp_path):
    mesh = trimesh.creation.box([0.2, 0.2, 0.2])
    e = Entity(5, "cup", mesh.vertices, mesh.faces, observed_space=_space())
    plain = Entity(6, "cup", mesh.vertices, mesh.faces)
    save_entities([e, plain], tmp_path)
    a, b = load_entities(tmp_path)
    assert a.observed_space is not None and np.array_equal(a.observed_space.observed, _space().observed)
    assert b.observed_space is None
