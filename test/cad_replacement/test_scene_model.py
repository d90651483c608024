"""The replaced-scene contract: a tree of placed CAD objects with validated poses and supports."""

from __future__ import annotations

import numpy as np
import pytest

from cad_replacement.cad import build_model
from cad_replacement.scene_model import MAP_ROOT, PlacedObject, ReplacedScene
from recon_core.errors import InputError


def _pose(x: float, y: float, z: float, yaw: float = 0.0) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    t = np.eye(4)
    t[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    t[:3, 3] = (x, y, z)
    return t


def test_objects_form_a_tree_and_link_poses_follow_joint_values():
    cabinet = build_model("cabinet", 1)
    table = build_model("table", 0)
    cup = build_model("cup", 0)
    scene = ReplacedScene("room", [
        PlacedObject("cabinet_1", "cabinet", cabinet, _pose(1, 0, 0, np.pi / 2)),
        PlacedObject("table_2", "table", table, _pose(0, 0, 0)),
        PlacedObject("cup_3", "cup", cup, _pose(0.1, 0, float(table.size[2])), parent="table_2",
                     support="floating", movable=True),
    ])
    scene.validate()
    assert [o.name for o in scene.children("table_2")] == ["cup_3"]
    np.testing.assert_allclose(scene.parent_link_pose(scene.object("cup_3")), scene.object("table_2").pose)
    assert scene.parent_link_pose(scene.object("table_2")).tolist() == np.eye(4).tolist()
    joint = cabinet.movable_joints[0]
    closed = scene.object("cabinet_1").link_poses()[joint.child]
    scene.object("cabinet_1").joint_values[joint.name] = 0.5 * (joint.lower + joint.upper)
    opened = scene.object("cabinet_1").link_poses()[joint.child]
    assert not np.allclose(closed, opened)


def test_bad_scenes_are_refused_with_clear_errors():
    table = build_model("table", 0)
    with pytest.raises(InputError, match="rigid"):
        PlacedObject("t", "table", table, np.full((4, 4), np.nan))
    with pytest.raises(InputError, match="support"):
        PlacedObject("t", "table", table, np.eye(4), support="welded")
    orphan = ReplacedScene("s", [PlacedObject("cup", "cup", build_model("cup", 0), np.eye(4), parent="table")])
    with pytest.raises(InputError, match="unknown or listed after"):
        orphan.validate()
    twice = ReplacedScene("s", [PlacedObject("t", "table", table, np.eye(4)),
                                PlacedObject("t", "table", table, np.eye(4))])
    with pytest.raises(InputError, match="duplicate"):
        twice.validate()
    no_link = ReplacedScene("s", [PlacedObject("t", "table", table, np.eye(4)),
                                  PlacedObject("c", "cup", build_model("cup", 0), np.eye(4), parent="t",
                                               parent_link="drawer_9")])
    with pytest.raises(InputError, match="no link"):
        no_link.validate()
    with pytest.raises(InputError, match="no object"):
        no_link.object("ghost")
    assert MAP_ROOT == "map"
