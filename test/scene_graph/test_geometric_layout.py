"""Layout from geometry: floor, walls and ceiling found in the map's unlabelled surface when the
segmenter has no layout classes, and things giving up layout planes larger than their class."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from recon_core.entity import Entity
from scene_graph.builder import ContactGraphBuilder, build_contact_graph
from scene_graph.config import GeometricLayoutConfig, SceneGraphConfig
from scene_graph.geometric_layout import concat_entities, give_up_layout_planes, layout_from_geometry
from scene_recon.synthetic.scene import build_scene, entities_from_ground_truth


def patch(origin, u, v, nu: int = 20, nv: int = 12) -> trimesh.Trimesh:
    """A planar grid of triangles (a TSDF-like single surface) spanned by u and v from origin."""
    origin, u, v = (np.asarray(a, float) for a in (origin, u, v))
    a, b = np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0, 1, nv + 1), indexing="ij")
    verts = origin + a.reshape(-1, 1) * u + b.reshape(-1, 1) * v
    idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    q = np.c_[idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()]
    return trimesh.Trimesh(verts, np.r_[q[:, [0, 1, 2]], q[:, [0, 2, 3]]], process=False)


def box(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return trimesh.creation.box(extents=hi - lo).apply_translation((lo + hi) / 2)


def unknown(meshes) -> Entity:
    """The map's unclaimed surface (entity 0, class "unknown") made of these meshes."""
    return Entity.from_mesh(0, "unknown", "unknown", trimesh.util.concatenate(list(meshes)), class_id=-1,
                            is_thing=False, category="unknown")


# 4 m x 3 m room, 2.5 m high, single-surface (TSDF-like) layout
WALLS = {"west": ([-2, -1.5, 0], [0, 3, 0]), "east": ([2, -1.5, 0], [0, 3, 0]),
         "south": ([-2, -1.5, 0], [4, 0, 0]), "north": ([-2, 1.5, 0], [4, 0, 0])}


def room_surface(ceiling: bool = True, walls=tuple(WALLS)) -> list[trimesh.Trimesh]:
    out = [patch([-2, -1.5, 0], [4, 0, 0], [0, 3, 0], 40, 30)]  # floor
    out += [patch(WALLS[w][0], WALLS[w][1], [0, 0, 2.5]) for w in walls]
    if ceiling:
        out.append(patch([-2, -1.5, 2.5], [4, 0, 0], [0, 3, 0], 40, 30))
    return out


def _parents(g) -> dict[str, tuple[str, str]]:
    """Object node name -> (parent class, support kind); layout nodes by class and rounded centre."""
    out = {}
    for i, n in g.nodes.items():
        if i == 0:
            continue
        key = n.name if n.category != "layout" else f"{n.class_name}@{np.round(n.box.center[:2], 1).tolist()}"
        p = g.parent(i)
        out[key] = (g.nodes[p].class_name if p else "scene", g.supports[i].kind)
    return out


# ---------------------------------------------------------------------------------------- layout
def test_ground_truth_room_without_layout_labels_gets_floor_and_walls_with_the_same_supports():
    ents = entities_from_ground_truth(build_scene(8, 3, name="no-layout"))
    labelled = build_contact_graph(ents)
    assert labelled.stats["geometric_layout"] == {}  # labelled layout: nothing derived
    layout = [e for e in ents if e.class_name in ("floor", "wall")]
    assert len(layout) == 5
    relabelled = [e for e in ents if e.class_name not in ("floor", "wall")] + [unknown([e.mesh() for e in layout])]
    g = build_contact_graph(relabelled)
    stats = g.stats["geometric_layout"]
    assert set(stats) == {"floor", "wall"}
    floors = [n for n in g.nodes.values() if n.class_name == "floor"]
    walls = [n for n in g.nodes.values() if n.class_name == "wall"]
    assert len(floors) == 1 and len(walls) == 4
    assert floors[0].box.z_max == pytest.approx(0.0, abs=0.01)
    # every object stands where it stood with the labelled layout; the walls stand on the floor
    assert _parents(g) == _parents(labelled)
    assert all(g.parent(w.id) == floors[0].id and g.supports[w.id].kind == "support" for w in walls)
    # switched off: no layout at all, objects fall back to the scene root
    off = SceneGraphConfig()
    off.geometric_layout.enabled = False
    g_off = build_contact_graph(relabelled, off)
    assert not [n for n in g_off.nodes.values() if n.category == "layout"]


def test_ceiling_found_and_a_cabinet_front_is_no_wall():
    front = patch([1.2, -0.6, 0.0], [0, 1.2, 0], [0, 0, 1.2])  # 0.8 m in front of the east wall
    table_top = patch([-1.0, -0.3, 0.75], [1.0, 0, 0], [0, 0.6, 0])  # small: not the floor
    found = layout_from_geometry(unknown([*room_surface(), front, table_top]), [], GeometricLayoutConfig(),
                                 SceneGraphConfig().layout)
    assert set(found) == {"floor", "wall", "ceiling"}
    assert np.ptp(found["floor"].vertices[:, 2]) < 0.01 and found["floor"].vertices[:, 2].max() < 0.01
    assert found["ceiling"].vertices[:, 2].min() == pytest.approx(2.5)
    wall = found["wall"].mesh()
    on_front = np.isclose(wall.triangles_center[:, 0], 1.2) & (np.abs(wall.face_normals[:, 0]) > 0.9)
    assert not on_front.any() and len(wall.faces) == 4 * 480  # the four walls; the cabinet front stays unlabelled
    g = build_contact_graph([unknown([*room_surface(), front, table_top])])
    assert sum(n.class_name == "wall" for n in g.nodes.values()) == 4
    assert sum(n.class_name == "ceiling" for n in g.nodes.values()) == 1


def test_a_ceiling_seen_from_below_is_never_the_floor():
    """A desk recording under a ceiling, no floor in view: the lowest large horizontal surface faces
    down (the ceiling, seen from below), so there is no floor; with the floor in view, the floor is
    the up-facing surface even when the ceiling is larger."""
    ceiling = patch([-2, -1.5, 2.5], [0, 3, 0], [4, 0, 0], 30, 40)  # wound to face down, as a TSDF sees it
    assert ceiling.face_normals[:, 2].max() < -0.99
    desk = patch([0, 0, 0.75], [1.2, 0, 0], [0, 0.6, 0], 12, 6)  # up-facing, 0.72 m^2
    found = layout_from_geometry(unknown([ceiling, desk]), [], GeometricLayoutConfig(), SceneGraphConfig().layout)
    assert "floor" not in found
    floor = patch([-1, -1, 0], [2, 0, 0], [0, 2, 0], 20, 20)  # 4 m^2 of floor, the ceiling is 12 m^2
    found = layout_from_geometry(unknown([ceiling, desk, floor]), [], GeometricLayoutConfig(),
                                 SceneGraphConfig().layout)
    assert found["floor"].vertices[:, 2].max() < 0.01


def test_one_wall_and_no_floor_gives_only_that_wall():
    found = layout_from_geometry(unknown([patch(*WALLS["north"], [0, 0, 2.5])]), [], GeometricLayoutConfig(),
                                 SceneGraphConfig().layout)
    assert set(found) == {"wall"}


# ---------------------------------------------------------------------------------------- things
def chair_with_wall(wall: bool = True) -> trimesh.Trimesh:
    parts = [box([0, 0.95, 0.42], [0.5, 1.4, 0.47]), box([0, 1.36, 0.47], [0.5, 1.4, 0.9])]
    parts += [box([x, y, 0], [x + 0.04, y + 0.04, 0.42]) for x in (0, 0.46) for y in (0.95, 1.36)]
    if wall:  # the detection mask bled onto the wall behind the chair: 3 m x 2.5 m of it
        parts.append(patch([-1.5, 1.5, 0], [3, 0, 0], [0, 0, 2.5], 30, 25))
    return trimesh.util.concatenate(parts)


def test_a_chair_that_swallowed_a_wall_patch_gives_it_up():
    chair = Entity.from_mesh(7, "chair_7", "chair", chair_with_wall(), class_id=12)
    kept, given = give_up_layout_planes(chair, 1.0, GeometricLayoutConfig())
    assert given is not None and np.allclose(given.vertices[:, 1], 1.5)
    assert np.ptp(kept.vertices[:, 0]) < 0.6 and kept.vertices[:, 2].max() < 0.95
    # a chair without the wall keeps everything
    clean = Entity.from_mesh(7, "chair_7", "chair", chair_with_wall(False), class_id=12)
    assert give_up_layout_planes(clean, 1.0, GeometricLayoutConfig())[1] is None
    # in the graph of a labelled room: the chair's box is a chair's
    floor = Entity.from_mesh(1, "floor", "floor", patch([-2, -1.5, 0], [4, 0, 0], [0, 3, 0], 40, 30),
                             is_thing=False, category="layout")
    g = build_contact_graph([floor, chair])
    assert g.nodes[7].box_unrefined.size.max() < 1.0 and g.parent(7) == 1
    off = SceneGraphConfig()
    off.geometric_layout.enabled = False
    assert build_contact_graph([floor, chair], off).nodes[7].box_unrefined.size.max() > 2.5


def test_the_wall_a_chair_gave_up_becomes_a_wall_node_of_an_unlabelled_map():
    chair = Entity.from_mesh(7, "chair_7", "chair", chair_with_wall(), class_id=12)
    surface = unknown(room_surface(ceiling=False, walls=("west", "east", "south")))  # the north wall: in the chair
    g = build_contact_graph([surface, chair])
    walls = [n for n in g.nodes.values() if n.class_name == "wall"]
    assert len(walls) == 4
    north = [n for n in walls if n.box.center[1] > 1.4]
    assert len(north) == 1 and north[0].box_unrefined.size[0] > 2.9
    assert g.nodes[7].box_unrefined.size.max() < 1.0
    assert g.nodes[g.parent(7)].class_name == "floor"


def table_with_cabinet_fronts(fronts: bool = True) -> trimesh.Trimesh:
    """A 2.2 m x 1.0 m table top at 0.75 m whose mask bled onto the fronts of an L-shaped kitchen
    counter behind it (0.9 m tall, 2.1 m and 1.8 m long: each shorter than a table can be)."""
    parts = [patch([-1.0, -0.5, 0.75], [2.2, 0, 0], [0, 1.0, 0], 44, 20)]
    if fronts:
        parts += [patch([-2.1, 1.0, 0.0], [2.1, 0, 0], [0, 0, 0.9], 42, 18),
                  patch([-2.1, -0.8, 0.0], [0, 1.8, 0], [0, 0, 0.9], 36, 18)]
    return trimesh.util.concatenate(parts)


def test_an_oversized_table_gives_up_the_cabinet_fronts_its_mask_bled_onto():
    table = Entity.from_mesh(3, "table_3", "table", table_with_cabinet_fronts(), class_id=10)
    kept, given = give_up_layout_planes(table, 2.0, GeometricLayoutConfig())
    assert given is not None
    assert np.ptp(kept.vertices[:, 0]) == pytest.approx(2.2, abs=0.01)
    assert np.ptp(kept.vertices[:, 1]) == pytest.approx(1.0, abs=0.01)
    assert np.allclose(kept.vertices[:, 2], 0.75)
    assert kept.mesh().area == pytest.approx(2.2, rel=0.01)
    assert given.mesh().area == pytest.approx(2.1 * 0.9 + 1.8 * 0.9, rel=0.01)
    # the table alone keeps everything; so does one no larger than a table can be with one front
    clean = Entity.from_mesh(3, "table_3", "table", table_with_cabinet_fronts(False), class_id=10)
    assert give_up_layout_planes(clean, 2.0, GeometricLayoutConfig())[1] is None
    short = trimesh.util.concatenate([patch([-1.0, -0.5, 0.75], [2.2, 0, 0], [0, 1.0, 0], 44, 20),
                                      patch([-1.0, 0.5, 0.0], [0, 0, 0.75], [2.2, 0, 0], 18, 44)])
    assert give_up_layout_planes(Entity.from_mesh(3, "t", "table", short, class_id=10), 2.0,
                                 GeometricLayoutConfig())[1] is None


def test_a_sofa_keeps_its_own_back_and_seat():
    sofa = trimesh.util.concatenate([box([0, 0, 0.0], [2.2, 0.9, 0.45]), box([0, 0.7, 0.45], [2.2, 0.9, 0.9])])
    e = Entity.from_mesh(5, "sofa_5", "sofa", sofa)
    assert give_up_layout_planes(e, 2.5, GeometricLayoutConfig())[1] is None


# ---------------------------------------------------------------------------------------- incremental
def test_incremental_builder_drops_derived_layout_once_labels_arrive():
    b = ContactGraphBuilder(SceneGraphConfig())
    b.update([unknown(room_surface())])
    g = b.build()
    derived = g.stats["geometric_layout"]
    assert set(derived) == {"floor", "wall", "ceiling"}
    assert b.ids == []  # derived layout has no source entity: a snapshot-mode node never removes it
    b.remove([derived["floor"]["id"]])
    assert derived["floor"]["id"] in b.build().nodes
    floor = Entity.from_mesh(3, "floor", "floor", patch([-2, -1.5, 0], [4, 0, 0], [0, 3, 0], 40, 30),
                             is_thing=False, category="layout")
    b.update([floor])
    g = b.build()
    assert g.stats["geometric_layout"] == {}
    assert [n.id for n in g.nodes.values() if n.class_name == "floor"] == [3]
    b.remove([3])
    assert set(b.build().stats["geometric_layout"]) == {"floor", "wall", "ceiling"}


def test_concat_entities_keeps_face_indices_valid():
    a = Entity.from_mesh(1, "a", "unknown", box([0, 0, 0], [1, 1, 1]))
    c = concat_entities(a, [Entity.from_mesh(2, "b", "unknown", box([2, 0, 0], [3, 1, 1]))])
    assert len(c.faces) == 24 and c.faces.max() == len(c.vertices) - 1 and c.id == 1


def test_a_wall_seen_only_above_a_counter_is_a_wall():
    """A kitchen's left wall showed only as its tiles above the counter (0.5 m tall, 0.7 m^2) on real
    frames: too small for a wall, yet it bounds the room and rises 1.4 m above the floor."""
    floor = patch([-2, -1.5, 0], [4, 0, 0], [0, 3, 0], 40, 30)
    north = patch(WALLS["north"][0], WALLS["north"][1], [0, 0, 2.5])
    strip = patch([-2, -1.0, 0.9], [0, 1.2, 0], [0, 0, 0.6], 24, 12)  # 0.72 m^2, 0.9-1.5 m
    counter = [patch([-2, -1.0, 0.9], [0.6, 0, 0], [0, 1.2, 0], 12, 24),  # top
               patch([-1.4, -1.0, 0.0], [0, 1.2, 0], [0, 0, 0.9], 24, 18)]  # front (a wall behind it)
    g = build_contact_graph([unknown([floor, north, strip, *counter])])
    walls = sorted((n for n in g.nodes.values() if n.class_name == "wall"), key=lambda n: n.box.center[0])
    assert len(walls) == 2
    west = walls[0]
    assert west.box.center[0] == pytest.approx(-2.0, abs=0.1) and west.box.z_min == pytest.approx(0.9, abs=0.05)
    assert west.box.size.max() == pytest.approx(1.2, abs=0.05)  # the strip only, not the counter front
    # without strips (their thresholds at the wall's): the north wall alone
    cfg = SceneGraphConfig()
    cfg.geometric_layout.wall_strip_min_area = cfg.geometric_layout.wall_min_area
    cfg.geometric_layout.wall_strip_min_height = cfg.geometric_layout.wall_min_height
    assert sum(n.class_name == "wall" for n in build_contact_graph([unknown([floor, north, strip, *counter])],
                                                                   cfg).nodes.values()) == 1


# ------------------------------------------------------------------ things leave the layout planes alone
def chair_with_bleed() -> trimesh.Trimesh:
    """A chair whose mask bled onto the floor beside it (0.6 m x 0.4 m: below give_up_min_area, so the
    per-thing size rule keeps it) and onto the skirting of the north wall behind it (0.5 m x 0.2 m)."""
    return trimesh.util.concatenate([chair_with_wall(False), patch([0.6, 0.6, 0.004], [0.6, 0, 0], [0, 0.4, 0]),
                                     patch([0.0, 1.5, 0.0], [0.5, 0, 0], [0, 0, 0.2], 10, 4)])


def test_things_give_their_faces_in_the_derived_floor_and_walls_to_the_layout():
    chair = Entity.from_mesh(7, "chair_7", "chair", chair_with_bleed(), class_id=12)
    # a screen hung on the east wall: its back in the wall plane, its front 2 cm off it (flush: kept)
    screen = Entity.from_mesh(8, "monitor_8", "monitor", box([1.98, -0.4, 1.0], [2.0, 0.4, 1.5]), class_id=16)
    # a book lying on the floor, 3 cm thick: its top is above the band (2 cm); its bottom (never seen in a
    # real map) is in the floor plane
    book = Entity.from_mesh(9, "book_9", "book", box([-1.0, -1.0, 0.0], [-0.8, -0.75, 0.03]), class_id=21)
    surface = unknown(room_surface(ceiling=False))
    g = build_contact_graph([surface, chair, screen, book])
    given = g.stats["layout_faces_given_m2"]
    assert set(given) == {"7", "9"} and given["7"] == pytest.approx(0.24 + 0.1, abs=0.03)
    assert given["9"] == pytest.approx(0.2 * 0.25, abs=1e-6)
    chair_box = g.nodes[7].box_unrefined  # the chair's own box: 0.5 m x 0.45 m, not the bleed's 1.2 m x 0.9 m
    assert chair_box.size[:2].max() < 0.55 and chair_box.size[2] == pytest.approx(0.9, abs=0.01)
    assert g.nodes[g.parent(7)].class_name == "floor"
    assert g.nodes[8].box_unrefined.size[1] == pytest.approx(0.8, abs=0.02)
    assert g.nodes[9].box_unrefined.size[2] == pytest.approx(0.03, abs=0.005)
    # without derived layout (the map has floor and wall labels) nothing is taken: the planes are the network's
    floor = Entity.from_mesh(1, "floor", "floor", patch([-2, -1.5, 0], [4, 0, 0], [0, 3, 0], 40, 30),
                             is_thing=False, category="layout")
    labelled = build_contact_graph([floor, chair])
    assert labelled.stats["layout_faces_given_m2"] == {} and labelled.nodes[7].box_unrefined.size[:2].max() > 1.0
    # the band can be switched off (0): the chair keeps its bleed
    off = SceneGraphConfig()
    off.geometric_layout.layout_band = 0.0
    assert build_contact_graph([surface, chair], off).nodes[7].box_unrefined.size[:2].max() > 1.0


def test_incremental_builder_trims_a_thing_that_arrives_after_the_layout_and_untrims_once_labels_arrive():
    b = ContactGraphBuilder(SceneGraphConfig())
    b.update([unknown(room_surface(ceiling=False))])
    assert b.build().stats["layout_faces_given_m2"] == {}
    chair = Entity.from_mesh(7, "chair_7", "chair", chair_with_bleed(), class_id=12)
    rebuilt = b.update([chair])
    assert rebuilt == [7]  # the layout did not change: only the new thing, trimmed by the planes held
    g = b.build()
    assert "7" in g.stats["layout_faces_given_m2"] and g.nodes[7].box_unrefined.size[:2].max() < 0.55
    floor = Entity.from_mesh(3, "floor", "floor", patch([-2, -1.5, 0], [4, 0, 0], [0, 3, 0], 40, 30),
                             is_thing=False, category="layout")
    b.update([floor])  # labelled layout: the derived planes go, the chair gets its faces back
    g = b.build()
    assert g.stats["layout_faces_given_m2"] == {} and g.nodes[7].box_unrefined.size[:2].max() > 1.0


def test_sub_entity_keeps_the_voted_core_count():
    from scene_graph.layout import sub_entity

    mesh = patch([0, 0, 0], [1, 0, 0], [0, 1, 0], 4, 4)
    e = Entity.from_mesh(5, "cup_5", "cup", mesh, class_id=1)
    e.set_geometry(e.vertices, e.faces, core_vertices=10)
    keep = np.all(e.faces >= 5, axis=1)  # drop the faces touching vertices 0-4
    sub = sub_entity(e, keep)
    used = np.unique(e.faces[keep])
    assert sub.core_vertices == int(np.count_nonzero(used < 10))
    np.testing.assert_array_equal(sub.vertices[: sub.core_vertices], e.vertices[used[used < 10]])


def test_a_fresh_builder_given_the_source_entities_builds_the_same_graph():
    """The contact-graph node rebuilds from scratch once entities stop coming: from the entities as
    given (the unlabelled surface included), not from the nodes' processed geometry, which holds no
    unlabelled surface (its class is ignored) and so lost the derived floor and walls every time."""
    chair = Entity.from_mesh(7, "chair_7", "chair", chair_with_bleed(), class_id=12)
    b = ContactGraphBuilder(SceneGraphConfig())
    b.update([unknown(room_surface(ceiling=False))])
    b.build()
    b.update([chair])
    g = b.build()
    assert [e.id for e in b.source_entities()] == [0, 7] and b.source_revision(7) == chair.revision
    fresh = ContactGraphBuilder(SceneGraphConfig())
    fresh.update(b.source_entities())
    assert fresh.build().to_dict() | {"stats": None} == g.to_dict() | {"stats": None}
    assert {n.class_name for n in g.nodes.values()} >= {"floor", "wall", "chair"}
    b.remove([7])
    assert b.source_revision(7) is None and b.layout_faces_given == {}
