"""Small hand-made replaced scenes shared by the export and physics tests."""

from __future__ import annotations

import numpy as np

from cad_replacement.cad import build_model
from cad_replacement.scene_model import PlacedObject, ReplacedScene


def yaw_pose(x: float, y: float, z: float, yaw: float = 0.0) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    t = np.eye(4)
    t[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    t[:3, 3] = (x, y, z)
    return t


def drawer_scene(opening: float = 0.5) -> ReplacedScene:
    """A cabinet with a drawer pulled out by ``opening`` of its travel holding a cup, a table with a
    bottle, a box on the floor (no floor model: the box rests on the map root)."""
    for seed in range(200):
        cabinet = build_model("cabinet", seed, overrides={"layout": "drawers"})
        surfaces = [s for s in cabinet.features.support_surfaces
                    if s.link != cabinet.root_link and s.clearance and s.clearance > 0.12]
        if surfaces:
            surface = surfaces[0]
            break
    else:
        raise AssertionError("no cabinet with a deep enough drawer")
    slide = next(j for j in cabinet.movable_joints if j.child == surface.link)
    values = {slide.name: opening * slide.upper}
    cab_pose = yaw_pose(1.0, 0.5, 0.0, np.pi / 2)
    centre = np.r_[surface.polygon.mean(axis=0), surface.height, 1.0]
    cup_at = cab_pose @ cabinet.surface_motion(surface.link, values) @ centre
    table = build_model("table", 1)
    return ReplacedScene("test room", [
        PlacedObject("cabinet_1", "cabinet", cabinet, cab_pose, joint_values=values),
        PlacedObject("cup_1", "cup", build_model("cup", 2), yaw_pose(*cup_at[:3], 0.3), parent="cabinet_1",
                     parent_link=surface.link, support="floating", movable=True),
        PlacedObject("table_1", "table", table, yaw_pose(-1.0, 0.0, 0.0, 0.2)),
        PlacedObject("bottle_1", "bottle", build_model("bottle", 0), yaw_pose(-1.0, 0.1, float(table.size[2])),
                     parent="table_1", support="floating", movable=True),
        PlacedObject("box_1", "box", build_model("box", 0), yaw_pose(0.0, -1.0, 0.0), support="floating",
                     movable=True),
    ])
