"""Collision geometry and inertials: exact box CSG, primitives, rings, convex pieces, scaling."""

from __future__ import annotations

import manifold3d as m3
import numpy as np
import pytest
import trimesh

from cad_replacement.cad import build_model
from cad_replacement.collision import (
    box_csg,
    box_shape,
    convex_pieces,
    cylinder_shape,
    inertial_from_shapes,
    mesh_digest,
    shape_mesh,
    shapes_volume,
    transform_inertial,
    transform_shapes,
)
from recon_core.kinematic_tree import CollisionShape


def _manifold_volume(mesh: trimesh.Trimesh) -> float:
    """Volume of a link mesh as manifold3d computes it (the reference for 'exact')."""
    m = m3.Manifold(m3.Mesh(np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.uint32)))
    return float(m.volume())


def _boxes_disjoint(shapes: list[CollisionShape]) -> bool:
    boxes = [s for s in shapes if s.kind == "box"]
    lo = np.array([s.origin[:3, 3] - 0.5 * s.size for s in boxes])
    hi = np.array([s.origin[:3, 3] + 0.5 * s.size for s in boxes])
    inter = np.clip(np.minimum(hi[:, None], hi[None]) - np.maximum(lo[:, None], lo[None]), 0.0, None).prod(axis=2)
    np.fill_diagonal(inter, 0.0)
    return bool(inter.max(initial=0.0) < 1e-12)


@pytest.mark.parametrize("class_name", ["cabinet", "shelf", "fridge", "wardrobe", "dishwasher"])
def test_box_csg_of_hollow_furniture_is_exact(class_name):
    for seed in range(4):
        model = build_model(class_name, seed)
        for link in model.links:
            shapes = list(link.collisions or ())
            if any(s.kind != "box" for s in shapes):
                continue  # links with a cylinder (a hanging rod) are checked for kinds below
            assert shapes and _boxes_disjoint(shapes), (class_name, seed, link.name)
            assert abs(shapes_volume(shapes) - _manifold_volume(link.mesh)) < 1e-6, (class_name, seed, link.name)
            assert abs(shapes_volume(shapes) - link.mesh.volume) < 1e-9


def test_box_csg_union_minus_cut_and_cavity_left_free():
    # two overlapping boxes: union volume = 2 + 2 - 1 overlap; a cut box removes 0.5
    adds = [[[0, 0, 0], [2, 1, 1]], [[1, 0, 0], [3, 1, 1]]]
    cuts = [[[0.5, 0.0, 0.5], [1.5, 1.0, 1.0]]]
    boxes = box_csg(adds, cuts)
    vol = float(np.prod(boxes[:, 1] - boxes[:, 0], axis=1).sum())
    assert vol == pytest.approx(3.0 - 0.5, abs=1e-12)
    # a hollow box (outer minus inner cut): no piece reaches into the cavity
    hollow = box_csg([[[0, 0, 0], [1, 1, 1]]], [[[0.1, 0.1, 0.1], [0.9, 0.9, 1.0]]])
    pts = np.random.default_rng(0).uniform([0.11, 0.11, 0.11], [0.89, 0.89, 0.99], size=(500, 3))
    inside = np.all((pts[:, None] > hollow[None, :, 0]) & (pts[:, None] < hollow[None, :, 1]), axis=2)
    assert not inside.any()
    assert len(hollow) <= 5  # bottom + four walls, greedily merged


def test_box_and_cylinder_inertia_match_closed_forms():
    size, rho = np.array([0.3, 0.2, 0.1]), 700.0
    inertial = inertial_from_shapes([box_shape(-0.5 * size, 0.5 * size)], rho)
    m = rho * size.prod()
    assert inertial.mass == pytest.approx(m)
    a, b, c = size ** 2
    np.testing.assert_allclose(inertial.inertia, np.diag([m * (b + c), m * (a + c), m * (a + b)]) / 12, rtol=1e-12)
    r, h = 0.05, 0.3
    cyl = inertial_from_shapes([cylinder_shape([0.0, 0.0, 1.0], r, h, axis=0)], rho)  # along x
    mc = rho * np.pi * r * r * h
    side = mc * (3 * r * r + h * h) / 12
    np.testing.assert_allclose(cyl.inertia, np.diag([0.5 * mc * r * r, side, side]), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(cyl.center_of_mass, [0.0, 0.0, 1.0])
    # one box split in two halves: the parallel-axis sum gives the whole box back
    halves = [box_shape([-0.15, -0.1, -0.05], [0.0, 0.1, 0.05]), box_shape([0.0, -0.1, -0.05], [0.15, 0.1, 0.05])]
    np.testing.assert_allclose(inertial_from_shapes(halves, rho).inertia, inertial.inertia, rtol=1e-12)
    # a convex mesh piece agrees with the primitive
    piece = CollisionShape("mesh", mesh=trimesh.creation.box(extents=size))
    np.testing.assert_allclose(inertial_from_shapes([piece], rho).inertia, inertial.inertia, rtol=1e-9)


def test_scaled_and_reframed_models_carry_collisions_and_inertials():
    cabinet = build_model("cabinet", 2)
    factors = np.array([1.2, 0.8, 1.1])
    scaled = cabinet.scaled(factors)
    for old, new in zip(cabinet.links, scaled.links, strict=True):
        assert all(s.kind == "box" for s in new.collisions)  # axis-aligned scaling keeps boxes
        assert shapes_volume(new.collisions) == pytest.approx(new.mesh.volume, rel=1e-9)
        assert shapes_volume(new.collisions) == pytest.approx(shapes_volume(old.collisions) * factors.prod(), rel=1e-9)
    cup = build_model("cup", 1)
    squashed = cup.scaled([1.3, 0.9, 1.0])  # a cylinder scaled unevenly in x/y: convex mesh pieces
    shapes = squashed.links[0].collisions
    assert not any(s.kind == "cylinder" for s in shapes) and all(s.mesh.is_convex for s in shapes if s.kind == "mesh")
    assert shapes_volume(shapes) == pytest.approx(squashed.links[0].mesh.volume, rel=0.01)
    uniform = cup.scaled(1.5)
    assert sum(s.kind == "cylinder" for s in uniform.links[0].collisions) == 1
    # reframing rotates the root link's shapes with its mesh
    yaw = trimesh.transformations.rotation_matrix(0.7, [0, 0, 1], [0.1, 0.2, 0.0])
    turned = cabinet.reframed(yaw)
    root = turned.link(turned.root_link)
    pts = np.concatenate([shape_mesh(s).vertices for s in root.collisions])
    np.testing.assert_allclose(pts.min(axis=0), root.mesh.bounds[0], atol=1e-9)
    np.testing.assert_allclose(pts.max(axis=0), root.mesh.bounds[1], atol=1e-9)


def test_transform_inertial_matches_recomputed_shapes():
    shapes = list(build_model("shelf", 3).links[0].collisions)
    base = inertial_from_shapes(shapes, 430.0)
    affine = np.diag([1.3, 0.7, 1.1, 1.0])
    affine[:3, 3] = (0.2, -0.1, 0.3)
    rot = trimesh.transformations.rotation_matrix(0.4, [0, 0, 1])
    for a in (affine, rot @ affine):
        moved = transform_inertial(base, a)
        direct = inertial_from_shapes(list(transform_shapes(shapes, a)), 430.0)
        assert moved.mass == pytest.approx(direct.mass, rel=1e-9)
        np.testing.assert_allclose(moved.center_of_mass, direct.center_of_mass, atol=1e-9)
        np.testing.assert_allclose(moved.inertia, direct.inertia, rtol=1e-8, atol=1e-12)


def test_cup_collides_as_bottom_plus_wall_ring_never_as_its_hull():
    cup = build_model("cup", 0).links[0]
    kinds = [s.kind for s in cup.collisions]
    assert kinds.count("cylinder") == 1 and kinds.count("mesh") == 32
    assert all(s.mesh.is_convex for s in cup.collisions if s.kind == "mesh")
    # polygon wall vs true-circle bottom: within 1 % of the exact mesh volume, far from the hull's
    assert shapes_volume(cup.collisions) == pytest.approx(cup.mesh.volume, rel=0.01)
    assert cup.mesh.convex_hull.volume > 1.5 * shapes_volume(cup.collisions)
    for cls in ("table", "bottle", "microwave", "oven", "bag", "book", "monitor", "chair"):
        for link in build_model(cls, 0).links:
            assert link.collisions and all(s.kind != "mesh" or s.mesh.is_convex for s in link.collisions)


def test_convex_pieces_of_a_concave_mesh_are_cached_and_have_a_fallback(tmp_path):
    tray = (m3.Manifold.cube([0.3, 0.2, 0.2]) - m3.Manifold.cube([0.2, 0.3, 0.15]).translate([0.05, -0.05, 0.05]))
    out = tray.to_mesh()
    mesh = trimesh.Trimesh(np.asarray(out.vert_properties)[:, :3], np.asarray(out.tri_verts))
    pieces = convex_pieces(mesh, tmp_path)
    assert len(pieces) >= 3 and all(p.is_convex for p in pieces)
    assert sum(p.volume for p in pieces) == pytest.approx(mesh.volume, rel=0.05)
    cached = tmp_path / f"{mesh_digest(mesh, 'coacd')}.npz"
    assert cached.is_file()
    with np.load(cached, allow_pickle=False) as data:
        assert data["vertex_counts"].sum() == len(data["vertices"])
    again = convex_pieces(mesh, tmp_path)
    assert [len(p.vertices) for p in again] == [len(p.vertices) for p in pieces]
    # without CoACD: hull of each connected component; a convex mesh is itself
    two = trimesh.util.concatenate([trimesh.creation.box(extents=(1, 1, 1)),
                                    trimesh.creation.box(extents=(1, 1, 1)).apply_translation((3, 0, 0))])
    assert len(convex_pieces(two, tmp_path, use_coacd=False)) == 2
    assert len(convex_pieces(trimesh.creation.box(extents=(1, 2, 3)), tmp_path)) == 1


def test_an_observed_scan_collides_as_its_hull_without_convex_decomposition():
    """A scanned object with no CAD model: a partial, open surface that changes with every map update.
    CoACD took 18-48 s per small real scan (20-49 pieces); its hull is one shape, at once."""
    import time

    from cad_replacement.collision import OBSERVED_MIN_THICKNESS, observed_collisions, shapes_volume

    cap = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    cap.update_faces(cap.triangles_center[:, 1] < 0.0)  # the camera-side half of a 10 cm ball: open
    cap.remove_unreferenced_vertices()
    assert not cap.is_watertight
    t0 = time.process_time()
    shapes = observed_collisions(cap)
    assert time.process_time() - t0 < 0.5
    assert len(shapes) == 1 and shapes[0].kind == "mesh"
    assert shapes_volume(shapes) == pytest.approx(cap.convex_hull.volume, rel=1e-6)
    # a scan of one flat face: its box, given a thickness
    flat = trimesh.Trimesh([[0, 0, 0], [0.2, 0, 0], [0.2, 0.1, 0], [0, 0.1, 0]], [[0, 1, 2], [0, 2, 3]])
    (box,) = observed_collisions(flat)
    assert box.kind == "box" and np.allclose(box.size, [0.2, 0.1, OBSERVED_MIN_THICKNESS])
    # a large scan of two separate parts (1.5 m apart): one hull per part, not one spanning the gap
    far = cap.copy()
    far.apply_translation([1.5, 0.0, 0.0])
    two = trimesh.util.concatenate([cap, far])
    assert len(observed_collisions(two)) == 2
    assert observed_collisions(trimesh.Trimesh()) == ()


def test_a_grounded_observed_scan_rests_on_a_footprint_under_its_centre_of_mass():
    """A chair scanned from the front: its seat and back reach the floor only through two front legs
    (an edge). Kept as its observed mesh, its hull would tip over; the grounded hull stands."""
    from scipy.spatial import ConvexHull

    from cad_replacement.collision import inertial_from_shapes, observed_collisions, shape_mesh

    seat = trimesh.creation.box([0.45, 0.45, 0.04]).apply_translation([0.0, 0.0, 0.45])
    back = trimesh.creation.box([0.04, 0.45, 0.5]).apply_translation([-0.2, 0.0, 0.72])
    legs = [trimesh.creation.box([0.03, 0.03, 0.43]).apply_translation([0.2, y, 0.215]) for y in (-0.2, 0.2)]
    scan = trimesh.util.concatenate([seat, back, *legs])
    for grounded in (False, True):
        shapes = observed_collisions(scan, grounded=grounded)
        assert all(s.kind == "mesh" and shape_mesh(s).is_convex for s in shapes)
        verts = np.concatenate([np.asarray(shape_mesh(s).vertices) for s in shapes])
        foot = verts[verts[:, 2] < 1e-6][:, :2]
        com = inertial_from_shapes(shapes, 500.0).center_of_mass
        area = ConvexHull(foot).volume if len(foot) >= 3 and np.ptp(foot[:, 0]) > 1e-3 else 0.0
        if grounded:  # a footprint as wide as the chair, under its centre of mass
            assert area > 0.15
            assert foot[:, 0].min() < com[0] < foot[:, 0].max()
        else:  # the front legs' edge only: x of every floor contact beyond the centre of mass
            assert area < 0.02 and foot[:, 0].min() > com[0]
