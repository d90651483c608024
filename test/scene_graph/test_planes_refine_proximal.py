"""Surface planes, box refinement (Fig. 3d) and proximal relations with broad-phase pruning."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from recon_core.geometry.box import GravityBox
from scene_graph.broadphase import all_pairs, sweep_pairs
from scene_graph.builder import build_contact_graph
from scene_graph.config import ProximalConfig, RefineConfig, SceneGraphConfig
from scene_graph.features import compute_features
from scene_graph.planes import SurfacePlane
from scene_graph.proximal import boxes_overlap, proximal_relations
from scene_graph.refine import refine_box
from scene_graph.support import SupportDecision


def test_planes_have_outward_normals_and_shelf_levels(room):
    cfg = SceneGraphConfig()
    table = compute_features(room[3], cfg)
    up = [p for p in table.planes if p.is_support(cfg.support.a_th)]
    assert any(abs(-p.d - 0.75) < 1e-6 for p in up)  # the top, normal +z
    assert all(p.normal[2] > 0.9 for p in up)
    assert any(p.source == "ransac" for p in table.planes)  # RANSAC (reused) found the big faces
    shelf = compute_features(room[5], cfg)
    levels = sorted(round(-p.d, 3) for p in shelf.planes if p.is_support(cfg.support.a_th))
    assert levels == [0.1, 0.5, 0.9, 1.2]  # each level, though far below RANSAC's 10 % rule
    top = next(p for p in shelf.planes if p.is_support(cfg.support.a_th) and abs(-p.d - 1.2) < 1e-6)
    assert len(top.region_triangles) > 0 and top.region_triangles.shape[1:] == (3, 2)


def test_points_input_uses_ransac_only():
    from recon_core.entity import Entity

    rng = np.random.default_rng(0)
    top = np.c_[rng.uniform(0, 1, (800, 2)), np.full(800, 0.7)]
    side = np.c_[rng.uniform(0, 1, 400), np.zeros(400), rng.uniform(0, 0.7, 400)]
    feats = compute_features(Entity.from_points(1, "t", "table", np.r_[top, side]), SceneGraphConfig())
    sup = [p for p in feats.planes if p.is_support(-0.9)]
    assert len(sup) == 1 and -sup[0].d == pytest.approx(0.7, abs=2e-3) and sup[0].normal[2] > 0.999
    assert len(sup[0].region_points) >= 700


def _plane(z: float) -> SurfacePlane:
    from cad_replacement.cad.feature_types import Plane

    return SurfacePlane(Plane(normal=[0, 0, 1], d=-z))


def test_refine_extends_the_bottom_to_the_supporting_plane():
    floating = GravityBox([0, 0, 0.6], [0.5, 0.5, 0.5], 0.2)  # chair seat + back seen, legs not
    d = SupportDecision(5, 1, "support", 0.6, 1.0, 0.35, _plane(0.0))
    refined = refine_box(floating, d, RefineConfig())
    assert refined.z_min == pytest.approx(0.0) and refined.z_max == pytest.approx(floating.z_max)
    np.testing.assert_allclose(refined.center[:2], floating.center[:2])
    assert refined.yaw == floating.yaw
    assert refine_box(floating, d, RefineConfig(enabled=False)) is floating
    assert refine_box(floating, SupportDecision(5, 1, "fallback_wall"), RefineConfig()) is floating
    far = SupportDecision(5, 1, "support", 0.1, 1.0, 2.0, _plane(-1.5))
    assert refine_box(floating, far, RefineConfig(max_extension=1.0)) is floating
    sunk = GravityBox([0, 0, 0.24], [0.5, 0.5, 0.5], 0.0)  # bottom 1 cm below the plane (noise)
    assert refine_box(sunk, d, RefineConfig()).z_min == pytest.approx(0.0)
    assert refine_box(sunk, d, RefineConfig(lift_bottoms=False)) is sunk


def test_refinement_in_the_graph_completes_a_partial_chair(entity):
    ents = [entity(1, "floor", [([-2, -2, -0.05], [2, 2, 0])]),
            entity(2, "chair", [([0, 0, 0.30], [0.45, 0.45, 0.35]), ([0, 0.4, 0.35], [0.45, 0.45, 0.8])])]
    g = build_contact_graph(ents)
    chair = g.nodes[2]
    assert g.supports[2].parent_id == 1
    assert chair.box_unrefined.z_min == pytest.approx(0.30)
    assert chair.box.z_min == pytest.approx(0.0) and chair.box.z_max == pytest.approx(0.8)


def test_sweep_pairs_equal_brute_force():
    rng = np.random.default_rng(1)
    lo = rng.uniform(0, 10, (300, 3))
    hi = lo + rng.uniform(0.05, 1.0, (300, 3))
    brute = {(i, j) for i, j in itertools.combinations(range(300), 2)
             if np.all(lo[i] <= hi[j]) and np.all(lo[j] <= hi[i])}
    assert {tuple(p) for p in sweep_pairs(lo, hi)} == brute
    assert len(all_pairs(lo, hi)) == 300 * 299 // 2
    assert len(sweep_pairs(lo[:1], hi[:1])) == 0


def test_far_pairs_never_reach_the_exact_test():
    rng = np.random.default_rng(2)
    boxes = [GravityBox(np.r_[rng.uniform(0, 20, 2), 0.5], rng.uniform(0.2, 1.0, 3), rng.uniform(-1, 1))
             for _ in range(120)]
    ids = list(range(1, 121))
    tested: list[tuple[int, int]] = []

    def spy(a, b, margin):
        tested.append((boxes.index(a), boxes.index(b)))
        return boxes_overlap(a, b, margin)

    cfg = ProximalConfig()
    res = proximal_relations(ids, boxes, {}, cfg, exact_test=spy)
    for a, b in tested:  # every exact test had overlapping (inflated) bounds
        (alo, ahi), (blo, bhi) = boxes[a].aabb(), boxes[b].aabb()
        assert np.all(alo - cfg.margin <= bhi + cfg.margin) and np.all(blo - cfg.margin <= ahi + cfg.margin)
    assert res.exact_tests == len(tested) < 120 * 119 // 20
    naive = proximal_relations(ids, boxes, {}, ProximalConfig(broadphase="all_pairs"))
    assert naive.pairs == res.pairs and naive.exact_tests == 120 * 119 // 2


def test_proximal_excludes_support_pairs(room):
    g = build_contact_graph(room)
    parent = g.parents()
    for a, b in g.proximal:
        assert parent.get(a) != b and parent.get(b) != a
    assert (2, 3) in g.proximal  # the two walls meet in a corner
    assert (4, 5) not in g.proximal  # table and cup: a support pair


def test_refinement_never_makes_a_box_taller_than_its_class_can_be(entity):
    """A microwave 0.8 m above the floor, accepted on it for want of its (unlabelled) counter, became
    1.2 m tall on real frames; a table seen as its top only still reaches down to the floor."""
    box = GravityBox([0, 0, 1.0], [0.5, 0.35, 0.35], 0.0)  # 0.83-1.18 m
    d = SupportDecision(5, 1, "support", 0.21, 1.0, 0.83, _plane(0.0))
    assert refine_box(box, d, RefineConfig(), max_height=0.75) is box
    assert refine_box(box, d, RefineConfig(), max_height=1.5).z_min == pytest.approx(0.0)
    ents = [entity(1, "floor", [([-2, -2, -0.05], [2, 2, 0])]),
            entity(2, "table", [([0, 0, 0.70], [1.4, 0.8, 0.75])]),
            entity(3, "microwave", [([1.8, 0, 0.55], [2.3, 0.35, 0.85])])]
    g = build_contact_graph(ents)
    assert g.supports[2].parent_id == 1 and g.nodes[2].box.z_min == pytest.approx(0.0)  # table top: completed
    mw = g.nodes[3]
    assert g.supports[3].parent_id == 1  # the floor, 0.55 m below
    assert mw.box.z_min == pytest.approx(0.55) and mw.box.size[2] == pytest.approx(0.30)  # microwave <= 0.75 m
