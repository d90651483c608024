"""JSON round trip of the contact graph, tree checks, joint table and the URDF kinematic tree."""

from __future__ import annotations

import json

import numpy as np
import pytest

from recon_core.config import ConfigError
from recon_core.contact_graph import ContactGraph, GraphError, SupportEdge
from scene_graph.builder import build_contact_graph
from scene_graph.joints import PairRule, SupportJointTable, load_support_joints
from scene_graph.kinematic import to_kinematic_tree


def test_json_round_trip(room, tmp_path):
    g = build_contact_graph(room, name="room")
    path = g.save(tmp_path / "g.json")
    back = ContactGraph.load(path)
    assert back.to_dict() == json.loads(path.read_text())
    assert back.to_dict() == g.to_dict()
    assert back.format_tree() == g.format_tree()
    assert back.nodes[5].box.iou(g.nodes[5].box) == pytest.approx(1.0)


def test_validate_rejects_broken_trees(room):
    g = build_contact_graph(room)
    g.supports[4] = SupportEdge(5, 4)  # table on the cup on the table: a cycle
    with pytest.raises(GraphError, match="cycle"):
        g.validate()
    g = build_contact_graph(room)
    g.supports[4] = SupportEdge(99, 4)
    with pytest.raises(GraphError, match="unknown parent"):
        g.validate()
    with pytest.raises(GraphError, match="not a contact graph"):
        ContactGraph.from_dict({"format": "something else"})


def test_format_tree_lists_class_score_and_joint(room):
    text = build_contact_graph(room).format_tree()
    lines = text.splitlines()
    assert lines[0] == "scene"
    cup = next(line for line in lines if line.strip().startswith("cup_5"))
    assert "[cup, rigid]" in cup and "score 1.00" in cup and "floating" in cup
    table_indent = next(line for line in lines if "table_4" in line).index("table_4")
    assert cup.index("cup_5") == table_indent + 2


def test_joint_table_resolution_order():
    t = SupportJointTable(default="fixed", movable="floating", layout="fixed", classes={"chair": "fixed"},
                          pairs=[PairRule("table", "cup", "fixed"), PairRule("*", "book", "fixed"),
                                 PairRule("shelf", "*", "floating")])
    assert t.resolve("table", "cup", True, False) == "fixed"  # pair rule beats movable
    assert t.resolve("desk", "cup", True, False) == "floating"  # movable class
    assert t.resolve("desk", "book", True, False) == "fixed"  # wildcard parent
    assert t.resolve("shelf", "box", True, False) == "floating"
    assert t.resolve("floor", "chair", True, False) == "fixed"  # class rule
    assert t.resolve("floor", "wall", False, True) == "fixed"
    assert t.resolve("floor", "table", False, False) == "fixed"
    with pytest.raises(ConfigError):
        SupportJointTable(default="revolute")
    repo = load_support_joints()
    assert repo.resolve("table", "cup", True, False) == "floating"
    assert repo.resolve("floor", "table", False, False) == "fixed"


def test_kinematic_tree_urdf_parses_with_the_right_joint_types(room, tmp_path):
    import yourdfpy

    g = build_contact_graph(room, name="room")
    tree = to_kinematic_tree(g, {e.id: e for e in room})
    path = tree.to_urdf(tmp_path / "urdf", filename="scene.urdf")
    urdf = yourdfpy.URDF.load(str(path), mesh_dir=str(tmp_path / "urdf"))
    assert urdf.validate()
    types = {j.child: j.type for j in urdf.robot.joints}
    assert types["cup_5"] == "floating" and types["book_7"] == "floating"
    assert types["table_4"] == "fixed" and types["wall_2"] == "fixed" and types["floor_1"] == "fixed"
    parents = {j.child: j.parent for j in urdf.robot.joints}
    assert parents["cup_5"] == "table_4" and parents["book_7"] == "shelf_6"
    # Link frames sit at the bottom centre of the refined boxes: forward kinematics puts them back.
    for nid in (4, 5, 7):
        node = g.nodes[nid]
        fk = urdf.get_transform(frame_to=node.name, frame_from="scene")
        np.testing.assert_allclose(fk, node.box.bottom_pose(), atol=1e-6)
    # The link mesh, moved by its link pose, is the entity's mesh in the map frame.
    cup_link = next(link for link in tree.links if link.name == "cup_5")
    moved = cup_link.mesh.copy()
    moved.apply_transform(g.nodes[5].box.bottom_pose())
    np.testing.assert_allclose(np.sort(moved.vertices, axis=0), np.sort(room[4].vertices, axis=0), atol=1e-9)


def test_yaml_config_matches_the_dataclass_defaults(tmp_path):
    import dataclasses

    from scene_graph.config import SceneGraphConfig, load_scene_graph_config

    assert dataclasses.asdict(load_scene_graph_config()) == dataclasses.asdict(SceneGraphConfig())
    bad = tmp_path / "bad.yaml"
    bad.write_text("support:\n  a_tth: -0.9\n")
    with pytest.raises(ConfigError, match="a_tth"):
        load_scene_graph_config(bad)
    bad.write_text("proximal:\n  broadphase: octree\n")
    with pytest.raises(ConfigError, match="broadphase"):
        load_scene_graph_config(bad)
