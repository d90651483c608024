"""Small hand-made scenes for the sensor-simulation tests (fast: 160x120 images)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from recon_core.frame import CameraIntrinsics
from scene_recon.synthetic import Appearance, RenderItem, RoomBounds, look_at_pose
from scene_recon.synthetic.toy_scene import room_shell

ROOM = RoomBounds(-2.0, 2.0, -1.5, 1.5, 2.5)


def _box(extents, center, label, color, pattern="noise") -> RenderItem:
    mesh = trimesh.creation.box(extents=extents)
    mesh.apply_translation(center)
    return RenderItem(mesh, label, Appearance(color, pattern), f"box_{label}")


@pytest.fixture(scope="session")
def intrinsics() -> CameraIntrinsics:
    return CameraIntrinsics(130.0, 130.0, 79.5, 59.5, 160, 120)


@pytest.fixture(scope="session")
def scene_items() -> list[RenderItem]:
    """Box room (labels 1-6) + two boxes (10, 11) and a sphere (12)."""
    items = room_shell(ROOM)
    items.append(_box((0.6, 0.5, 0.8), (0.8, 0.3, 0.4), 10, (0.8, 0.2, 0.2), "checker"))
    items.append(_box((0.4, 0.4, 0.4), (-0.7, -0.4, 0.2), 11, (0.2, 0.3, 0.85), "stripes"))
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    sphere.apply_translation((0.0, 0.6, 0.3))
    items.append(RenderItem(sphere, 12, Appearance((0.2, 0.8, 0.3), "plain", smooth_shading=True), "sphere"))
    return items


@pytest.fixture(scope="session")
def view_pose() -> np.ndarray:
    """A camera in a room corner looking at the objects (sees floor, walls and all three objects)."""
    return look_at_pose(np.array([-1.6, -1.2, 1.5]), np.array([0.2, 0.2, 0.35]))


@pytest.fixture(scope="session")
def room() -> RoomBounds:
    return ROOM
