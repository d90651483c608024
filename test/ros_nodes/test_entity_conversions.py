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
