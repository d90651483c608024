"""PanopticEntity <-> Entity: the voted-core marking travels as ``fringe_vertices``."""

from __future__ import annotations

import numpy as np
import trimesh

from recon_core.entity import Entity


def test_fringe_vertices_round_trip_inline_and_unmarked_entities_stay_unmarked():
    from ros_nodes.entity_conversions import entity_to_msg, msg_to_entity

    core = trimesh.creation.box([0.1, 0.1, 0.2])
    fringe = trimesh.creation.box([0.3, 0.02, 0.3]).apply_translation([0, 0.1, 0])
    both = trimesh.util.concatenate([core, fringe])
    e = Entity(3, "bottle", both.vertices, both.faces, core_vertices=len(core.vertices))
    msg = entity_to_msg(e)
    assert msg.fringe_vertices == len(fringe.vertices)
    back = msg_to_entity(msg)
    assert back.core_vertices == e.core_vertices and np.allclose(back.vertices, e.vertices)
    plain = msg_to_entity(entity_to_msg(Entity(4, "cup", core.vertices, core.faces)))
    assert plain.core_vertices == -1


def test_observed_space_round_trip_and_a_malformed_grid_is_an_entity_error():
    import pytest

    from recon_core.errors import EntityError
    from recon_core.geometry.observed_space import ObservedSpace
    from ros_nodes.entity_conversions import entity_to_msg, msg_to_entity

    core = trimesh.creation.box([0.1, 0.1, 0.2])
    grid = np.random.default_rng(0).random((5, 7, 3)) > 0.5  # 105 cells: the last byte is partly padding
    space = ObservedSpace(np.array([-0.3, -0.4, -0.1]), 0.05, grid)
    msg = entity_to_msg(Entity(3, "bottle", core.vertices, core.faces, observed_space=space))
    back = msg_to_entity(msg).observed_space
    assert back is not None and back.shape == (5, 7, 3) and back.cell == 0.05
    assert np.array_equal(back.observed, grid) and np.allclose(back.origin, space.origin)
    assert msg_to_entity(entity_to_msg(Entity(4, "cup", core.vertices, core.faces))).observed_space is None
    msg.observed_bits = bytes(msg.observed_bits)[:-1]
    with pytest.raises(EntityError, match="bytes for 105 cells"):
        msg_to_entity(msg)
