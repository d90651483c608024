"""Generated scenes: physically valid layouts, true support parents, URDF, bag read-back."""

from __future__ import annotations

import json

import numpy as np
import open3d as o3d
import pytest
import yourdfpy

from panoptic_mapping.dataio.registry import open_dataset
from scene_recon.synthetic.generate import GenerateConfig, generate_recording, ground_truth_path
from scene_recon.synthetic.scene import GroundTruthScene, build_scene
from scene_recon.synthetic.suite import SUITE, scene_config

SEEDS = [0, 1, 2, 3, 4, 5]


@pytest.fixture(scope="module", params=SEEDS)
def scene(request) -> GroundTruthScene:
    return build_scene(20, request.param)


def _tensor_scene(mesh):
    s = o3d.t.geometry.RaycastingScene()
    s.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
                    o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)))
    return s


def _parts(scene: GroundTruthScene, e) -> list:
    """Watertight pieces of an entity in the map frame (each CAD link separately)."""
    model = scene.model_of(e)
    if model is None:
        return [e.mesh]
    out = []
    for mesh in model.posed_link_meshes(e.joint_values).values():
        m = mesh.copy()
        m.apply_transform(e.pose)
        out.append(m)
    return out


def test_no_interpenetration_above_5mm(scene):
    ents = scene.entities
    lo = np.array([e.mesh.bounds[0] for e in ents])
    hi = np.array([e.mesh.bounds[1] for e in ents])
    parts = {e.name: [(_tensor_scene(m), m.bounds) for m in _parts(scene, e)] for e in ents}
    for i, a in enumerate(ents):
        pts = np.vstack([a.mesh.sample(3000, seed=1), a.mesh.vertices]).astype(np.float32)
        for j, b in enumerate(ents):
            if i == j or np.any(hi[i] < lo[j] - 0.01) or np.any(hi[j] < lo[i] - 0.01):
                continue
            for rs, (blo, bhi) in parts[b.name]:
                near = np.all((pts >= blo - 0.01) & (pts <= bhi + 0.01), axis=1)
                if not near.any():
                    continue
                # majority vote over 5 rays makes the inside test robust to points on coincident faces
                sd = rs.compute_signed_distance(o3d.core.Tensor(pts[near]), nsamples=5).numpy()
                depth = float(max(0.0, -sd.min()))
                assert depth < 0.005, f"{a.name} penetrates {b.name} by {depth * 1000:.1f} mm"


def test_support_parent_really_holds_each_object(scene):
    names = {e.name: e for e in scene.entities}
    objects = [e for e in scene.entities if e.category != "layout"]
    assert objects
    for e in objects:
        assert e.parent in names, e.name
        parent = names[e.parent]
        bottom = e.mesh.bounds[0][2]
        # the object's lowest vertices rest on the parent: some of them lie within 5 mm of its surface
        low = e.mesh.vertices[e.mesh.vertices[:, 2] < bottom + 0.002]
        dist = _tensor_scene(parent.mesh).compute_distance(o3d.core.Tensor(low.astype(np.float32))).numpy()
        assert dist.min() < 0.005, f"{e.name} floats {dist.min() * 1000:.1f} mm above its parent {e.parent}"
        # and the parent is what is right below the object's bottom
        top_of_parent = parent.mesh.bounds[1][2]
        assert bottom <= top_of_parent + 0.005, f"{e.name} is above {e.parent}'s top"
        assert bottom >= parent.mesh.bounds[0][2] - 1e-6
    # the parse tree is a tree rooted at the scene
    for e in scene.entities:
        seen, cur = set(), e.name
        while cur != "scene":
            assert cur not in seen, f"support cycle through {cur}"
            seen.add(cur)
            cur = names[cur].parent


def test_scene_has_variety_and_valid_boxes(scene):
    classes = {e.class_name for e in scene.entities}
    assert {"floor", "wall"} <= classes
    assert len(classes - {"floor", "wall"}) >= 4
    assert 18 <= sum(e.category != "layout" for e in scene.entities) <= 22
    ids = [e.id for e in scene.entities]
    assert len(set(ids)) == len(ids) and min(ids) >= 1
    for e in scene.entities:
        # the oriented box contains the mesh (up to float error)
        c, s = np.cos(e.box.yaw), np.sin(e.box.yaw)
        rel = e.mesh.vertices - e.box.center
        local = np.c_[c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1], rel[:, 2]]
        assert np.all(np.abs(local) <= e.box.size / 2 + 1e-6)
    for a, b in scene.proximal:
        assert (a, b) not in scene.support_edges and (b, a) not in scene.support_edges


def test_deterministic_for_a_seed():
    a, b = build_scene(12, 7), build_scene(12, 7)
    assert [e.name for e in a.entities] == [e.name for e in b.entities]
    for ea, eb in zip(a.entities, b.entities, strict=True):
        np.testing.assert_array_equal(ea.pose, eb.pose)
        np.testing.assert_array_equal(ea.mesh.vertices, eb.mesh.vertices)
    assert [e.name for e in build_scene(12, 8).entities] != [e.name for e in a.entities] or not np.allclose(
        build_scene(12, 8).entities[-1].pose, a.entities[-1].pose)


def test_ground_truth_urdf_forward_kinematics_match_scene(tmp_path):
    scene = build_scene(16, 2)
    scene.save(tmp_path / "gt")
    robot = yourdfpy.URDF.load(str(tmp_path / "gt" / "urdf" / "scene.urdf"), load_meshes=True)
    assert robot.validate()
    # set revolute/prismatic joints to the scene's joint values, floating joints to identity motion
    cfg = {}
    for e in scene.entities:
        for jname, value in e.joint_values.items():
            cfg[f"{e.name}__{jname}"] = value
    robot.update_cfg({k: v for k, v in cfg.items() if k in robot.actuated_joint_names})
    for e in scene.entities:
        t = robot.get_transform(e.name, "map")
        np.testing.assert_allclose(t, e.pose, atol=1e-6, err_msg=e.name)
    # every link of every articulated object sits where the CAD model's kinematics put it
    checked = 0
    for e in scene.entities:
        model = scene.model_of(e)
        if model is None or not model.is_articulated:
            continue
        poses = model.link_poses(e.joint_values)
        for link in model.links:
            name = e.name if link.name == model.root_link else f"{e.name}__{link.name}"
            np.testing.assert_allclose(robot.get_transform(name, "map"), e.pose @ poses[link.name], atol=1e-6)
            checked += 1
    assert checked > 0
    # reload the sidecar
    again = GroundTruthScene.load(tmp_path / "gt")
    assert [x.name for x in again.entities] == [x.name for x in scene.entities]
    np.testing.assert_allclose(again.entities[-1].mesh.vertices, scene.entities[-1].mesh.vertices, atol=1e-6)


def test_generate_bag_reads_back_with_labels(tmp_path):
    cfg = GenerateConfig(objects=6, frames=12, seed=3)
    cfg.sensor.camera.width, cfg.sensor.camera.height = 160, 120
    cfg.sensor.camera.fx = cfg.sensor.camera.fy = 131.25
    cfg.sensor.camera.cx, cfg.sensor.camera.cy = 79.5, 59.5
    summary = generate_recording(tmp_path / "rec.db3", cfg, progress=False)
    bag = tmp_path / "rec"
    assert summary["storage"] == "db3" and (bag / "rec.db3").is_file()
    gt = ground_truth_path(bag)
    assert (gt / "overview.png").is_file() and (gt / "urdf" / "scene.urdf").is_file()
    meta = json.loads((gt / "scene.json").read_text())
    ids = {e["id"] for e in meta["entities"]}
    from panoptic_mapping.dataio import DataInputConfig

    dcfg = DataInputConfig()
    dcfg.topics.labels = "/ground_truth/panoptic_labels"
    with open_dataset(bag, dcfg) as loader:
        frames = list(loader)
    assert len(frames) == 12
    for f in frames:
        assert f.color.shape == (120, 160, 3) and f.pose is not None
        assert set(np.unique(f.extras["labels"])) <= ids | {0}
        valid = f.depth > 0
        assert valid.mean() > 0.5
    seen = {e["name"] for e in meta["entities"] if e["visible_pixels"] > 0}
    assert "floor" in seen


def test_suite_definitions_build():
    for s in SUITE.values():
        cfg = scene_config(s)
        assert cfg.objects == s.objects and cfg.frames == s.frames
        build_scene(min(s.objects, 10), s.seed, layout=cfg.layout)
