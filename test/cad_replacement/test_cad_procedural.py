"""Procedural CAD classes: geometry validity, canonical frame, variety, kinematics."""

from __future__ import annotations

import manifold3d as m3
import numpy as np
import pytest
import trimesh

from cad_replacement.cad import CLASS_BUILDERS, CadModel, build_model
from recon_core.errors import UnknownClassError

SEEDS = range(10)
ARTICULATED = ("fridge", "microwave", "cabinet", "oven", "dishwasher", "wardrobe")
REQUIRED = (
    *ARTICULATED,
    "table",
    "chair",
    "sofa",
    "bed",
    "desk",
    "shelf",
    "monitor",
    "bag",
    "box",
    "cup",
    "bottle",
    "book",
)


def _solid(mesh: trimesh.Trimesh) -> m3.Manifold:
    return m3.Manifold(
        m3.Mesh(
            vert_properties=np.asarray(mesh.vertices, dtype=np.float32),
            tri_verts=np.asarray(mesh.faces, dtype=np.uint32),
        )
    )


def _overlap(a: trimesh.Trimesh, b: trimesh.Trimesh) -> float:
    return float((_solid(a) ^ _solid(b)).volume())


@pytest.fixture(scope="module")
def models() -> dict[tuple[str, int], CadModel]:
    return {(c, s): build_model(c, s) for c in CLASS_BUILDERS for s in SEEDS}


def test_required_classes_are_supported() -> None:
    assert set(REQUIRED) <= set(CLASS_BUILDERS)
    for name in ARTICULATED:
        assert CLASS_BUILDERS[name].articulated


@pytest.mark.parametrize("class_name", sorted(CLASS_BUILDERS))
def test_links_are_watertight_solids_and_joints_valid(models, class_name: str) -> None:
    for seed in SEEDS:
        m = models[(class_name, seed)]
        assert m.class_name == class_name
        for link in m.links:
            assert link.mesh.is_watertight, (class_name, seed, link.name)
            assert link.mesh.volume > 0.0, (class_name, seed, link.name)
        for j in m.joints:
            assert j.type in ("revolute", "prismatic", "fixed")
            assert np.isclose(np.linalg.norm(j.axis), 1.0)
            assert np.allclose(j.origin[:3, :3] @ j.origin[:3, :3].T, np.eye(3))
            if j.movable:
                assert j.lower < j.upper
                assert j.lower == 0.0  # closed configuration at 0
                if j.type == "revolute":
                    assert 0.5 < j.upper <= np.pi
                else:
                    assert 0.05 < j.upper < 1.0  # metres of drawer travel
        if class_name in ARTICULATED:
            assert m.movable_joints, (class_name, seed)
        else:
            assert not m.movable_joints, (class_name, seed)


@pytest.mark.parametrize("class_name", sorted(CLASS_BUILDERS))
def test_canonical_frame_and_dimensions(models, class_name: str) -> None:
    for seed in SEEDS:
        m = models[(class_name, seed)]
        lo, hi = m.mesh().bounds
        size = hi - lo
        assert lo[2] == pytest.approx(0.0, abs=1e-9)
        assert lo[:2] == pytest.approx(-hi[:2], abs=1e-9)  # centred in x and y
        assert m.size == pytest.approx(size, abs=1e-9)
        expected = [m.params["depth"], m.params["width"], m.params["height"]]
        assert size == pytest.approx(expected, abs=1e-9)
        assert m.features.box_center == pytest.approx([0.0, 0.0, 0.5 * size[2]], abs=1e-9)


@pytest.mark.parametrize("class_name", sorted(CLASS_BUILDERS))
def test_features_are_consistent(models, class_name: str) -> None:
    for seed in SEEDS:
        m = models[(class_name, seed)]
        f = m.features
        half = 0.5 * f.box_size
        for plane in f.planes:
            assert np.linalg.norm(plane.normal) == pytest.approx(1.0)
            dist = plane.signed_distance(f.box_center)[0]
            reach = np.abs(plane.normal) @ half
            if np.isclose(abs(dist), reach):  # a side of the bounding box: normal points away from it
                assert dist < 0.0
            else:  # an inner level (seat, shelf): a support plane facing up
                assert plane.support and plane.normal == pytest.approx([0.0, 0.0, 1.0])
                assert abs(dist) < reach
        link_names = {lk.name for lk in m.links}
        for s in f.support_surfaces:
            assert s.link in link_names
            assert 0.0 <= s.height <= f.box_size[2] + 1e-9
            assert np.all(np.abs(s.polygon) <= half[:2] + 1e-9)
            assert s.area > 0.0
            assert s.clearance is None or s.clearance > 0.0
        visible = [s for s in f.support_surfaces if not s.enclosed]
        for s in visible:  # every visible support surface is also a support plane
            assert any(p.support and abs(-p.d - s.height) < 1e-6 for p in f.planes)


@pytest.mark.parametrize("class_name", ["table", "desk", "shelf", "sofa", "bed", "chair", "cabinet", "fridge"])
def test_furniture_has_support_surfaces(models, class_name: str) -> None:
    for seed in SEEDS:
        assert any(not s.enclosed for s in models[(class_name, seed)].features.support_surfaces)


def test_shelf_levels_are_support_surfaces_with_clearance(models) -> None:
    for seed in SEEDS:
        m = models[("shelf", seed)]
        levels = sorted(s.height for s in m.features.support_surfaces if s.clearance is not None)
        assert len(levels) == m.params["levels"]
        gaps = np.diff([*levels, m.size[2]])
        assert np.all(gaps > 0.15)


@pytest.mark.parametrize("class_name", sorted(CLASS_BUILDERS))
def test_seeds_give_variety_and_are_deterministic(models, class_name: str) -> None:
    sizes = {tuple(np.round(models[(class_name, s)].size, 6)) for s in SEEDS}
    assert len(sizes) >= 8
    again = build_model(class_name, 3)
    assert again.size == pytest.approx(models[(class_name, 3)].size, abs=0.0)
    assert again.params == models[(class_name, 3)].params


def test_styles_vary_within_a_class(models) -> None:
    tables = {(models[("table", s)].params["top_shape"], models[("table", s)].params["base"]) for s in SEEDS}
    assert len(tables) >= 3
    layouts = {build_model("cabinet", s).params["layout"] for s in range(20)}
    assert {"doors", "drawers"} <= layouts


def test_overrides_and_target_size() -> None:
    m = build_model("table", 5, overrides={"top_shape": "rectangular", "width": 1.5, "depth": 0.9, "height": 0.74})
    assert m.size == pytest.approx([0.9, 1.5, 0.74])
    assert m.model_id != build_model("table", 5).model_id
    base = build_model("cabinet", 2)
    target = (0.5, 1.2, 0.9)
    fitted = build_model("cabinet", 2, target_size=target)
    assert fitted.size == pytest.approx(target)
    lo, hi = fitted.mesh().bounds
    assert hi - lo == pytest.approx(target, abs=1e-9)
    assert lo[2] == pytest.approx(0.0, abs=1e-12)
    assert [j.name for j in fitted.joints] == [j.name for j in base.joints]
    for lk in fitted.links:
        assert lk.mesh.is_watertight
    with pytest.raises(ValueError, match="unknown parameter"):
        build_model("table", 0, overrides={"legs": 3})
    with pytest.raises(ValueError, match="one of"):
        build_model("table", 0, overrides={"top_shape": "oval"})
    with pytest.raises(UnknownClassError, match="supported"):
        build_model("spaceship", 0)
    with pytest.raises(ValueError, match="seed"):
        build_model("table", -1)


def test_uniform_scaling_keeps_kinematics() -> None:
    m = build_model("fridge", 1)
    s = m.scaled(1.5)
    assert s.size == pytest.approx(1.5 * m.size)
    j = m.movable_joints[0]
    q = {j.name: 1.0}
    pa, pb = m.link_poses(q)[j.child], s.link_poses(q)[j.child]
    assert pb[:3, :3] == pytest.approx(pa[:3, :3])
    assert pb[:3, 3] == pytest.approx(1.5 * pa[:3, 3])


@pytest.mark.parametrize("class_name", ARTICULATED)
def test_forward_kinematics_opens_without_hitting_the_body(models, class_name: str) -> None:
    for seed in range(4):
        m = models[(class_name, seed)]
        closed = m.link_poses()
        body = m.link(m.root_link).mesh
        for j in m.movable_joints:
            opened = m.link_poses({j.name: j.upper})
            moved = opened[j.child] @ np.linalg.inv(closed[j.child])
            if j.type == "revolute":
                angle = np.arccos(np.clip((np.trace(moved[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))
                assert angle == pytest.approx(j.upper, abs=1e-9)
            else:
                assert moved[:3, 3] == pytest.approx(j.upper * np.array([1.0, 0.0, 0.0]), abs=1e-9)
            child = m.link(j.child).mesh.copy()
            child.apply_transform(opened[j.child])
            # Fronts open outwards (+x): the moved link ends up further out, and barely touches the body.
            assert child.bounds[1][0] > m.mesh().bounds[1][0]
            assert _overlap(child, body) <= 1e-3 * child.volume, (class_name, seed, j.name)


def test_closed_links_do_not_interpenetrate(models) -> None:
    for class_name in ARTICULATED:
        m = models[(class_name, 0)]
        meshes = m.posed_link_meshes()
        body = meshes.pop(m.root_link)
        for name, mesh in meshes.items():
            assert _overlap(mesh, body) < 1e-7, (class_name, name)


def test_joint_values_are_clipped_and_checked(models) -> None:
    m = models[("microwave", 0)]
    j = m.movable_joints[0]
    assert np.allclose(m.link_poses({j.name: 10.0})[j.child], m.link_poses({j.name: j.upper})[j.child])
    with pytest.raises(KeyError, match="no movable joint"):
        m.link_poses({"nope": 0.1})
    mesh = m.mesh({j.name: 1.0})
    assert len(mesh.faces) == sum(len(lk.mesh.faces) for lk in m.links)


def test_features_without_meshes_equal_the_built_models(models) -> None:
    """The library computes features from the parts alone (``procedural_features``): the same numbers as the
    built model's, for every class and seed, and for a front-layout override."""
    import json

    from cad_replacement.cad.procedural import procedural_features

    def same(a, b) -> bool:
        return json.dumps(a.to_dict(), sort_keys=True) == json.dumps(b.to_dict(), sort_keys=True)

    for (class_name, seed), model in models.items():
        assert same(procedural_features(class_name, seed), model.features), (class_name, seed)
    overrides = {"layout": "drawers"}
    assert same(procedural_features("cabinet", 2, overrides=overrides),
                build_model("cabinet", 2, overrides=overrides).features)
