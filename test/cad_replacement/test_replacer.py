"""The stage-4 pipeline on a generated scene's ground-truth entities: every node replaced, a valid tree."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yourdfpy

from cad_replacement.cad.library import CadLibrary
from cad_replacement.export import link_name, scene_to_tree
from cad_replacement.replacer import CadReplacer
from cad_replacement.scene_model import MAP_ROOT
from scene_graph.builder import ContactGraphBuilder
from scene_graph.config import load_scene_graph_config
from scene_recon.synthetic.scene import build_scene, entities_from_ground_truth


@pytest.fixture(scope="module")
def replaced():
    scene = build_scene(8, 5)
    builder = ContactGraphBuilder(load_scene_graph_config())
    builder.update(entities_from_ground_truth(scene))
    graph = builder.build(name="room")
    replacer = CadReplacer(CadLibrary(seeds_per_class=3))
    nodes = builder.node_entities()
    return scene, graph, nodes, replacer, replacer.replace(graph, nodes)


def test_every_node_is_placed_with_its_support(replaced):
    _scene, graph, _nodes, _replacer, result = replaced
    placed = {o.name: o for o in result.scene}
    assert set(placed) == {n.name for nid, n in graph.nodes.items() if nid != graph.root_id}
    for nid, edge in graph.supports.items():
        obj = placed[graph.nodes[nid].name]
        expected = MAP_ROOT if edge.parent_id == graph.root_id else graph.nodes[edge.parent_id].name
        assert obj.parent == expected and obj.support == edge.joint
    things = [r for r in result.records if r.kind == "cad"]
    assert things and all(r.cad_id.startswith("procedural/") for r in things)
    for o in result.scene:
        assert np.all(np.isfinite(o.pose))


def test_objects_rest_on_their_supporting_plane(replaced):
    _scene, graph, _nodes, _replacer, result = replaced
    for obj in result.scene:
        node = next(n for n in graph.nodes.values() if n.name == obj.name)
        edge = graph.supports.get(node.id)
        if node.category == "layout" or edge is None or edge.plane is None or edge.plane.normal[2] < 0.9:
            continue
        low = min(float((m.vertices @ obj.pose[:3, :3].T + obj.pose[:3, 3])[:, 2].min())
                  for m in obj.model.posed_link_meshes(obj.joint_values).values() if len(m.vertices))
        assert low == pytest.approx(-edge.plane.d, abs=1e-6), obj.name


def test_scene_urdf_parses_and_its_kinematics_match(replaced, tmp_path):
    _scene, _graph, _nodes, _replacer, result = replaced
    tree = scene_to_tree(result.scene)
    path = tree.to_urdf(tmp_path, filename="scene.urdf")
    urdf = yourdfpy.URDF.load(str(path))
    assert urdf.validate()
    urdf.update_cfg({k: v for k, v in tree.joint_values.items() if k in urdf.actuated_joint_names})
    for obj in result.scene:
        for link, pose in obj.link_poses().items():
            np.testing.assert_allclose(urdf.get_transform(link_name(obj, link), MAP_ROOT), pose, atol=1e-6)
    assert "nan" not in path.read_text().lower()


def test_an_update_rematches_only_what_changed(replaced):
    _scene, graph, nodes, replacer, _result = replaced
    again = replacer.replace(graph, nodes)
    assert again.rematched == 0
    target = next(r for r in again.records if r.kind == "cad")
    changed = dict(nodes)
    changed[target.node_id] = dataclasses.replace(nodes[target.node_id], revision=nodes[target.node_id].revision + 1)
    third = replacer.replace(graph, changed)
    assert third.rematched == 1
    assert [r.name for r in third.records if r.kind == "cad" and not r.reused] == [target.name]
