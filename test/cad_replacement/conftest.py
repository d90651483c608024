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


# ---------------------------------------------------------------------------- real-layout asset folders
def _glb_scene(parts: list[tuple[tuple[float, float, float], tuple[float, float, float]]]) -> bytes:
    """A glTF scene of boxes, each ``(extents, node translation)``: the geometry is centred and
    only the node transform places it (so an importer ignoring node transforms gets it wrong)."""
    scene = trimesh.Scene()
    for k, (extents, offset) in enumerate(parts):
        scene.add_geometry(
            trimesh.creation.box(extents=extents),
            node_name=f"part{k}",
            geom_name=f"part{k}",
            transform=trimesh.transformations.translation_matrix(offset),
        )
    return scene.export(file_type="glb")


def _write_replica_folder(folder: Path) -> Path:
    """ReplicaCAD-style folder: several URDFs side by side, y-up glTF meshes (front +z).

    ``kitchen_counter.urdf`` (class from the folder meta) refers to its meshes through
    ``package://replica_cad/...`` although the folder has another name; ``fridge.urdf`` (class from
    ``fridge.meta.yaml``) uses relative paths. Source sizes (x width, y height, z depth): counter
    1.2 x 0.9 x 0.6 with a drawer sliding along +z; fridge 0.7 x 1.8 x 0.65, door hinged about +y.
    """
    meshes = folder / "meshes"
    meshes.mkdir(parents=True, exist_ok=True)
    # Counter: carcass plus a top slab, both placed by node transforms (bottom at y = 0).
    (meshes / "counter.glb").write_bytes(_glb_scene([((1.2, 0.86, 0.6), (0.0, 0.43, 0.0)),
                                                      ((1.2, 0.04, 0.6), (0.0, 0.88, 0.0))]))
    (meshes / "counter_drawer.glb").write_bytes(_glb_scene([((0.5, 0.15, 0.02), (0.0, 0.075, 0.01))]))
    (meshes / "fridge_body.glb").write_bytes(_glb_scene([((0.7, 1.2, 0.65), (0.0, 0.6, 0.0)),
                                                          ((0.7, 0.6, 0.65), (0.0, 1.5, 0.0))]))
    (meshes / "fridge_door.glb").write_bytes(_glb_scene([((0.7, 1.8, 0.04), (0.35, 0.9, 0.02))]))
    (folder / "kitchen_counter.urdf").write_text("""<?xml version="1.0"?>
<robot name="kitchen_counter">
  <link name="base">
    <visual><geometry><mesh filename="package://replica_cad/meshes/counter.glb"/></geometry></visual>
  </link>
  <link name="drawer1">
    <visual><geometry><mesh filename="package://replica_cad/meshes/counter_drawer.glb"/></geometry></visual>
  </link>
  <joint name="drawer1_joint" type="prismatic">
    <parent link="base"/><child link="drawer1"/>
    <origin xyz="0 0.5 0.3" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="0" upper="0.4"/>
  </joint>
</robot>
""")
    (folder / "fridge.urdf").write_text("""<?xml version="1.0"?>
<robot name="fridge">
  <link name="body">
    <visual><geometry><mesh filename="meshes/fridge_body.glb"/></geometry></visual>
  </link>
  <link name="door">
    <visual><geometry><mesh filename="./meshes/fridge_door.glb"/></geometry></visual>
  </link>
  <joint name="door_hinge" type="revolute">
    <parent link="body"/><child link="door"/>
    <origin xyz="-0.35 0 0.325"/><axis xyz="0 1 0"/>
    <limit lower="-1.9" upper="0"/>
  </joint>
</robot>
""")
    (folder / "meta.yaml").write_text("class: cabinet\n")
    (folder / "fridge.meta.yaml").write_text("class: fridge\n")
    return folder


def _boxes_mesh(boxes: list[tuple[tuple[float, float, float], tuple[float, float, float]]],
                max_edge: float | None = None) -> trimesh.Trimesh:
    """Concatenated axis-aligned boxes ``(lo, hi)``, optionally subdivided into small triangles."""
    parts = []
    for lo, hi in boxes:
        box = trimesh.creation.box(bounds=[lo, hi])
        if max_edge is not None:
            v, f = trimesh.remesh.subdivide_to_size(box.vertices, box.faces, max_edge=max_edge)
            box = trimesh.Trimesh(v, f)
        parts.append(box)
    return trimesh.util.concatenate(parts)


#: Sektion carcass in its source frame (z up, x front, origin at the centre): 0.5 deep, 0.8 wide,
#: 0.9 high, 2 cm panels; the top is four planks with 1 mm gaps, a shelf at z = 0..0.02 splits it,
#: a 2 cm plinth stands below the doors.
SEKTION_PANELS = [
    *[((-0.25, y0, 0.43), (0.25, y1, 0.45)) for y0, y1 in
      ((-0.4, -0.2005), (-0.1995, -0.0005), (0.0005, 0.1995), (0.2005, 0.4))],  # top planks
    ((-0.25, -0.4, -0.45), (0.25, 0.4, -0.43)),  # bottom
    ((-0.25, -0.4, -0.43), (0.25, -0.38, 0.43)),  # right side
    ((-0.25, 0.38, -0.43), (0.25, 0.4, 0.43)),  # left side
    ((-0.25, -0.38, -0.43), (-0.23, 0.38, 0.43)),  # back
    ((-0.23, -0.38, 0.0), (0.25, 0.38, 0.02)),  # shelf
    ((0.23, -0.38, -0.43), (0.25, 0.38, -0.35)),  # plinth
]
#: Drawer in its link frame (the joint sits on the carcass front at z = 0.03): tray and front.
SEKTION_DRAWER = [
    ((-0.45, -0.36, 0.0), (0.0, 0.36, 0.01)),  # bottom
    ((-0.45, -0.37, 0.0), (0.0, -0.36, 0.15)),
    ((-0.45, 0.36, 0.0), (0.0, 0.37, 0.15)),
    ((-0.46, -0.37, 0.0), (-0.45, 0.37, 0.15)),
    ((0.0, -0.39, -0.01), (0.02, 0.39, 0.39)),  # front panel
]


def _write_sektion_package(folder: Path, *, collision_mesh: str = "package://sektion_cabinet_model/meshes/"
                           "drawer_collision.stl") -> Path:
    """Isaac/Franka ``sektion_cabinet_model`` layout: ``urdf/`` + ``meshes/``, package:// paths.

    A cabinet with a prismatic drawer and two revolute doors (left about +z, right about -z),
    comma-separated xyz/rpy, collision boxes/cylinder/mesh, inertials (one rotated, one mass 0),
    limits without effort/velocity (as PartNet and many exports), OBJ and STL meshes. The carcass
    OBJ is subdivided into thousands of small triangles.
    """
    meshes, urdf_dir = folder / "meshes", folder / "urdf"
    meshes.mkdir(parents=True, exist_ok=True)
    urdf_dir.mkdir(exist_ok=True)
    _boxes_mesh(SEKTION_PANELS, max_edge=0.05).export(meshes / "sektion.obj")
    _boxes_mesh(SEKTION_DRAWER).export(meshes / "drawer.stl")
    trimesh.creation.box(bounds=[(-0.46, -0.37, 0.0), (0.02, 0.37, 0.15)]).export(meshes / "drawer_collision.stl")
    trimesh.creation.box(bounds=[(0.0, -0.39, 0.0), (0.02, 0.0, 0.34)]).export(meshes / "door_left.obj")
    trimesh.creation.box(bounds=[(0.0, 0.0, 0.0), (0.02, 0.39, 0.34)]).export(meshes / "door_right.obj")
    trimesh.creation.box(bounds=[(0.0, -0.01, -0.05), (0.03, 0.01, 0.05)]).export(meshes / "handle.stl")
    pkg = "package://sektion_cabinet_model/meshes"
    panels = "\n".join(
        f'    <collision name="panel{k}"><origin xyz="{(lo[0] + hi[0]) / 2},{(lo[1] + hi[1]) / 2},'
        f'{(lo[2] + hi[2]) / 2}" rpy="0,0,0"/><geometry><box size="{hi[0] - lo[0]} {hi[1] - lo[1]} '
        f'{hi[2] - lo[2]}"/></geometry></collision>'
        for k, (lo, hi) in enumerate(SEKTION_PANELS[4:], start=1)
    )
    (urdf_dir / "sektion_cabinet.urdf").write_text(f"""<?xml version="1.0"?>
<robot name="cabinet_sektion">
  <material name="White"><color rgba="0.85,0.85,0.85,1.0"/></material>
  <link name="sektion">
    <inertial>
      <origin xyz="0 0 0.1" rpy="0 0 1.5707963267948966"/>
      <mass value="20.0"/>
      <inertia ixx="1.0" ixy="0" ixz="0" iyy="2.0" iyz="0" izz="3.0"/>
    </inertial>
    <visual name="sektion_visual"><origin xyz="0 0 0" rpy="0 0 0"/>
      <geometry><mesh filename="{pkg}/sektion.obj"/></geometry><material name="White"/></visual>
    <collision name="top"><origin xyz="0,0,0.44"/><geometry><box size="0.5,0.8,0.02"/></geometry></collision>
{panels}
  </link>
  <link name="drawer_top">
    <inertial><mass value="2.0"/><inertia ixx="0.02" ixy="0" ixz="0" iyy="0.03" iyz="0" izz="0.04"/></inertial>
    <visual><geometry><mesh filename="{pkg}/drawer.stl"/></geometry></visual>
    <collision><geometry><mesh filename="{collision_mesh}"/></geometry></collision>
  </link>
  <link name="door_left">
    <visual><geometry><mesh filename="{pkg}/door_left.obj"/></geometry></visual>
    <collision><origin xyz="0.01, -0.195, 0.17"/><geometry><box size="0.02 0.39 0.34"/></geometry></collision>
  </link>
  <link name="door_right">
    <visual><geometry><mesh filename="../meshes/door_right.obj"/></geometry></visual>
  </link>
  <link name="door_left_handle">
    <inertial><mass value="0"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>
    <visual><geometry><mesh filename="{pkg}/handle.stl"/></geometry></visual>
    <collision><origin xyz="0.03 0 0" rpy="0 1.5707963267948966 0"/>
      <geometry><cylinder radius="0.01" length="0.06"/></geometry></collision>
  </link>
  <joint name="drawer_top_joint" type="prismatic">
    <parent link="sektion"/><child link="drawer_top"/>
    <origin xyz="0.25,0,0.03" rpy="0,0,0"/><axis xyz="1,0,0"/>
    <limit lower="0" upper="0.4"/>
  </joint>
  <joint name="door_left_joint" type="revolute">
    <parent link="sektion"/><child link="door_left"/>
    <origin xyz="0.25, 0.39, -0.35"/><axis xyz="0 0 1"/>
    <limit lower="0" upper="1.57" effort="10" velocity="1"/>
  </joint>
  <joint name="door_right_joint" type="revolute">
    <parent link="sektion"/><child link="door_right"/>
    <origin xyz="0.25,-0.39,-0.35" rpy="0,0,0"/><axis xyz="0,0,-1"/>
    <limit lower="0" upper="1.57"/>
  </joint>
  <joint name="door_left_handle_joint" type="fixed">
    <parent link="door_left"/><child link="door_left_handle"/>
    <origin xyz="0.02 -0.35 0.2"/>
  </joint>
</robot>
""")
    return urdf_dir / "sektion_cabinet.urdf"


@pytest.fixture
def write_replica_folder() -> Callable[[Path], Path]:
    """Writer of a ReplicaCAD-style multi-URDF folder (see ``_write_replica_folder``)."""
    return _write_replica_folder


@pytest.fixture
def write_sektion_package() -> Callable[..., Path]:
    """Writer of an Isaac ``sektion_cabinet_model`` package; returns the URDF path."""
    return _write_sektion_package
