"""Fixtures shared by the CAD library tests."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
import trimesh

BASE_EXTENTS = (0.5, 0.6, 0.8)  # source frame: x, y, z


def _write_external_model(folder: Path, *, up: str = "+z", extra_meta: str = "") -> Path:
    """A cabinet-like model: base box, a revolute door (.obj) and a prismatic drawer (.stl)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "parts").mkdir(exist_ok=True)
    trimesh.creation.box(extents=BASE_EXTENTS).export(folder / "parts" / "base.stl")
    door = trimesh.creation.box(extents=(0.02, 0.3, 0.4))
    door.apply_translation((0.01, -0.15, 0.2))  # hinge line along the link's z axis
    door.export(folder / "parts" / "door.obj")
    trimesh.creation.box(extents=(0.4, 0.25, 0.15)).export(folder / "parts" / "drawer.stl")
    urdf = """<?xml version="1.0"?>
<robot name="test cabinet">
  <link name="base">
    <visual><geometry><mesh filename="parts/base.stl"/></geometry></visual>
  </link>
  <link name="door (left)">
    <visual><origin xyz="0 0 0" rpy="0 0 0"/><geometry><mesh filename="package://whatever/parts/door.obj"/></geometry></visual>
  </link>
  <link name="drawer">
    <visual><geometry><mesh filename="./parts/drawer.stl"/></geometry></visual>
  </link>
  <link name="handle_frame"/>
  <joint name="door hinge" type="revolute">
    <parent link="base"/><child link="door (left)"/>
    <origin xyz="0.25 0.3 -0.2" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="0" upper="1.5" effort="1" velocity="1"/>
  </joint>
  <joint name="drawer_slide" type="prismatic">
    <parent link="base"/><child link="drawer"/>
    <origin xyz="0.05 -0.15 0.2" rpy="0 0 0"/><axis xyz="1 0 0"/>
    <limit lower="0" upper="0.3" effort="1" velocity="1"/>
  </joint>
  <joint name="handle_fixed" type="fixed">
    <parent link="drawer"/><child link="handle_frame"/><origin xyz="0.2 0 0"/>
  </joint>
</robot>
"""
    path = folder / "mobility.urdf"
    path.write_text(urdf)
    if up != "+z" or extra_meta:
        (folder / "meta.yaml").write_text(f"class: cabinet\nup_axis: '{up}'\nfront_axis: '+x'\n{extra_meta}")
    return path


@pytest.fixture
def write_external_model() -> Callable[..., Path]:
    """Writer of a small external URDF model (see ``_write_external_model``)."""
    return _write_external_model
