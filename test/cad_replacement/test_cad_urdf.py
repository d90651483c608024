"""URDF import (external models written by the test) and export round trips through yourdfpy."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yourdfpy

from cad_replacement.cad import build_model, export_urdf, import_urdf_model, write_urdf
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
