"""Support inference (Eqs. (1)-(3)): every case of the issue on hand-made scenes."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from recon_core.contact_graph import ROOT_ID
from recon_core.errors import EntityError
from scene_graph.builder import build_contact_graph


def parents(graph) -> dict[str, str]:
    return {graph.nodes[c].name: graph.nodes[e.parent_id].name for c, e in graph.supports.items()}


def test_room_supports(room):
    g = build_contact_graph(room)
    p = parents(g)
    assert p["floor_1"] == "scene"
    assert p["wall_2"] == p["wall_3"] == "floor_1"
    assert p["table_4"] == "floor_1"  # table on floor
    assert p["cup_5"] == "table_4"  # cup on table
    assert p["shelf_6"] == "floor_1"
    assert p["book_7"] == "shelf_6"  # book on a shelf level


def test_cup_on_table_edge_plane_and_scores(room):
    g = build_contact_graph(room)
    cup = g.supports[5]
    assert cup.kind == "support"
    np.testing.assert_allclose(cup.plane.normal, [0, 0, 1], atol=1e-9)
    assert -cup.plane.d == pytest.approx(0.75, abs=1e-9)
    assert cup.score == pytest.approx(1.0, abs=1e-6)  # Eq. (3): D = 0, full contact
    assert cup.contact_ratio == pytest.approx(1.0)


def test_book_picks_the_level_right_under_it_not_a_lower_one(room):
    g = build_contact_graph(room)
    book = g.supports[7]
    assert -book.plane.d == pytest.approx(0.5, abs=1e-6)  # the middle level, not 0.1 below it
    assert book.distance == pytest.approx(0.0, abs=1e-6)


def test_stacked_books_chain(entity):
    ents = [
        entity(1, "floor", [([-2, -2, -0.05], [2, 2, 0])]),
        entity(2, "table", [([-0.5, -0.5, 0.7], [0.5, 0.5, 0.73]), ([-0.5, -0.5, 0], [-0.45, -0.45, 0.7])]),
        entity(3, "book", [([0.0, 0.0, 0.73], [0.2, 0.3, 0.76])]),
        entity(4, "book", [([0.02, 0.03, 0.76], [0.18, 0.25, 0.78])]),  # thin book on the lower one
        entity(5, "box", [([0.05, 0.05, 0.78], [0.15, 0.15, 0.88])]),  # a box on the stack
    ]
    p = parents(build_contact_graph(ents))
    assert p == {"floor_1": "scene", "table_2": "floor_1", "book_3": "table_2", "book_4": "book_3", "box_5": "book_4"}


def test_occluded_table_top_registers_an_invisible_supporting_plane(entity):
    legs = [([x, y, 0], [x + 0.05, y + 0.05, 0.72]) for x in (-0.5, 0.45) for y in (-0.4, 0.35)]
    apron = [([-0.5, -0.4, 0.68], [0.5, -0.38, 0.72]), ([-0.5, 0.38, 0.68], [0.5, 0.4, 0.72])]
    ents = [
        entity(1, "floor", [([-2, -2, -0.05], [2, 2, 0])]),
        entity(2, "table", legs + apron),  # the top was never seen
        entity(3, "box", [([-0.1, -0.1, 0.75], [0.1, 0.1, 0.9])]),
    ]
    g = build_contact_graph(ents)
    edge = g.supports[3]
    assert edge.parent_id == 2 and edge.kind == "inferred_plane"
    assert -edge.plane.d == pytest.approx(0.75)
    assert any(p.source == "inferred" for p in g.nodes[2].planes)
    # Without invisible planes the floor 0.75 m below wins Eq. (3) with 0.25 > 0.2.
    from scene_graph.config import SceneGraphConfig

    cfg = SceneGraphConfig()
    cfg.support.invisible_planes = False
    assert build_contact_graph(ents, cfg).supports[3].parent_id == 1


def test_object_against_a_wall_falls_back_to_the_wall(entity):
    ents = [
        entity(1, "floor", [([-2, -2, -0.05], [2, 2, 0])]),
        entity(2, "wall", [([-2, 2, 0], [2, 2.1, 2.5])]),
        entity(3, "wall", [([2, -2, 0], [2.1, 2, 2.5])]),
        entity(4, "box", [([0.0, 1.9, 1.4], [0.4, 2.0, 1.8])], name="picture"),  # hangs on wall_2
        entity(5, "bottle", [([-1.0, -1.0, 1.0], [-0.9, -0.9, 1.3])]),  # floats mid-room: no wall near
    ]
    g = build_contact_graph(ents)
    assert g.supports[4].parent_id == 2 and g.supports[4].kind == "fallback_wall"
    assert g.supports[5].parent_id == 1 and g.supports[5].kind == "fallback_floor"
    # no contact, no plane: the floating bottle's box is not stretched down to the floor (a
    # microwave on an unlabelled kitchen counter became 1.1 m tall on real frames)
    assert g.supports[5].plane is None
    assert g.nodes[5].box.z_min == pytest.approx(1.0, abs=0.02) and g.nodes[5].box.size[2] < 0.35


def test_tilted_plane_fails_eq1_gravity_tolerance(entity, box):
    import trimesh

    ramp = box([-0.5, -0.5, -0.02], [0.5, 0.5, 0.0])
    ramp.apply_transform(trimesh.transformations.rotation_matrix(np.radians(35), [1, 0, 0]))  # n.g = -0.82 > -0.9
    ramp.apply_translation([0, 0, 0.6])
    ents = [entity(1, "floor", [([-2, -2, -0.05], [2, 2, 0])]), entity(2, "table", ramp),
            entity(3, "cup", [([-0.05, -0.05, 0.62], [0.05, 0.05, 0.72])])]
    from scene_graph.config import SceneGraphConfig

    cfg = SceneGraphConfig()
    cfg.support.invisible_planes = False  # Eq. (1) alone
    g = build_contact_graph(ents, cfg)
    assert not any(p.is_support(cfg.support.a_th) for p in g.nodes[2].planes)
    assert g.supports[3].parent_id == 1  # the floor below, not the ramp


def test_score_below_threshold_falls_back(entity):
    # The cup overhangs the table edge: a sliver of contact (Eq. (3) score 0.05 < 0.2), no floor seen below.
    ents = [entity(1, "floor", [([-2, -2, -0.05], [0.3, 2, 0])]),
            entity(2, "table", [([-0.5, -0.5, 0.70], [0.5, 0.5, 0.72])]),
            entity(3, "cup", [([0.49, 0.0, 0.72], [0.69, 0.2, 0.9])])]
    g = build_contact_graph(ents)
    e = g.supports[3]
    assert e.kind == "fallback_floor" and e.parent_id == 1 and e.score == 0.0


def test_no_cycles_between_equal_bottoms(entity):
    # Two boxes side by side touching, same bottom: neither supports the other.
    ents = [entity(1, "floor", [([-2, -2, -0.05], [2, 2, 0])]),
            entity(2, "box", [([0, 0, 0], [0.3, 0.3, 0.3])]), entity(3, "box", [([0.3, 0, 0], [0.6, 0.3, 0.3])])]
    g = build_contact_graph(ents)
    assert parents(g) == {"floor_1": "scene", "box_2": "floor_1", "box_3": "floor_1"}
    g.validate()


def test_degenerate_entities_give_clear_results(entity):
    from recon_core.entity import Entity

    ents = [
        entity(1, "floor", [([-2, -2, -0.05], [2, 2, 0])]),
        Entity.from_points(2, "few", "cup", [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0.05]]),
        Entity.from_points(3, "flat", "book", [[0.5, 0.5, 0.0], [0.7, 0.5, 0.0], [0.7, 0.8, 0.0], [0.5, 0.8, 0.0]]),
        Entity.from_points(4, "line", "bottle", [[1, 1, 0.0], [1.2, 1.2, 0.0], [1.4, 1.4, 0.0]]),
        Entity.from_points(5, "point", "box", [[-1, -1, 0.0]]),
        Entity.from_points(6, "empty", "bag", np.zeros((0, 3))),
        Entity.from_points(7, "dup", "cup", [[1, -1, 0.0]] * 5),
    ]
    g = build_contact_graph(ents)
    assert g.skipped == {6: "entity 'empty' (6) has no geometry"}
    assert set(g.nodes) == {ROOT_ID, 1, 2, 3, 4, 5, 7}
    for nid in (2, 3, 4, 5, 7):
        n = g.nodes[nid]
        assert np.all(np.isfinite(n.box.center)) and np.all(np.isfinite(n.box.size)) and np.isfinite(n.box.yaw)
        assert g.supports[nid].parent_id == 1  # everything stands on the floor
        assert np.isfinite(g.supports[nid].score)
    assert g.nodes[4].box.size[0] == pytest.approx(np.hypot(0.4, 0.4)) and g.nodes[4].box.size[1] == pytest.approx(0)
    assert np.allclose(g.nodes[5].box.size, 0) and np.allclose(g.nodes[7].box.size, 0)
    import json

    json.dumps(g.to_dict(), allow_nan=False)  # no NaN anywhere


def test_root_id_is_reserved(entity):
    with pytest.raises(EntityError, match="reserved"):
        build_contact_graph([entity(0, "box", [([0, 0, 0], [1, 1, 1])])])


def test_non_finite_vertices_are_rejected():
    from recon_core.entity import Entity

    with pytest.raises(EntityError, match="non-finite"):
        Entity.from_points(1, "bad", "box", [[0, 0, np.nan]])


def test_unknown_class_becomes_rigid_with_a_warning(entity, caplog):
    with caplog.at_level(logging.WARNING):
        g = build_contact_graph([entity(1, "floor", [([-2, -2, -0.05], [2, 2, 0])]),
                                 entity(2, "teapot_xyz", [([0, 0, 0], [0.2, 0.2, 0.2])])])
    assert g.nodes[2].category == "rigid" and g.supports[2].parent_id == 1
    assert "teapot_xyz" in caplog.text


def test_no_floor_hangs_on_the_root(entity):
    g = build_contact_graph([entity(1, "box", [([0, 0, 0.5], [0.2, 0.2, 0.7])])])
    assert g.supports[1].parent_id == ROOT_ID and g.supports[1].kind == "fallback_root"


def test_ignored_classes_are_left_out(entity):
    g = build_contact_graph([entity(1, "floor", [([-2, -2, -0.05], [2, 2, 0])]),
                             entity(2, "unknown", [([0, 0, 0], [0.5, 0.5, 0.3])]),
                             entity(3, "cup", [([0.1, 0.1, 0.3], [0.2, 0.2, 0.4])])])
    assert 2 not in g.nodes and "ignored" in g.skipped[2]
    assert g.supports[3].parent_id == 1  # the unknown blob cannot carry anything
