"""Scene actions: joints within limits, placements that rest on a support, refusals that change nothing."""

from __future__ import annotations

import numpy as np
import pytest

from cad_replacement.actions import ActionError, SceneAction, apply_action, penetration, support_spots
from cad_replacement.cad import build_model
from cad_replacement.layout_models import box_model
from cad_replacement.scene_model import PlacedObject, ReplacedScene


def _pose(x: float, y: float, z: float, yaw: float = 0.0) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    t = np.eye(4)
    t[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    t[:3, 3] = (x, y, z)
    return t


@pytest.fixture()
def room() -> ReplacedScene:
    table, shelf, fridge, cup = build_model("table", 0), build_model("shelf", 1), build_model("fridge", 0), \
        build_model("cup", 0)
    top = float(table.size[2])
    scene = ReplacedScene("room", [
        PlacedObject("floor", "floor", box_model("floor", (6, 6, 0.05)), _pose(0, 0, -0.05)),
        PlacedObject("table_1", "table", table, _pose(0, 0, 0), parent="floor"),
        PlacedObject("shelf_1", "shelf", shelf, _pose(2, 0, 0, np.pi), parent="floor"),
        PlacedObject("fridge_1", "fridge", fridge, _pose(-2, 1, 0), parent="floor"),
        PlacedObject("cup_1", "cup", cup, _pose(0.1, 0, top), parent="table_1", support="floating", movable=True),
        PlacedObject("cup_2", "cup", cup, _pose(-0.15, 0.1, top), parent="table_1", support="floating",
                     movable=True),
    ])
    scene.validate()
    return scene


def _state(scene: ReplacedScene) -> list:
    return [(o.name, o.parent, o.parent_link, o.pose.tolist(), sorted(o.joint_values.items())) for o in scene] + \
        [scene.revision]


def _bottom(obj: PlacedObject) -> float:
    return min(float((m.vertices @ obj.pose[:3, :3].T + obj.pose[:3, 3])[:, 2].min())
               for m in obj.model.posed_link_meshes(obj.joint_values).values() if len(m.vertices))


def test_open_the_fridge_door(room):
    door = room.object("fridge_1").model.movable_joints[0]
    opened = apply_action(room, SceneAction("set_joint", joint=f"fridge_1__{door.name}", value=1.0))
    assert opened.object("fridge_1").joint_values[door.name] == pytest.approx(1.0)
    assert opened.revision == room.revision + 1
    assert door.name not in room.object("fridge_1").joint_values  # the original is untouched


@pytest.mark.parametrize("action", [
    SceneAction("set_joint", joint="fridge_1__door_left_0_hinge", value=5.0),  # outside [0, 2]
    SceneAction("set_joint", joint="fridge_1__no_such_joint", value=0.1),
    SceneAction("set_joint", joint="fridge_1__door_left_0_hinge", value=float("nan")),
    SceneAction("move", object_name="ghost", pose=np.eye(4)),
    SceneAction("move", object_name="cup_1", pose=_pose(9.0, 9.0, 0.5)),  # nothing below to rest on
    SceneAction("move", object_name="cup_1", pose=_pose(0.1, 0.0, 0.3)),  # inside the table
    SceneAction("reparent", object_name="table_1", new_parent="cup_1"),  # the table rests on nothing that small
    SceneAction("reparent", object_name="table_1", new_parent="table_1"),
    SceneAction("launch", object_name="cup_1"),
])
def test_bad_actions_are_refused_and_change_nothing(room, action):
    before = _state(room)
    with pytest.raises(ActionError):
        apply_action(room, action)
    assert _state(room) == before


def test_move_a_cup_onto_another_support_rests_on_it(room):
    top = float(room.object("table_1").model.size[2])
    moved = apply_action(room, SceneAction("move", object_name="cup_1", pose=_pose(0.2, 0.2, top + 0.08, 0.3)))
    cup = moved.object("cup_1")
    assert cup.parent == "table_1"
    assert _bottom(cup) == pytest.approx(top, abs=0.005)
    depth, _who = penetration(cup, [o for o in moved if o.name != "cup_1"])
    assert depth <= 0.01


def test_reparent_a_cup_into_the_shelf_and_into_the_fridge(room):
    for parent in ("shelf_1", "fridge_1"):
        placed = apply_action(room, SceneAction("reparent", object_name="cup_1", new_parent=parent))
        cup = placed.object("cup_1")
        assert cup.parent == parent and cup.parent_link
        spots = support_spots(placed.object(parent))
        heights = [s.height for s in spots]
        assert min(abs(_bottom(cup) - h) for h in heights) <= 0.005
        assert penetration(cup, [o for o in placed if o.name != "cup_1"])[0] <= 0.01
        lo, hi = (np.min([m.bounds[0] for m in placed.object(parent).model.posed_link_meshes().values()], axis=0),
                  np.max([m.bounds[1] for m in placed.object(parent).model.posed_link_meshes().values()], axis=0))
        local = np.linalg.inv(placed.object(parent).pose) @ np.r_[cup.pose[:3, 3], 1.0]
        assert np.all(local[:3] >= lo - 1e-6) and np.all(local[:3] <= hi + 1e-6), f"cup not within {parent}"
        if parent == "fridge_1":  # a container: the cup goes inside, on an enclosed shelf
            assert any(s.enclosed and abs(_bottom(cup) - s.height) <= 0.005 for s in spots)


def test_a_tray_carries_what_stands_on_it(room):
    moved = apply_action(room, SceneAction("move", object_name="table_1", pose=_pose(0.5, -1.0, 0.0)))
    shift = moved.object("table_1").pose[:3, 3] - room.object("table_1").pose[:3, 3]
    for cup in ("cup_1", "cup_2"):
        np.testing.assert_allclose(moved.object(cup).pose[:3, 3] - room.object(cup).pose[:3, 3], shift, atol=1e-9)
