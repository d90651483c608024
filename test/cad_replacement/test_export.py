"""Scene export: URDF (FK = scene poses), per-object URDFs, MJCF for MuJoCo, GLB, finite numbers."""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest
import trimesh
import yourdfpy
from testsupport.scenes import drawer_scene

from cad_replacement.cad import build_model
from cad_replacement.export import SEP, export_scene, scene_to_tree, subtree
from cad_replacement.scene_model import MAP_ROOT, PlacedObject, ReplacedScene
from recon_core.errors import InputError


@pytest.fixture(scope="module")
def scene() -> ReplacedScene:
    return drawer_scene()


@pytest.fixture(scope="module")
def exported(scene, tmp_path_factory):
    return export_scene(scene, tmp_path_factory.mktemp("export") / "scene")


def test_tree_names_joints_and_support(scene):
    tree = scene_to_tree(scene)
    assert tree.root == MAP_ROOT
    by_child = {j.child: j for j in tree.joints}
    assert by_child["cabinet_1"].type == "fixed" and by_child["box_1"].type == "floating"
    cup_joint = by_child["cup_1"]
    assert cup_joint.type == "floating" and cup_joint.parent == f"cabinet_1{SEP}{scene.object('cup_1').parent_link}"
    cabinet = scene.object("cabinet_1").model
    for j in cabinet.movable_joints:
        tj = next(t for t in tree.joints if t.name == f"cabinet_1{SEP}{j.name}")
        assert (tj.type, tj.lower, tj.upper, tj.effort, tj.velocity) == (j.type, j.lower, j.upper, j.effort, j.velocity)
    poses = tree.link_poses()
    for obj in scene:
        for link, pose in obj.link_poses().items():
            name = obj.name if link == obj.model.root_link else f"{obj.name}{SEP}{link}"
            np.testing.assert_allclose(poses[name], pose, atol=1e-12)
    # masses from collision volume x class density; positive-definite inertias
    for lk in tree.links[1:]:
        assert lk.inertial is not None and lk.inertial.mass > 0
        assert np.linalg.eigvalsh(lk.inertial.inertia).min() > 0
    static = subtree(tree, tree.root)
    assert {"cup_1", "bottle_1", "box_1"}.isdisjoint(lk.name for lk in static.links)


def test_the_tree_is_rooted_at_the_scenes_frame(scene):
    """A map built in another TF frame (the mapper node's gravity-aligned `map_gravity`): the URDF's root
    link, and so the parent of every TF the replacer publishes, is that frame, not a `map` it is not in."""
    aligned = ReplacedScene(scene.name, list(scene), frame_id="map_gravity", revision=scene.revision)
    tree = scene_to_tree(aligned)
    assert tree.root == "map_gravity" and MAP_ROOT not in {lk.name for lk in tree.links}
    assert {j.parent for j in tree.joints if j.child == "cabinet_1"} == {"map_gravity"}
    same = scene_to_tree(scene).link_poses()
    for name, pose in tree.link_poses().items():  # the same kinematics below the root
        np.testing.assert_allclose(pose, same[MAP_ROOT if name == "map_gravity" else name], atol=1e-12)


def test_urdf_parses_and_forward_kinematics_match_the_scene(scene, exported):
    robot = yourdfpy.URDF.load(str(exported.urdf), load_meshes=True, build_collision_scene_graph=True,
                               load_collision_meshes=True)
    assert robot.validate()
    states = json.loads(exported.joint_states.read_text())
    robot.update_cfg({k: v for k, v in states["joints"].items() if k in robot.actuated_joint_names})
    for obj in scene:
        for link, pose in obj.link_poses().items():
            name = obj.name if link == obj.model.root_link else f"{obj.name}{SEP}{link}"
            np.testing.assert_allclose(robot.get_transform(name, "map"), pose, atol=1e-9, err_msg=name)
        np.testing.assert_allclose(states["objects"][obj.name]["pose"], obj.pose, atol=1e-12)
    # no link collides as a concave visual mesh: only primitives and convex pieces
    text = exported.urdf.read_text()
    assert "<box size=" in text and "<cylinder radius=" in text
    for path in exported.folder.glob("meshes/*_collision_*.stl"):
        assert trimesh.load(path).is_convex
    # per-object URDFs for PyBullet and the static part
    assert set(exported.object_urdfs) == {"cup_1", "bottle_1", "box_1"}
    for path in [*exported.object_urdfs.values(), exported.static_urdf]:
        assert yourdfpy.URDF.load(str(path), load_meshes=True).validate()


def test_mjcf_loads_with_one_free_joint_per_movable_object(scene, exported):
    model = mujoco.MjModel.from_xml_path(str(exported.mjcf))
    free = int(np.sum(model.jnt_type == mujoco.mjtJoint.mjJNT_FREE))
    assert free == sum(o.movable for o in scene) == 3
    cabinet = scene.object("cabinet_1").model
    assert int(np.sum(model.jnt_type != mujoco.mjtJoint.mjJNT_FREE)) == len(cabinet.movable_joints)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    for obj in scene:
        for link, pose in obj.link_poses().items():
            name = obj.name if link == obj.model.root_link else f"{obj.name}{SEP}{link}"
            bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
            np.testing.assert_allclose(data.xpos[bid], pose[:3, 3], atol=1e-9, err_msg=name)
            np.testing.assert_allclose(data.xmat[bid].reshape(3, 3), pose[:3, :3], atol=1e-9, err_msg=name)
    # the open drawer's slide starts at its current value
    (name, value), = scene.object("cabinet_1").joint_values.items()
    assert float(data.qpos[model.joint(f"cabinet_1{SEP}{name}").qposadr[0]]) == pytest.approx(value)


def test_everything_written_is_finite_and_the_glb_loads(exported):
    for path in exported.folder.rglob("*"):
        if path.suffix in (".urdf", ".xml", ".json"):
            text = path.read_text().lower()
            assert "nan" not in text.replace("name", "") and "inf" not in text.replace("info", ""), path
    glb = trimesh.load(exported.glb)
    assert isinstance(glb, trimesh.Scene) and len(glb.geometry) >= 5
    assert np.all(np.isfinite(glb.bounds))
    assert not list(exported.folder.rglob("*.tmp"))


def test_a_movable_link_without_density_is_refused():
    model = build_model("box", 0)
    scene = ReplacedScene("x", [PlacedObject("thing", "no_such_class", model, np.eye(4), support="floating",
                                             movable=True)])
    with pytest.raises(InputError, match="needs a mass"):
        scene_to_tree(scene)
