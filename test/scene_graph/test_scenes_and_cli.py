"""Generated scenes (cg_map setting), entity sources, observed meshes and the graph / eval-graph commands."""

from __future__ import annotations

import json

import numpy as np
import pytest

from recon_core.entity import save_entities
from recon_core.errors import InputError
from scene_graph.builder import build_contact_graph
from scene_recon.evaluation.graph_ground_truth import ground_truth_graph, restrict_graph
from scene_recon.evaluation.graph_metrics import evaluate_graph
from scene_recon.sources import load_source, read_mapped
from scene_recon.synthetic.scene import build_scene, entities_from_ground_truth


@pytest.fixture(scope="module")
def scene():
    return build_scene(14, 11, name="test-room")


@pytest.mark.parametrize("seed", [0, 4])
def test_generated_scenes_from_ground_truth_meshes_have_zero_ged(seed):
    s = build_scene(20, seed)
    g = build_contact_graph(entities_from_ground_truth(s))
    r = evaluate_graph(g, ground_truth_graph(s))
    assert r["ged"]["total"] == 0, r["ged"]
    assert r["box_map_refined"]["mAP"] >= 0.9


def test_ground_truth_graph_and_restriction(scene):
    gt = ground_truth_graph(scene)
    assert len(gt.nodes) == len(scene.entities) + 1
    keep = {e.id for e in scene.entities if e.category == "layout" or e.parent in ("floor", "scene")}
    small = restrict_graph(gt, keep)
    assert set(small.nodes) == keep | {0}
    small.validate()


def test_mapped_scene_folder_round_trip(scene, tmp_path):
    ents = entities_from_ground_truth(scene)
    ents[3].revision = 7
    save_entities(ents, tmp_path / "mapped", name="mapped-room")
    src = load_source(tmp_path / "mapped")
    assert src.kind == "mapped" and src.name == "mapped-room" and len(src.entities) == len(ents)
    a, b = ents[3], src.entities[3]
    assert (b.id, b.name, b.class_name, b.revision) == (a.id, a.name, a.class_name, 7)
    np.testing.assert_allclose(b.vertices, a.vertices)
    np.testing.assert_array_equal(b.faces, a.faces)
    g1, g2 = build_contact_graph(ents), build_contact_graph(src.entities)
    assert g1.parents() == g2.parents()
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "entities.json").write_text(json.dumps({"format": "x"}))
    with pytest.raises(InputError, match="cannot read entities"):
        read_mapped(tmp_path / "bad")
    with pytest.raises(InputError, match="neither"):
        load_source(tmp_path)


def test_observed_meshes_keep_what_a_camera_sees(entity):
    from scene_recon.evaluation.observed import CameraView, ObservationConfig, observed_entities
    from scene_recon.synthetic.scene import GroundTruthScene, SceneEntity

    cube = entity(2, "box", [([-0.25, -0.25, 0.0], [0.25, 0.25, 0.5])])
    import trimesh

    def scene_entity(e, category="rigid", z=0.0):
        pose = np.eye(4)
        pose[2, 3] = z
        return SceneEntity(e.id, e.name, e.class_name, 0, category, True, True, pose, "scene",
                           mesh=trimesh.Trimesh(e.vertices, e.faces, process=False))

    gt = GroundTruthScene("s", 0, (1.0, 1.0, 1.0), [scene_entity(cube)])
    # A camera 2 m in front of the cube (on -x), looking along +x: optical z = map +x.
    pose = np.eye(4)
    pose[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]])  # columns: camera x, y, z in the map
    pose[:3, 3] = [-2.0, 0.0, 0.25]
    k = np.array([[80.0, 0, 39.5], [0, 80.0, 29.5], [0, 0, 1]])
    ents, stats = observed_entities(gt, [CameraView(pose, k, 80, 60)], ObservationConfig(max_edge=0.1))
    assert len(ents) == 1
    assert ents[0].vertices[:, 0].max() == pytest.approx(-0.25)  # only the face towards the camera
    assert 0.1 < stats["box_2"] < 0.2  # one of six faces
    cut, _ = observed_entities(gt, [CameraView(pose, k, 80, 60)], ObservationConfig(max_edge=0.1, contact_band=0.05))
    assert cut[0].vertices[:, 2].min() == pytest.approx(0.05)


def test_graph_and_eval_graph_commands(scene, tmp_path, capsys):
    from scene_recon.cli import main

    gt_dir = tmp_path / "room_groundtruth"
    scene.save(gt_dir)
    out = tmp_path / "out"
    assert main(["graph", str(gt_dir), "--out", str(out), "--urdf"]) == 0
    text = capsys.readouterr().out
    assert text.splitlines()[0] == "scene" and "floor [floor, layout]" in text
    for name in ("contact_graph.json", "contact_graph.png", "urdf/scene.urdf"):
        assert (out / name).is_file()
    assert main(["eval-graph", str(out / "contact_graph.json"), str(gt_dir), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["ged"]["total"] == 0 and result["ged"]["gt_nodes"] == len(scene.entities)
    assert result["box_map_refined"]["mAP"] > 0.9
    assert main(["eval-graph", str(out / "contact_graph.json"), str(gt_dir)]) == 0
    assert "GED total: 0" in capsys.readouterr().out
    assert main(["graph", str(tmp_path / "nowhere"), "--out", str(out)]) == 2
    assert "does not exist" in capsys.readouterr().err
