"""Caches a second process reuses (issue 23, item 4): per-object results on disk, models built once,
observed pieces built on demand, the export's parallel mesh files."""

from __future__ import annotations

import dataclasses
import json
import os
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from cad_replacement import observed_physics
from cad_replacement.cad import library as library_module
from cad_replacement.cad.library import CadLibrary
from cad_replacement.observation import ObjectObservation
from cad_replacement.replace_config import CadReplacementConfig
from cad_replacement.replacer import CadReplacer
from cad_replacement.result_store import ResultStore, library_digest, library_result_store, result_key
from cad_replacement.workers import ReplaceWorkers
from scene_graph.builder import ContactGraphBuilder
from scene_graph.config import load_scene_graph_config
from scene_recon.synthetic.scene import build_scene, entities_from_ground_truth

ROOT = Path(__file__).resolve().parents[2]


def _obs(shift: float = 0.0) -> ObjectObservation:
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.1, 0.1, (200, 3)) + shift
    return ObjectObservation(3, "cup_1", "cup", points, normals=np.tile([0.0, 0.0, 1.0], (200, 1)), support_z=0.0)


@dataclasses.dataclass
class _Result:
    entity_id: int
    poses: list[np.ndarray]
    timings: dict[str, float]


def test_result_store_round_trip_and_damaged_or_foreign_files_are_misses(tmp_path):
    store = ResultStore(tmp_path / "results")
    key = "ab" + "0" * 62
    assert store.load(key) is None
    store.save(key, _Result(3, [np.eye(4)], {"total": 1.0}))
    assert store.load(key) is None  # a class from outside the project's packages is refused ...
    # ... the project's own classes and numpy arrays are built
    from cad_replacement.cad.library import CadEntry

    entry = CadEntry("procedural/cup/cup_s0001", "cup", "procedural", seed=1)
    store.save(key, {"entry": entry, "pose": np.eye(4), "values": (1.0, 2)})
    back = store.load(key)
    assert back["entry"] == entry and np.array_equal(back["pose"], np.eye(4)) and back["values"] == (1.0, 2)
    assert not list(store.path(key).parent.glob(".tmp-*"))  # temp + rename leaves nothing behind
    # a file naming another key, a truncated file, a pickle that would run code: all ignored
    other = "cd" + "1" * 62
    store.path(other).parent.mkdir(parents=True, exist_ok=True)
    store.path(other).write_bytes(store.path(key).read_bytes())
    assert store.load(other) is None
    store.path(key).write_bytes(store.path(key).read_bytes()[:40])
    assert store.load(key) is None
    evil = pickle.dumps(os.system)
    store.path(key).write_bytes(f"scene_recon.cad_result 1 {key}\n".encode() + evil)
    assert store.load(key) is None


def test_result_key_follows_the_observation_the_settings_and_the_library(tmp_path):
    lib = CadLibrary(seeds_per_class=1, classes=["cup"], cache_dir=tmp_path / "cad_features")
    digest = library_digest(lib)
    assert digest is not None and digest == library_digest(CadLibrary(seeds_per_class=1, classes=["cup"],
                                                                      cache_dir=tmp_path / "other"))
    config = CadReplacementConfig()
    key = result_key(_obs(), config, None, digest)
    assert key == result_key(_obs(), CadReplacementConfig(), None, digest)  # content, not identity
    assert key != result_key(_obs(1e-9), config, None, digest)
    assert key != result_key(_obs(), dataclasses.replace(config, top_k=config.top_k + 1), None, digest)
    bigger = library_digest(CadLibrary(seeds_per_class=2, classes=["cup"], cache_dir=tmp_path / "cad_features"))
    assert key != result_key(_obs(), config, None, bigger or "")
    assert library_result_store(lib) == ResultStore(tmp_path / "cad_results")


@pytest.fixture(scope="module")
def room():
    builder = ContactGraphBuilder(load_scene_graph_config())
    builder.update(entities_from_ground_truth(build_scene(8, 5)))
    return builder.build(name="room"), builder.node_entities()


def _summary(result):
    return {o.name: (o.cad_id, o.pose.tolist(), o.scale.tolist(), o.joint_values) for o in result.scene}


def test_a_second_process_reads_the_results_back_and_places_every_object_the_same(room, tmp_path):
    graph, nodes = room
    library = CadLibrary(seeds_per_class=3, cache_dir=tmp_path / "cache" / "cad_features")
    config = CadReplacementConfig(workers=2, parallel_min_objects=4)
    first = ReplaceWorkers(library, 2, store="library")
    try:
        a = CadReplacer(library, config, workers=first).replace(graph, nodes)
    finally:
        first.close()
    assert first.submitted >= 4 and first.restored == 0
    assert len(list((tmp_path / "cache" / "cad_results").rglob("*.pkl"))) == first.submitted
    # a new library and pool, as in the next process: every object comes from the store, no worker starts
    library2 = CadLibrary(seeds_per_class=3, cache_dir=tmp_path / "cache" / "cad_features")
    second = ReplaceWorkers(library2, 2, store="library")
    try:
        b = CadReplacer(library2, config, workers=second).replace(graph, nodes)
        assert second.restored == first.submitted and second.submitted == 0 and not second.started
    finally:
        second.close()
    assert _summary(a) == _summary(b)
    restored = [r for r in b.records if r.candidates]
    assert restored and all("restored_s" in r.timings for r in restored)
    strip = [{k: v for k, v in r.to_dict().items() if k != "timings"} for r in a.records]
    assert strip == [{k: v for k, v in r.to_dict().items() if k != "timings"} for r in b.records]


def test_features_and_geometry_read_back_from_disk_replace_every_object_the_same(room, tmp_path):
    """A second process with the feature and geometry caches of the first (no result store): the same scene."""
    graph, nodes = room
    config = CadReplacementConfig(workers=1)
    cache = tmp_path / "cache" / "cad_features"
    a = CadReplacer(CadLibrary(seeds_per_class=3, cache_dir=cache), config).replace(graph, nodes)
    assert list(cache.glob("*.json")) and list((tmp_path / "cache" / "cad_geometry").glob("*.npz"))
    library2 = CadLibrary(seeds_per_class=3, cache_dir=cache)
    replacer2 = CadReplacer(library2, config)
    b = replacer2.replace(graph, nodes)
    assert library2.stats.computed == 0 and replacer2.cache.built == 0 and replacer2.cache.restored > 0
    assert _summary(a) == _summary(b)
    strip = [{k: v for k, v in r.to_dict().items() if k != "timings"} for r in a.records]
    assert strip == [{k: v for k, v in r.to_dict().items() if k != "timings"} for r in b.records]


def test_features_build_no_model_and_a_model_is_built_once(tmp_path, monkeypatch):
    lib = CadLibrary(seeds_per_class=2, classes=["cabinet"], cache_dir=tmp_path)
    calls = []
    real = library_module.build_model
    monkeypatch.setattr(library_module, "build_model", lambda *a, **k: calls.append(a) or real(*a, **k))
    entry = lib.entries("cabinet")[0]
    feats = lib.features(entry)  # empty cache: computed from the parts, no mesh built
    assert calls == []
    model = lib.model(entry)
    assert lib.model(entry) is model and len(calls) == 1
    assert json.dumps(model.features.to_dict(), sort_keys=True) == json.dumps(feats.to_dict(), sort_keys=True)
    # the model is the one a fresh build gives
    fresh = real(entry.class_name, entry.seed)
    assert [lk.name for lk in model.links] == [lk.name for lk in fresh.links]
    for a, b in zip(model.links, fresh.links, strict=True):
        np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)


def test_observed_pieces_built_on_demand_equal_the_pieces_built_up_front(room):
    """And ``settle_observed`` drops the same pieces with them as with every piece built up front."""
    graph, nodes = room
    scene = CadReplacer(CadLibrary(seeds_per_class=2), CadReplacementConfig(workers=1)).replace(graph, nodes).scene
    moved = scene.objects[-1]
    moved.pose = moved.pose.copy()
    moved.pose[:3, 3] += (0.1, -0.2, 0.0)
    for obj in scene:
        up_front = observed_physics._world_pieces(obj)
        lazy = observed_physics._PlacedPieces(obj)
        assert len(lazy) == len(up_front)
        for k, piece in enumerate(up_front):
            # bounds that contain the piece (a pair they keep apart cannot have a probe inside the other), tight
            assert np.all(lazy.bounds[k][0] <= piece.bounds[0]) and np.all(lazy.bounds[k][1] >= piece.bounds[1])
            assert np.allclose(lazy.bounds[k], piece.bounds, atol=0.1 * max(piece.extents)), obj.name
            np.testing.assert_array_equal(lazy.piece(k).vertices, piece.vertices)
            np.testing.assert_array_equal(lazy.piece(k).face_normals, piece.face_normals)


def test_export_writes_the_mesh_files_to_urdf_would(room, tmp_path):
    from cad_replacement.export import export_scene, scene_to_tree

    graph, nodes = room
    scene = CadReplacer(CadLibrary(seeds_per_class=2), CadReplacementConfig(workers=1)).replace(graph, nodes).scene
    seen = []
    export_scene(scene, tmp_path / "a", on_glb=seen.append)
    assert seen == [tmp_path / "a" / "scene.glb"]
    scene_to_tree(scene).to_urdf(tmp_path / "b", mesh_dir="meshes", filename="scene.urdf")  # one by one
    a = sorted(p.name for p in (tmp_path / "a" / "meshes").iterdir())
    assert a == sorted(p.name for p in (tmp_path / "b" / "meshes").iterdir()) and a
    for name in a:
        assert (tmp_path / "a" / "meshes" / name).read_bytes() == (tmp_path / "b" / "meshes" / name).read_bytes()
    assert (tmp_path / "a" / "scene.urdf").read_text() == (tmp_path / "b" / "scene.urdf").read_text()
    assert isinstance(trimesh.load(tmp_path / "a" / "scene.glb", force="scene"), trimesh.Scene)


def test_the_replace_command_line_loads_no_other_stage_before_its_work():
    code = ("import sys; from scene_recon.cli import build_parser; build_parser('replace')"
            ".parse_args(['replace', 'G', '--out', 'O']); "
            "print(sorted(m for m in ('open3d', 'trimesh', 'cv2', 'panoptic_mapping', 'matplotlib', 'pybullet', "
            "'mujoco', 'scipy') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_open3d_imported_for_replace_leaves_dash_and_plotly_for_later():
    code = ("import sys; from recon_core.lazy_import import import_open3d; import_open3d(); "
            "print('open3d' in sys.modules, 'dash' in sys.modules, 'plotly' in sys.modules); "
            "import open3d as o3d, numpy as np; "
            "m = sys.modules['open3d.visualization.draw_plotly']; "
            "pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.zeros((3, 3)))); "
            "print(type(m.get_plotly_fig([pc])).__name__, 'dash' in sys.modules or 'plotly' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["True", "False", "False", "Figure", "True"]


def test_the_result_store_calls_no_function_of_the_project(tmp_path):
    import io

    from recon_core import io as recon_io

    class _Write:  # pickles as a call of recon_core.io.write_text_atomic(path, text)
        def __reduce__(self):
            return recon_io.write_text_atomic, (str(tmp_path / "written"), "x")

    store = ResultStore(tmp_path / "results")
    key = "ef" + "2" * 62
    store.path(key).parent.mkdir(parents=True, exist_ok=True)
    body = io.BytesIO()
    pickle.Pickler(body).dump(_Write())
    store.path(key).write_bytes(f"scene_recon.cad_result 1 {key}\n".encode() + body.getvalue())
    assert store.load(key) is None and not (tmp_path / "written").exists()
