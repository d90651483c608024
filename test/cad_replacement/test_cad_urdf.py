"""URDF import (external models written by the test) and export round trips through yourdfpy."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
import yourdfpy

from cad_replacement.cad import build_model, export_urdf, import_urdf_folder, import_urdf_model, write_urdf
from recon_core.errors import CadImportError
from recon_core.geometry.transforms import rotation_about


def test_external_urdf_imports_with_joints(tmp_path: Path, write_external_model) -> None:
    path = write_external_model(tmp_path / "cabinet" / "m001")
    m = import_urdf_model(path, class_name="cabinet")
    assert m.class_name == "cabinet" and m.model_id == "m001"
    assert {lk.name for lk in m.links} == {"base", "door__left_", "drawer", "handle_frame"}
    types = {j.name: j.type for j in m.joints}
    assert types == {"door_hinge": "revolute", "drawer_slide": "prismatic", "handle_fixed": "fixed"}
    hinge = m.joint("door_hinge")
    assert (hinge.lower, hinge.upper) == (0.0, 1.5)
    # Canonical frame: origin at the bottom centre of the closed model (the door adds 2 cm in front).
    assert m.size == pytest.approx([0.52, 0.6, 0.8], abs=1e-6)
    lo = m.mesh().bounds[0]
    assert lo == pytest.approx([-0.26, -0.3, 0.0], abs=1e-6)
    # Kinematics survive: the drawer slides along +x, the door turns about z.
    q0, q1 = m.link_poses(), m.link_poses({"drawer_slide": 0.3, "door_hinge": 1.0})
    assert (q1["drawer"][:3, 3] - q0["drawer"][:3, 3]) == pytest.approx([0.3, 0.0, 0.0])
    assert q1["door__left_"][:3, :3] == pytest.approx(rotation_about((0, 0, 1), 1.0)[:3, :3])
    assert q1["handle_frame"][:3, 3] - q1["drawer"][:3, 3] == pytest.approx([0.2, 0.0, 0.0])
    # Features were computed by RANSAC: the top of the base is a support plane.
    assert any(p.support and abs(p.d + 0.8) < 0.02 for p in m.features.planes)
    assert len(m.features.planes) >= 4


def test_meta_yaml_rotates_y_up_models(tmp_path: Path, write_external_model) -> None:
    folder = tmp_path / "m_yup"
    write_external_model(folder, up="+y", extra_meta="scale: 2.0\nmodel_id: 'my model!'\n")
    m = import_urdf_model(folder)  # class from meta.yaml
    assert m.class_name == "cabinet" and m.model_id == "my_model_"
    # Source y (0.6) is up now, scaled by 2; source z (0.8) becomes the width.
    assert m.size == pytest.approx([1.04, 1.6, 1.2], abs=1e-6)
    hinge = m.joint("door_hinge")
    world_axis = m.link_poses()["door__left_"][:3, :3] @ hinge.axis
    assert abs(world_axis @ [0.0, 1.0, 0.0]) == pytest.approx(1.0)  # source z axis -> canonical y
    slide = m.joint("drawer_slide")
    assert slide.upper == pytest.approx(0.6)  # prismatic limits scale with the model


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda t: t.replace("</robot>", ""), "well-formed"),
        (lambda t: t[: len(t) // 2], "well-formed"),
        (lambda t: t.replace("<robot", "<rowboat").replace("</robot>", "</rowboat>"), "<robot>"),
        (lambda t: t.replace("parts/base.stl", "parts/missing.stl"), "not found"),
        (lambda t: t.replace("parts/base.stl", "../../../etc/passwd"), "outside the model folder"),
        (lambda t: t.replace("parts/base.stl", "file:///etc/passwd"), "outside the model folder"),
        (lambda t: t.replace("package://whatever/parts", "package://whatever/../../parts"), "outside the model"),
        (lambda t: t.replace('xyz="0.25 0.3 -0.2"', 'xyz="0.25,0.3"'), "must hold 3 finite numbers"),
        (lambda t: t.replace('<axis xyz="1 0 0"/>', '<axis xyz="1,zero,0"/>'), "must hold 3 finite numbers"),
        (lambda t: t.replace('type="revolute"', 'type="revolute" ').replace('upper="1.5"', ""), "limit"),
        (lambda t: t.replace('type="revolute"', 'type="floating"'), "unsupported"),
        (lambda t: t.replace('lower="0" upper="1.5"', 'lower="1" upper="0.5"'), "empty range"),
        (lambda t: t.replace('<child link="drawer"/>', '<child link="ghost"/>'), "unknown links"),
        (lambda t: t.replace('<child link="handle_frame"/>', '<child link="base"/>'), "one root link"),
        (lambda t: t.replace('<link name="drawer">', '<link name="base">'), "duplicate link"),
    ],
)
def test_corrupted_urdf_raises_cad_import_error(tmp_path: Path, write_external_model, mutate, message: str) -> None:
    path = write_external_model(tmp_path / "bad")
    path.write_text(mutate(path.read_text()))
    with pytest.raises(CadImportError, match=message):
        import_urdf_model(path, class_name="cabinet")


def test_broken_mesh_file_and_missing_class(tmp_path: Path, write_external_model) -> None:
    path = write_external_model(tmp_path / "broken")
    (tmp_path / "broken" / "parts" / "door.obj").write_text("this is not an obj file\n")
    with pytest.raises(CadImportError, match="door"):
        import_urdf_model(path, class_name="cabinet")
    ok = write_external_model(tmp_path / "noclass")
    with pytest.raises(CadImportError, match="class"):
        import_urdf_model(ok)
    (tmp_path / "noclass" / "meta.yaml").write_text("class: cabinet\nup_axis: '+q'\n")
    with pytest.raises(CadImportError, match="up_axis"):
        import_urdf_model(ok)
    with pytest.raises(CadImportError, match="no such"):
        import_urdf_model(tmp_path / "nothing.urdf", class_name="cabinet")


@pytest.mark.parametrize(("class_name", "seed"), [("cabinet", 0), ("fridge", 2), ("bed", 1), ("oven", 3)])
def test_export_round_trip_through_yourdfpy(tmp_path: Path, class_name: str, seed: int) -> None:
    model = build_model(class_name, seed)
    path = write_urdf(model, tmp_path)
    urdf = yourdfpy.URDF.load(str(path))
    assert urdf.validate()
    assert set(urdf.link_map) == {lk.name for lk in model.links}
    assert urdf.base_link == model.root_link
    q = {j.name: 0.7 * j.upper for j in model.movable_joints}
    urdf.update_cfg(q)
    poses = model.link_poses(q)
    for name, pose in poses.items():
        assert urdf.get_transform(name, urdf.base_link) == pytest.approx(pose, abs=1e-9)
    for j in model.movable_joints:
        uj = urdf.joint_map[j.name]
        assert (uj.limit.lower, uj.limit.upper) == pytest.approx((j.lower, j.upper))
    # Inertials: mass = collision volume x density (class table), the shapes' full inertia tensor.
    body = urdf.link_map[model.root_link]
    assert body.inertial.mass > 1.0
    assert np.all(np.diag(body.inertial.inertia) > 0.0)
    # The exported meshes load back and match the model's closed geometry.
    scene_bounds = urdf.scene.bounds
    assert scene_bounds == pytest.approx(model.mesh(q).bounds, abs=1e-5)


def test_export_then_import_preserves_model(tmp_path: Path) -> None:
    model = build_model("wardrobe", 5)
    path = write_urdf(model, tmp_path / "out", mesh_format="obj")
    back = import_urdf_model(path, class_name="wardrobe", compute_features=False)
    assert back.size == pytest.approx(model.size, abs=1e-5)
    q = {j.name: 0.5 * j.upper for j in model.movable_joints}
    for name, pose in model.link_poses(q).items():
        assert back.link_poses(q)[name] == pytest.approx(pose, abs=1e-5)


def test_export_escapes_and_sanitises_names(tmp_path: Path) -> None:
    model = build_model("box", 0)
    text = export_urdf(model, tmp_path, robot_name='evil"<robot>&', density=100.0, name_prefix="a b/")
    assert 'name="evil__robot__"' in text
    assert 'name="a_b_body"' in text
    assert (tmp_path / "a_b_body.stl").is_file()
    (tmp_path / "m.urdf").write_text(text)
    urdf = yourdfpy.URDF.load(str(tmp_path / "m.urdf"))
    mass = urdf.link_map["a_b_body"].inertial.mass
    assert mass == pytest.approx(model.link("body").mesh.volume * 100.0)


# ---------------------------------------------------------------------------- real asset layouts
def test_replica_folder_imports_every_urdf_z_up(tmp_path: Path, write_replica_folder) -> None:
    folder = write_replica_folder(tmp_path / "replica")
    models = {m.model_id: m for m in import_urdf_folder(folder)}
    assert set(models) == {"fridge", "kitchen_counter"}  # one model per URDF, ids from the stems
    counter, fridge = models["kitchen_counter"], models["fridge"]
    assert (counter.class_name, fridge.class_name) == ("cabinet", "fridge")  # folder meta, per-URDF meta
    assert (counter.params["up_source"], counter.params["up_axis"], counter.params["front_axis"]) == (
        "gltf", "+y", "+z")
    # glTF y (height) -> z, glTF z (front) -> x, glTF x (width) -> y; the drawer front adds 2 cm.
    assert counter.size == pytest.approx([0.62, 1.2, 0.9], abs=1e-6)
    assert fridge.size == pytest.approx([0.69, 0.7, 1.8], abs=1e-6)  # both scene nodes placed
    for m in models.values():
        lo, hi = m.mesh().bounds
        assert lo[2] == pytest.approx(0.0, abs=1e-9)
        assert lo[:2] + hi[:2] == pytest.approx([0.0, 0.0], abs=1e-9)
    # The joints turned with the meshes: the drawer slides to the front, the hinge is vertical.
    q0, q1 = counter.link_poses(), counter.link_poses({"drawer1_joint": 0.3})
    assert q1["drawer1"][:3, 3] - q0["drawer1"][:3, 3] == pytest.approx([0.3, 0.0, 0.0])
    hinge = fridge.joint("door_hinge")
    assert abs(fridge.link_poses()["door"][:3, :3] @ hinge.axis @ [0.0, 0.0, 1.0]) == pytest.approx(1.0)
    assert fridge.mesh({"door_hinge": -1.5}).bounds[1][0] > fridge.mesh().bounds[1][0] + 0.5  # opens forward
    # The counter top is a horizontal support surface at the top, open above.
    tops = [s for s in counter.features.support_surfaces if abs(s.height - 0.9) < 1e-6]
    assert len(tops) == 1 and tops[0].area == pytest.approx(0.72, rel=0.02)
    assert tops[0].clearance is None and not tops[0].enclosed


def test_replica_folder_meta_and_ambiguities(tmp_path: Path, write_replica_folder) -> None:
    folder = write_replica_folder(tmp_path / "replica")
    with pytest.raises(CadImportError, match="several models"):
        import_urdf_model(folder)  # a folder of several URDFs is imported with import_urdf_folder
    # An explicit up axis wins over the glTF convention (here: the data is taken as z-up).
    (folder / "kitchen_counter.meta.yaml").write_text("up_axis: '+z'\nfront_axis: '+x'\n")
    m = import_urdf_model(folder / "kitchen_counter.urdf")
    assert m.params["up_source"] == "meta" and m.class_name == "cabinet" and m.model_id == "kitchen_counter"
    assert m.size == pytest.approx([1.2, 0.9, 0.62], abs=1e-6)
    # glTF mixed with a z-up format: no convention applies, the user must say.
    trimesh.creation.box(extents=(0.7, 1.8, 0.04)).export(folder / "meshes" / "door.obj")
    urdf = folder / "fridge.urdf"
    urdf.write_text(urdf.read_text().replace("./meshes/fridge_door.glb", "meshes/door.obj"))
    with pytest.raises(CadImportError, match=r"up axis is ambiguous.*up_axis"):
        import_urdf_model(urdf)
    # A folder-wide model_id would name every model of the folder alike.
    (folder / "meta.yaml").write_text("class: cabinet\nmodel_id: counter\n")
    with pytest.raises(CadImportError, match=r"model_id.*ambiguous"):
        import_urdf_model(folder / "kitchen_counter.urdf")


def test_sektion_package_imports_joints_and_physics(tmp_path: Path, write_sektion_package) -> None:
    urdf = write_sektion_package(tmp_path / "sektion_cabinet_model")
    m = import_urdf_model(urdf, class_name="cabinet")
    assert m.model_id == "sektion_cabinet_model" and m.params["up_source"] == "urdf"
    assert len(m.link("sektion").mesh.faces) > 2000  # the carcass is a fine triangle mesh
    # z-up source: only moved (bottom centre to the origin); the door handle sticks out 5 cm.
    assert m.size == pytest.approx([0.55, 0.8, 0.9], abs=1e-6)
    lo, hi = m.mesh().bounds
    assert lo[2] == pytest.approx(0.0, abs=1e-9) and hi[2] == pytest.approx(0.9, abs=1e-9)
    joints = {j.name: (j.type, j.lower, j.upper) for j in m.joints}
    assert joints == {
        "drawer_top_joint": ("prismatic", 0.0, 0.4),
        "door_left_joint": ("revolute", 0.0, 1.57),
        "door_right_joint": ("revolute", 0.0, 1.57),
        "door_left_handle_joint": ("fixed", 0.0, 0.0),
    }
    q = {"drawer_top_joint": 0.3, "door_left_joint": 1.0, "door_right_joint": 1.0}
    poses, closed = m.link_poses(q), m.link_poses()
    assert poses["drawer_top"][:3, 3] - closed["drawer_top"][:3, 3] == pytest.approx([0.3, 0.0, 0.0])
    assert poses["door_left"][:3, :3] == pytest.approx(rotation_about((0, 0, 1), 1.0)[:3, :3])
    assert poses["door_right"][:3, :3] == pytest.approx(rotation_about((0, 0, 1), -1.0)[:3, :3])
    front = m.mesh().bounds[1][0]
    for door in ("door_left", "door_right"):  # both doors swing out to the front
        assert m.posed_link_meshes(q)[door].bounds[1][0] > front + 0.2

    # <collision> elements carried, moved with the model: 7 carcass boxes, the drawer's mesh, a cylinder.
    body = m.link("sektion")
    assert body.collisions is not None and [s.kind for s in body.collisions] == ["box"] * 7
    top, bottom = body.collisions[0], body.collisions[1]
    assert top.origin[:3, 3] == pytest.approx([-0.025, 0.0, 0.89]) and top.size == pytest.approx([0.5, 0.8, 0.02])
    assert bottom.origin[:3, 3] == pytest.approx([-0.025, 0.0, 0.01])
    (drawer_piece,) = m.link("drawer_top").collisions or ()
    assert drawer_piece.kind == "mesh" and drawer_piece.mesh is not None
    corners = drawer_piece.mesh.bounds + drawer_piece.origin[:3, 3]
    assert corners == pytest.approx(np.array([[-0.46, -0.37, 0.0], [0.02, 0.37, 0.15]]), abs=1e-6)  # STL: float32
    (handle,) = m.link("door_left_handle").collisions or ()
    assert (handle.kind, handle.radius, handle.length) == ("cylinder", 0.01, 0.06)
    assert handle.origin[:3, :3] @ [0.0, 0.0, 1.0] == pytest.approx([1.0, 0.0, 0.0], abs=1e-9)
    assert m.link("door_right").collisions is None  # none given: the exporter derives them
    # <inertial>: mass as given, inertia rotated into link axes by its rpy, COM moved with the model.
    inertial = body.inertial
    assert inertial is not None and inertial.mass == 20.0
    assert inertial.inertia == pytest.approx(np.diag([2.0, 1.0, 3.0]), abs=1e-9)
    assert inertial.center_of_mass == pytest.approx([-0.025, 0.0, 0.55])
    assert m.link("drawer_top").inertial is not None and m.link("drawer_top").inertial.mass == 2.0
    assert m.link("door_left_handle").inertial is None  # mass 0: "static", left to the exporter

    # The exporter writes what the asset says instead of recomputing it.
    exported = yourdfpy.URDF.load(str(write_urdf(m, tmp_path / "out", density=500.0)))
    assert exported.link_map["sektion"].inertial.mass == pytest.approx(20.0)
    assert len(exported.link_map["sektion"].collisions) == 7
    assert exported.link_map["sektion"].collisions[0].geometry.box is not None

    # Support surfaces: the real horizontal ones only -- top (four planks, one surface), shelf,
    # drawer bottom, carcass floor; no plinth, panel edges, drawer-front edge or rim of side panels.
    surfaces = sorted(m.features.support_surfaces, key=lambda s: s.height)
    assert [s.height for s in surfaces] == pytest.approx([0.02, 0.47, 0.49, 0.9], abs=0.005)
    assert [s.link for s in surfaces] == ["sektion", "sektion", "drawer_top", "sektion"]
    assert surfaces[-1].area == pytest.approx(0.4, rel=0.02) and surfaces[-1].clearance is None
    assert surfaces[2].area == pytest.approx(0.45 * 0.72, rel=0.05) and surfaces[2].enclosed
    assert all(s.area > 0.3 for s in surfaces)
    assert not import_urdf_model(urdf, class_name="cabinet", collisions=False, compute_features=False).link(
        "sektion").collisions


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda t: t.replace('xyz="0.25,0,0.03"', 'xyz="0.25,0"'), r"line \d+: <origin xyz='0.25,0'> must hold 3"),
        (lambda t: t.replace('size="0.5,0.8,0.02"', 'size="0.5,0.8,nan"'), "must hold 3 finite numbers"),
        (lambda t: t.replace('ixx="1.0"', 'ixx="-5.0"'), "not positive semi-definite"),
        (lambda t: t.replace('<mass value="2.0"/>', '<mass value="-2.0"/>'), "mass -2.0"),
        (lambda t: t.replace("meshes/drawer_collision.stl", "meshes/../../../drawer.stl"), "outside the model"),
        (lambda t: t.replace("../meshes/door_right.obj", "../../door_right.obj"), "outside the model folder"),
        (lambda t: t.replace("package://sektion_cabinet_model/meshes/handle.stl", "http://x.org/h.stl"),
         "unsupported URI scheme"),
        (lambda t: t.replace("meshes/sektion.obj", "meshes/sektion.fbx"), "not found"),
        (lambda t: t.replace('<cylinder radius="0.01"', '<cylinder radius="-0.01"'), "collision"),
        (lambda t: t.replace('type="prismatic"', 'type="planar"'), "unsupported"),
    ],
)
def test_malformed_sektion_files_raise_cad_import_error(
    tmp_path: Path, write_sektion_package, mutate, message: str
) -> None:
    urdf = write_sektion_package(tmp_path / "sektion_cabinet_model")
    urdf.write_text(mutate(urdf.read_text()))
    with pytest.raises(CadImportError, match=message) as info:
        import_urdf_model(urdf, class_name="cabinet")
    assert str(urdf) in str(info.value)  # the message names the file


def test_broken_glb_and_empty_scene(tmp_path: Path, write_replica_folder) -> None:
    folder = write_replica_folder(tmp_path / "replica")
    (folder / "meshes" / "fridge_door.glb").write_bytes(b"glTF" + b"\0" * 20)
    with pytest.raises(CadImportError, match=r"fridge_door\.glb"):
        import_urdf_model(folder / "fridge.urdf")
    points = trimesh.Scene(trimesh.PointCloud([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.0, 1.0, 0.0]]))
    (folder / "meshes" / "fridge_door.glb").write_bytes(points.export(file_type="glb"))  # no triangles
    with pytest.raises(CadImportError, match=r"fridge_door\.glb holds no triangles"):
        import_urdf_model(folder / "fridge.urdf")


def test_folder_import_reports_broken_urdfs_and_keeps_the_rest(tmp_path: Path, write_replica_folder) -> None:
    folder = write_replica_folder(tmp_path / "replica")
    (folder / "fridge.urdf").write_text("<robot name='fridge'><link name='a'/>")
    with pytest.raises(CadImportError, match="well-formed"):
        import_urdf_folder(folder)
    failed: list[Path] = []
    models = import_urdf_folder(folder, compute_features=False, on_error=lambda path, exc: failed.append(path))
    assert [m.model_id for m in models] == ["kitchen_counter"] and failed == [folder / "fridge.urdf"]
