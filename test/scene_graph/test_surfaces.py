"""Support patches from observed, undetected surfaces (``scene_graph/surfaces.py``, issue 22)."""

from __future__ import annotations

import dataclasses

import numpy as np
import trimesh

from recon_core.entity import Entity
from scene_graph.builder import ContactGraphBuilder, build_contact_graph
from scene_graph.config import SceneGraphConfig
from scene_graph.surfaces import KIND

from .conftest import box_mesh, make_entity

DESK_Z = 0.72


def unknown(meshes) -> Entity:
    """The map's unclaimed surface (entity 0, class "unknown") made of these meshes."""
    return Entity.from_mesh(0, "unknown", "unknown", trimesh.util.concatenate(list(meshes)), class_id=-1,
                            is_thing=False, category="unknown")


def desk_top(hole: tuple[float, float, float, float] | None = None, z: float = DESK_Z) -> trimesh.Trimesh:
    """The upward face of a desk top (a TSDF surface: one sheet, facing the camera above), with a hole
    where an object stands on it (the scan never sees under it)."""
    lo, hi = np.array([-0.5, -0.3]), np.array([0.5, 0.3])  # 0.6 m^2: no floor derived from it
    step = 0.05
    faces = []
    for x in np.arange(lo[0], hi[0], step):
        for y in np.arange(lo[1], hi[1], step):
            cx, cy = x + step / 2, y + step / 2
            if hole is not None and hole[0] <= cx <= hole[2] and hole[1] <= cy <= hole[3]:
                continue
            faces.append([[x, y, z], [x + step, y, z], [x + step, y + step, z]])
            faces.append([[x, y, z], [x + step, y + step, z], [x, y + step, z]])
    tri = np.asarray(faces)
    return trimesh.Trimesh(tri.reshape(-1, 3), np.arange(len(tri) * 3).reshape(-1, 3), process=False)


def cup(z: float = DESK_Z) -> Entity:
    return make_entity(5, "cup", [([0.1, 0.1, z], [0.18, 0.18, z + 0.1])])


def test_a_cup_on_an_undetected_desk_stands_on_a_patch_of_the_observed_desk():
    g = build_contact_graph([unknown([desk_top(hole=(0.1, 0.1, 0.18, 0.18))]), cup()])
    edge = g.supports[5]
    assert edge.kind == KIND and edge.joint == "floating"
    patch = g.nodes[edge.parent_id]
    assert patch.class_name == "surface" and patch.category == "layout" and not patch.movable
    assert g.supports[patch.id].parent_id == g.root_id and g.supports[patch.id].joint == "fixed"
    assert abs(patch.box.z_max - DESK_Z) < 1e-6 and patch.box.size[2] >= 0.05 - 1e-9
    assert abs(edge.plane.d + DESK_Z) < 1e-6 and abs(edge.distance) < 1e-6
    # the patch covers the cup's footprint (the desk continues unseen under it), with a margin
    lo, hi = patch.box.aabb()
    assert np.all(lo[:2] <= [0.1 - 0.019, 0.1 - 0.019]) and np.all(hi[:2] >= [0.18 + 0.019, 0.18 + 0.019])
    assert g.stats["surface_patches"]["5"]["id"] == patch.id


def test_no_patch_without_an_observed_surface_near_the_bottom():
    # nothing seen at all: the cup stays a fallback on the root
    g = build_contact_graph([cup()])
    assert g.supports[5].kind == "fallback_root" and not g.stats["surface_patches"]
    # a surface 20 cm below the cup's bottom is not what it stands on
    g = build_contact_graph([unknown([desk_top(z=DESK_Z - 0.2)]), cup()])
    assert g.supports[5].kind == "fallback_root" and len(g.nodes) == 2
    # a surface beside the cup, not under it
    side = desk_top().apply_translation([2.0, 0.0, 0.0])
    g = build_contact_graph([unknown([side]), cup()])
    assert g.supports[5].kind == "fallback_root"


def test_the_objects_own_mask_bleeding_onto_the_desk_is_evidence_too():
    """No unlabelled surface under it (the detector's mask took the desk around the object)."""
    body = box_mesh([0.1, 0.1, DESK_Z], [0.18, 0.18, DESK_Z + 0.1])
    ring = desk_top(hole=(0.1, 0.1, 0.18, 0.18))
    ring = ring.slice_plane([0.06, 0.06, 0], [1, 0, 0]).slice_plane([0.06, 0.06, 0], [0, 1, 0])
    ring = ring.slice_plane([0.22, 0.22, 0], [-1, 0, 0]).slice_plane([0.22, 0.22, 0], [0, -1, 0])
    obj = Entity.from_mesh(5, "object_5", "object", trimesh.util.concatenate([body, ring]))
    g = build_contact_graph([obj])
    assert g.supports[5].kind == KIND
    assert abs(g.nodes[g.supports[5].parent_id].box.z_max - DESK_Z) < 1e-6
    # its top is not its support: a box lying alone in view stays unsupported
    g = build_contact_graph([make_entity(5, "object", [([0.1, 0.1, DESK_Z], [0.18, 0.18, DESK_Z + 0.01])])])
    assert g.supports[5].kind == "fallback_root"


def test_supported_and_fixed_things_are_left_alone(room, entity):
    """A labelled room (generated scenes): no patch, the same graph with the rule on or off."""
    off = SceneGraphConfig()
    off.surfaces = dataclasses.replace(off.surfaces, enabled=False)
    surface = unknown([desk_top(z=0.3)])
    with_rule = build_contact_graph([*room, surface])
    without = build_contact_graph([*room, surface], off)
    assert not with_rule.stats["surface_patches"]
    assert {k: (e.parent_id, e.kind) for k, e in with_rule.supports.items()} == \
        {k: (e.parent_id, e.kind) for k, e in without.supports.items()}
    # a fixed thing (a fridge) on no floor is held by its fixed joint: no patch
    fridge = entity(8, "fridge", [([0.1, 0.1, DESK_Z], [0.7, 0.7, DESK_Z + 0.5])])
    g = build_contact_graph([unknown([desk_top()]), fridge])
    assert g.supports[8].kind == "fallback_root"


def test_the_builder_lists_the_patch_entity_and_drops_it_once_supported():
    b = ContactGraphBuilder()
    b.update([unknown([desk_top(hole=(0.1, 0.1, 0.18, 0.18))]), cup()])
    g = b.build()
    pid = g.supports[5].parent_id
    ents = b.node_entities()
    assert pid in ents and ents[pid].class_name == "surface" and ents[pid].has_faces
    # the desk is detected after all: the cup stands on it, the patch is gone
    b.update([make_entity(9, "desk", [([-0.5, -0.3, DESK_Z - 0.03], [0.5, 0.3, DESK_Z])] +
                          [([x, -0.3, 0.0], [x + 0.05, 0.3, DESK_Z - 0.03]) for x in (-0.5, 0.45)])])
    g = b.build()
    assert g.supports[5].parent_id == 9 and pid not in g.nodes and pid not in b.node_entities()
