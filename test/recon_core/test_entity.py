"""The core entity's voted core / fringe marking: kept through copies, files and messages."""

from __future__ import annotations

import numpy as np
import trimesh

from recon_core.entity import Entity, load_entities, save_entities


def _fringed() -> Entity:
    core = trimesh.creation.box([0.1, 0.1, 0.2])
    fringe = trimesh.creation.box([0.3, 0.02, 0.3]).apply_translation([0, 0.1, 0])
    both = trimesh.util.concatenate([core, fringe])
    return Entity(3, "bottle", both.vertices, both.faces, core_vertices=len(core.vertices))


def test_core_mesh_leaves_the_fringe_out_and_falls_back_when_the_core_is_a_sliver():
    e = _fringed()
    v, f = e.core_mesh(min_faces=12)
    assert len(v) == 8 and len(f) == 12 and np.ptp(v, axis=0)[1] < 0.11
    assert e.core_mesh()[1].shape == e.faces.shape  # fewer than MIN_CORE_FACES core faces: the whole mesh
    unmarked = Entity(1, "cup", e.vertices, e.faces)
    assert unmarked.core_mesh(min_faces=1)[1].shape == e.faces.shape  # unmarked: all core


def test_new_geometry_resets_the_marking_and_out_of_range_counts_mean_all_core():
    e = _fringed()
    e.set_geometry(e.vertices[:8], e.faces[:12])
    assert e.core_vertices == -1
    assert Entity(1, "cup", e.vertices, e.faces, core_vertices=99).core_vertices == -1


def test_the_marking_survives_a_mapped_scene_folder(tmp_path):
    e = _fringed()
    save_entities([e], tmp_path)
    (back,) = load_entities(tmp_path)
    assert back.core_vertices == e.core_vertices and np.allclose(back.vertices, e.vertices)
    assert np.array_equal(back.faces, e.faces)
