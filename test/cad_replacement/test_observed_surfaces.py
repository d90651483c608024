"""Stage 4 on a map whose desk was seen but not detected (issue 22): the exported scene stands still."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from cad_replacement.cad.library import CadLibrary
from cad_replacement.export import export_scene
from cad_replacement.replacer import CadReplacer
from recon_core.entity import Entity
from scene_graph.builder import ContactGraphBuilder
from scene_graph.config import load_scene_graph_config
from scene_recon.evaluation.physics import check_mujoco, check_pybullet

DESK_Z = 0.72


def _sheet(lo, hi, z, holes=()) -> trimesh.Trimesh:
    """An upward-facing sheet of 5 cm squares at height z (a TSDF surface), without the squares in ``holes``."""
    faces, step = [], 0.05
    for x in np.arange(lo[0], hi[0] - 1e-9, step):
        for y in np.arange(lo[1], hi[1] - 1e-9, step):
            c = (x + step / 2, y + step / 2)
            if any(h[0] <= c[0] <= h[2] and h[1] <= c[1] <= h[3] for h in holes):
                continue
            faces += [[[x, y, z], [x + step, y, z], [x + step, y + step, z]],
                      [[x, y, z], [x + step, y + step, z], [x, y + step, z]]]
    tri = np.asarray(faces)
    return trimesh.Trimesh(tri.reshape(-1, 3), np.arange(len(tri) * 3).reshape(-1, 3), process=False)


def _scene(surfaces: bool):
    """No floor in view, a desk top nobody detected (in the unlabelled surface), a box-like `object`
    (no CAD model: exported as its observed mesh) and a cup standing on it."""
    desk = _sheet((-0.5, -0.3), (0.5, 0.3), DESK_Z, holes=[(-0.3, -0.1, 0.0, 0.1), (0.15, -0.05, 0.25, 0.05)])
    unknown = Entity.from_mesh(0, "unknown", "unknown", desk, class_id=-1, is_thing=False, category="unknown")
    body = trimesh.creation.box([0.3, 0.2, 0.12]).apply_translation([-0.15, 0.0, DESK_Z + 0.06])
    obj = Entity.from_mesh(3, "object_3", "object", body)
    mug = trimesh.creation.cylinder(radius=0.04, height=0.1, sections=24).apply_translation([0.2, 0.0, DESK_Z + 0.05])
    cup = Entity.from_mesh(4, "cup_4", "cup", mug)
    cfg = load_scene_graph_config()
    cfg.surfaces = dataclasses.replace(cfg.surfaces, enabled=surfaces)
    builder = ContactGraphBuilder(cfg)
    builder.update([unknown, obj, cup])
    graph = builder.build(name="desk")
    return graph, builder.node_entities()


@pytest.fixture(scope="module")
def replaced(tmp_path_factory):
    out = {}
    for surfaces in (True, False):
        graph, nodes = _scene(surfaces)
        result = CadReplacer(CadLibrary(seeds_per_class=3)).replace(graph, nodes)
        folder = tmp_path_factory.mktemp(f"surfaces_{surfaces}")
        out[surfaces] = (graph, result, export_scene(result.scene, folder / "scene", glb=False))
    return out


def test_the_patches_are_static_slabs_whose_tops_are_the_desk(replaced):
    _graph, result, _export = replaced[True]
    objs = {o.name: o for o in result.scene}
    for child in ("object_3", "cup_4"):
        parent = objs[objs[child].parent]
        assert parent.class_name == "surface" and not parent.movable and parent.model.source == "box"
        top = float((np.asarray(parent.model.links[0].mesh.vertices) @ parent.pose[:3, :3].T
                     + parent.pose[:3, 3])[:, 2].max())
        assert abs(top - DESK_Z) < 1e-6
    kinds = {r.name: r.kind for r in result.records}
    assert kinds["object_3"] == "observed_mesh" and all(kinds[n] == "layout" for n in kinds if "surface" in n)


@pytest.mark.parametrize("check", [check_pybullet, check_mujoco], ids=["pybullet", "mujoco"])
def test_objects_on_an_undetected_desk_stay_still(replaced, check):
    _graph, _result, export = replaced[True]
    report = check(export.folder, seconds=2.0)
    assert report.loaded and not report.errors
    assert set(report.displacement) == {"object_3", "cup_4"}
    assert report.still_fraction == 1.0, report.displacement


def test_without_the_patches_they_fall(replaced):
    graph, _result, export = replaced[False]
    assert graph.supports[3].kind == "fallback_root"
    report = check_pybullet(export.folder, seconds=1.0)
    assert report.loaded and report.still_fraction == 0.0, report.displacement
