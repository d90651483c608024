"""Mapped-entity input: wall splitting, stray faces and fragments, over-segmentation, floor under
objects, layout matching and the seen-only evaluation."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from recon_core.contact_graph import ROOT_ID, ContactGraph, GraphNode, SupportEdge, root_node
from recon_core.entity import Entity
from recon_core.geometry.box import GravityBox
from scene_graph.builder import ContactGraphBuilder, build_contact_graph
from scene_graph.config import LayoutConfig, SceneGraphConfig
from scene_graph.layout import split_layout
from scene_recon.evaluation.graph_metrics import evaluate_graph, graph_edit_distance, match_nodes

WALLS, FLOORS = ["wall"], ["floor", "ceiling"]


def patch(origin, u, v, nu: int = 20, nv: int = 12, noise: float = 0.0, seed: int = 0) -> trimesh.Trimesh:
    """A planar grid of triangles (a TSDF-like single surface) spanned by u and v from origin."""
    origin, u, v = (np.asarray(a, float) for a in (origin, u, v))
    a, b = np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0, 1, nv + 1), indexing="ij")
    verts = origin + a.reshape(-1, 1) * u + b.reshape(-1, 1) * v
    if noise:
        verts = verts + np.random.default_rng(seed).normal(0, noise, verts.shape)
    idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    q = np.c_[idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()]
    faces = np.r_[q[:, [0, 1, 2]], q[:, [0, 2, 3]]]
    return trimesh.Trimesh(verts, faces, process=False)


def room_walls(walls=("west", "east", "south", "north"), h: float = 2.5, noise: float = 0.005) -> trimesh.Trimesh:
    """Inner wall surfaces of a 4 m x 3 m room (x in [-2, 2], y in [-1.5, 1.5]) as ONE mesh."""
    up = [0, 0, h]
    spec = {"west": ([-2, -1.5, 0], [0, 3, 0]), "east": ([2, -1.5, 0], [0, 3, 0]),
            "south": ([-2, -1.5, 0], [4, 0, 0]), "north": ([-2, 1.5, 0], [4, 0, 0])}
    return trimesh.util.concatenate([patch(spec[w][0], spec[w][1], up, noise=noise, seed=k)
                                     for k, w in enumerate(walls)])


def mapped_floor(hole=None) -> trimesh.Trimesh:
    """The seen floor surface at z = 0 (a thin partial surface), optionally with a rectangular hole."""
    m = patch([-1.9, -1.4, 0], [3.8, 0, 0], [0, 2.8, 0], nu=38, nv=28)
    if hole is not None:
        (x0, y0), (x1, y1) = hole
        c = m.triangles_center
        keep = ~((c[:, 0] > x0) & (c[:, 0] < x1) & (c[:, 1] > y0) & (c[:, 1] < y1))
        m = trimesh.Trimesh(m.vertices, m.faces[keep], process=False)
    return m


# ---------------------------------------------------------------------------------------- layout split
def test_four_walls_in_one_entity_become_four_wall_nodes():
    ents = [Entity.from_mesh(1, "wall_1", "wall", room_walls(), is_thing=False),
            Entity.from_mesh(2, "floor_2", "floor", mapped_floor(), is_thing=False),
            Entity.from_mesh(7, "table_7", "table", trimesh.creation.box([1, 0.6, 0.75]).apply_translation(
                [0, 0, 0.375]))]
    g = build_contact_graph(ents)
    walls = [n for n in g.nodes.values() if n.class_name == "wall"]
    assert len(walls) == 4
    ids = {n.id for n in walls}
    assert not ids & {1, 2, 7} and min(ids) >= 1000  # new ids, no collision with any entity id
    assert sorted(n.name for n in walls) == ["wall_1", "wall_2", "wall_3", "wall_4"]
    assert all(g.parent(i) == 2 for i in ids)  # every wall stands on the floor
    assert g.stats["layout_parts"] == {1: sorted(ids)}
    # Each part is one planar wall: a thin box along x or along y.
    for n in walls:
        thin = min(n.box_unrefined.size[:2])
        assert thin < 0.05 and max(n.box_unrefined.size[:2]) > 2.9
    centres = sorted((round(float(n.box.center[0]), 1), round(float(n.box.center[1]), 1)) for n in walls)
    assert centres == [(-2.0, 0.0), (0.0, -1.5), (0.0, 1.5), (2.0, 0.0)]


def test_l_shaped_wall_splits_in_two_and_ground_truth_walls_stay_as_they_are():
    cfg = LayoutConfig()
    l_shape = Entity.from_mesh(5, "wall_5", "wall", room_walls(("west", "south")))
    parts = split_layout(l_shape, cfg, WALLS, FLOORS)
    assert len(parts) == 2 and {p.name for p in parts} == {"wall_1", "wall_2"}
    assert sum(len(p.faces) for p in parts) == len(l_shape.faces)  # corner faces joined a part, none lost
    # A ground-truth wall: a 10 cm slab (two large faces 10 cm apart) -> the very same entity.
    slab = trimesh.creation.box([0.1, 3.0, 2.5]).apply_translation([-2.05, 0, 1.25])
    gt_wall = Entity.from_mesh(2, "wall_west", "wall", slab)
    assert split_layout(gt_wall, cfg, WALLS, FLOORS) == [gt_wall]
    slab = trimesh.creation.box([4, 3, 0.05]).apply_translation([0, 0, -0.025])
    gt_floor = Entity.from_mesh(1, "floor", "floor", slab)
    assert split_layout(gt_floor, cfg, WALLS, FLOORS) == [gt_floor]
    # Disabled: nothing happens.
    assert split_layout(l_shape, LayoutConfig(enabled=False), WALLS, FLOORS) == [l_shape]


def test_coplanar_walls_apart_are_two_walls_and_stray_faces_leave():
    cfg = LayoutConfig()
    two = trimesh.util.concatenate([patch([-3, 0, 0], [2, 0, 0], [0, 0, 2.5]),
                                    patch([1, 0, 0], [2, 0, 0], [0, 0, 2.5], seed=1)])  # 2 m gap
    parts = split_layout(Entity.from_mesh(3, "wall_3", "wall", two), cfg, WALLS, FLOORS)
    assert len(parts) == 2
    near = trimesh.util.concatenate([patch([-3, 0, 0], [2, 0, 0], [0, 0, 2.5]),
                                     patch([-0.5, 0, 0], [2, 0, 0], [0, 0, 2.5], seed=1)])  # 0.5 m gap: a door
    assert len(split_layout(Entity.from_mesh(3, "wall_3", "wall", near), cfg, WALLS, FLOORS)) == 1
    # A floor with a chair foot fused at 0.3-0.5 m: the stray faces are dropped, the box stays flat.
    foot = trimesh.creation.box([0.05, 0.05, 0.2]).apply_translation([0.5, 0.5, 0.4])
    floor = Entity.from_mesh(4, "floor_4", "floor", trimesh.util.concatenate([mapped_floor(), foot]))
    (clean,) = split_layout(floor, cfg, WALLS, FLOORS)
    assert clean.id == 4 and clean.vertices[:, 2].max() < 0.01
    assert len(clean.faces) == len(floor.faces) - len(foot.faces)


def test_split_walls_through_the_incremental_builder():
    b = ContactGraphBuilder(SceneGraphConfig())
    wall = Entity.from_mesh(3, "wall_3", "wall", room_walls(("west", "north")), revision=4)
    b.update([wall, Entity.from_mesh(2, "floor_2", "floor", mapped_floor())])
    assert b.ids == [2, 3] and b.features(3).entity.revision == 4
    g = b.build()
    parts = g.stats["layout_parts"][3]
    assert len(parts) == 2 and set(parts) <= set(g.nodes)
    ents = b.node_entities()
    assert set(parts) <= set(ents) and all(ents[p].class_name == "wall" for p in parts)
    assert b.update([wall]) == []  # same revision: not recomputed
    assert b.build().stats["layout_parts"] == {3: parts}  # stable ids
    b.remove([3])
    assert not [n for n in b.build().nodes.values() if n.class_name == "wall"]


# ---------------------------------------------------------------------------------------- objects
def test_far_fragment_no_longer_inflates_a_cup_box():
    cup = trimesh.creation.cylinder(radius=0.04, height=0.1, sections=24).apply_translation([0, 0, 0.8])
    sliver = patch([0.5, 0.3, 0.75], [0.04, 0, 0], [0, 0, 0.04], nu=2, nv=2)  # 4 faces of wall 60 cm away
    e = Entity.from_mesh(9, "cup_9", "cup", trimesh.util.concatenate([cup, sliver]))
    g = build_contact_graph([e])
    assert np.all(g.nodes[9].box_unrefined.size[:2] < 0.1)
    off = SceneGraphConfig()
    off.fragments.enabled = False
    assert build_contact_graph([e], off).nodes[9].box_unrefined.size[:2].max() > 0.5


def _with_fringe(eid: int, name: str, cls: str, core: trimesh.Trimesh, fringe: trimesh.Trimesh) -> Entity:
    """An entity as the mapper extracts it: voted core vertices first, the fill's fringe after them."""
    both = trimesh.util.concatenate([core, fringe])
    return Entity(eid, cls, both.vertices, both.faces, name=name, core_vertices=len(core.vertices))


def test_a_bottle_box_comes_from_its_voted_core_not_the_joined_fringe():
    """The fill joins the cabinet front behind a 5 cm bottle to it (unvoted fringe): the box must not
    grow to cover it (mapped bottles measured 17 cm wide before)."""
    bottle = trimesh.creation.cylinder(radius=0.027, height=0.18, sections=24).apply_translation([0, 0, 1.0])
    behind = patch([-0.06, 0.04, 0.92], [0.12, 0, 0], [0, 0, 0.16], nu=6, nv=8)
    e = _with_fringe(9, "bottle_9", "bottle", bottle, behind)
    box = build_contact_graph([e]).nodes[9].box_unrefined
    assert np.all(box.size[:2] < 0.07), box.size
    whole = Entity(9, "bottle", e.vertices, e.faces, name="bottle_9")  # without the marking: inflated
    assert build_contact_graph([whole]).nodes[9].box_unrefined.size[:2].max() > 0.1


def test_merged_fragments_keep_every_voted_core_before_the_fringes():
    from scene_graph.merge import merged_entity

    a = _with_fringe(1, "table_1", "table", trimesh.creation.box([1, 1, 0.03]),
                     patch([0.6, 0, 0], [0.1, 0, 0], [0, 0.1, 0], nu=1, nv=1))
    b = _with_fringe(2, "table_2", "table", trimesh.creation.box([0.05, 0.05, 0.7]),
                     patch([0.3, 0.3, 0], [0.1, 0, 0], [0, 0.1, 0], nu=1, nv=1))
    m = merged_entity(a, [b])
    n_core = a.core_vertices + b.core_vertices
    assert m.core_vertices == n_core and len(m.vertices) == len(a.vertices) + len(b.vertices)
    v, f = m.core_mesh(min_faces=1)
    # the core mesh is exactly the two cores' triangles, the fringe triangles are all left out
    core_tris = np.r_[a.vertices[a.faces[np.all(a.faces < a.core_vertices, axis=1)]],
                      b.vertices[b.faces[np.all(b.faces < b.core_vertices, axis=1)]]]
    assert np.allclose(np.sort(v[f].reshape(-1, 3), axis=0), np.sort(core_tris.reshape(-1, 3), axis=0))
    assert len(m.faces) == len(a.faces) + len(b.faces)
    assert np.allclose(m.vertices[m.faces].sum(), a.vertices[a.faces].sum() + b.vertices[b.faces].sum())


def test_over_segmented_table_merges_but_stacked_books_do_not(entity):
    floor = Entity.from_mesh(1, "floor_1", "floor", mapped_floor())
    table = entity(4, "table", [([-0.5, -0.4, 0.72], [0.5, 0.4, 0.75]), ([-0.5, -0.4, 0.0], [-0.45, -0.35, 0.72])])
    leg = entity(8, "table", [([0.45, 0.35, 0.0], [0.5, 0.4, 0.7])])  # a leg mapped as another table
    book_a = entity(5, "book", [([0.0, 0.0, 0.75], [0.2, 0.3, 0.78])])
    book_b = entity(6, "book", [([0.02, 0.02, 0.78], [0.18, 0.25, 0.80])])  # lies on book_a
    g = build_contact_graph([floor, table, leg, book_a, book_b])
    assert 8 not in g.nodes and "fragment of node 4" in g.skipped[8]
    assert g.stats["merged_fragments"] == {4: [8]}
    assert g.nodes[4].box_unrefined.size[0] == pytest.approx(1.0)
    assert g.parent(6) == 5 and g.parent(5) == 4 and g.parent(4) == 1


def test_object_without_bottom_next_to_a_wall_stands_on_the_floor(entity):
    """A cabinet seen only from 0.3 m up (its bottom hidden), against a wall, over the floor hole it
    hides: the floor (Eq. (3), D = 0.3) and not the wall fallback; the refined box reaches the floor."""
    floor = Entity.from_mesh(1, "floor_1", "floor", mapped_floor(hole=((1.0, 0.5), (1.9, 1.4))))
    wall = Entity.from_mesh(2, "wall_2", "wall", patch([-2, 1.5, 0], [4, 0, 0], [0, 0, 2.5]))
    cabinet = entity(3, "cabinet", [([1.0, 0.6, 0.3], [1.9, 1.45, 0.32]), ([1.0, 0.6, 0.3], [1.02, 1.45, 0.9]),
                                    ([1.0, 0.6, 0.88], [1.9, 1.45, 0.9])])
    g = build_contact_graph([floor, wall, cabinet])
    assert g.parent(3) == 1 and g.supports[3].kind == "support"
    assert g.nodes[3].box.z_min == pytest.approx(0.0, abs=0.01)
    cfg = SceneGraphConfig()
    cfg.support.floor_under_objects = False
    assert build_contact_graph([floor, wall, cabinet], cfg).supports[3].kind == "fallback_wall"


def test_a_wall_never_stands_on_furniture(entity):
    floor = Entity.from_mesh(1, "floor_1", "floor", mapped_floor())
    desk = entity(3, "desk", [([-1.0, 1.0, 0.7], [0.0, 1.5, 0.75]), ([-1.0, 1.0, 0.0], [-0.95, 1.05, 0.7])])
    wall = Entity.from_mesh(2, "wall_2", "wall", patch([-2, 1.5, 0.76], [4, 0, 0], [0, 0, 1.7]))  # lower part hidden
    g = build_contact_graph([floor, desk, wall])
    assert g.parent(2) == 1


# ---------------------------------------------------------------------------------------- evaluation
def _graph(nodes: list[tuple[int, str, str, str, GravityBox]], parents: dict[int, int]) -> ContactGraph:
    g = ContactGraph(nodes={ROOT_ID: root_node()})
    for nid, name, cls, cat, box in nodes:
        g.nodes[nid] = GraphNode(nid, name, cls, cat, box=box, box_unrefined=box)
        g.supports[nid] = SupportEdge(parents[nid], nid)
    g.validate()
    return g


GT_NODES = [
    (1, "floor", "floor", "layout", GravityBox([0, 0, -0.025], [4.2, 3.2, 0.05])),
    (2, "wall_west", "wall", "layout", GravityBox([-2.05, 0, 1.25], [0.1, 3.2, 2.5])),
    (3, "wall_south", "wall", "layout", GravityBox([0, -1.55, 1.25], [4.0, 0.1, 2.5])),
    (4, "table_1", "table", "rigid", GravityBox([0, 0, 0.375], [1.0, 0.6, 0.75])),
    (5, "book_1", "book", "rigid", GravityBox([1.0, 1.0, 0.02], [0.2, 0.3, 0.04])),
]
GT_PARENTS = {1: 0, 2: 1, 3: 1, 4: 1, 5: 1}


def test_layout_matches_by_class_and_containment_not_iou():
    gt = _graph(GT_NODES, GT_PARENTS)
    pred = _graph([
        (10, "floor_10", "floor", "layout", GravityBox([-0.5, 0.2, 0.0], [2.0, 1.5, 0.01])),  # partial, thin
        (1000, "wall_1", "wall", "layout", GravityBox([-2.0, 0.4, 1.0], [0.01, 1.5, 2.0])),  # seen part
        (1001, "wall_2", "wall", "layout", GravityBox([0.5, -1.5, 1.0], [2.0, 0.01, 2.0])),
        (7, "table_7", "table", "rigid", GravityBox([0, 0, 0.375], [1.0, 0.6, 0.75])),
    ], {10: 0, 1000: 10, 1001: 10, 7: 10})
    m = match_nodes(pred, gt)
    assert m.pred_to_gt == {0: 0, 10: 1, 1000: 2, 1001: 3, 7: 4}
    r = graph_edit_distance(pred, gt)
    assert (r.wrong_support, r.wrong_detection, r.missing_nodes) == (0, 0, ["book_1"])
    # A floor-class prediction that covers a book is not the book (layout and objects never match),
    # nor is a big predicted box around a small ground-truth object of another class.
    pred2 = _graph([(11, "floor_11", "floor", "layout", GravityBox([1.0, 1.0, 0.3], [0.6, 0.6, 0.6])),
                    (12, "shelf_12", "shelf", "rigid", GravityBox([1.0, 1.0, 0.5], [1.0, 1.0, 1.0]))],
                   {11: 0, 12: 0})
    assert match_nodes(pred2, gt).pred_to_gt == {0: 0}


def test_seen_only_evaluation_leaves_out_unseen_entities_and_their_matches():
    gt = _graph(GT_NODES, GT_PARENTS)
    pred = _graph([
        (10, "floor_10", "floor", "layout", GravityBox([0, 0, 0], [3.0, 2.0, 0.01])),
        (20, "book_20", "book", "rigid", GravityBox([1.0, 1.0, 0.02], [0.2, 0.3, 0.04])),
    ], {10: 0, 20: 10})
    seen = {1, 3, 4}  # the west wall and the book were never seen; the table was, but is missing
    r = evaluate_graph(pred, gt, seen=seen)
    assert r["ged"]["missing"] == 3  # wall_west, wall_south, table_1
    s = r["seen_only"]
    assert s["ged"]["gt_nodes"] == 3 and s["ged"]["missing_nodes"] == ["wall_south", "table_1"]
    assert s["void_predictions"] == ["book_20"] and s["ged"]["wrong_detection"] == 0
    assert s["unseen_gt_nodes"] == ["wall_west", "book_1"]
    assert evaluate_graph(pred, gt).keys() == {"ged", "box_map_refined", "box_map_unrefined"}


def test_eval_graph_command_prints_raw_and_seen_only(tmp_path, capsys):
    from scene_recon.cli import main
    from scene_recon.synthetic.scene import build_scene

    scene = build_scene(8, 3, name="seen-room")
    for k, e in enumerate(scene.entities):
        e.visible_pixels = 0 if k % 4 == 3 else 50_000
    gt_dir = tmp_path / "room_groundtruth"
    scene.save(gt_dir)
    out = tmp_path / "g"
    assert main(["graph", str(gt_dir), "--out", str(out), "--no-picture"]) == 0
    capsys.readouterr()
    assert main(["eval-graph", str(out / "contact_graph.json"), str(gt_dir)]) == 0
    text = capsys.readouterr().out
    assert "GED total: 0" in text and "seen only" in text
    assert main(["eval-graph", str(out / "contact_graph.json"), str(gt_dir), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    unseen = [e.name for k, e in enumerate(scene.entities) if k % 4 == 3]
    assert sorted(r["seen_only"]["unseen_gt_nodes"]) == sorted(unseen)
    assert r["seen_only"]["ged"]["total"] == 0 and len(r["seen_only"]["void_predictions"]) == len(unseen)
