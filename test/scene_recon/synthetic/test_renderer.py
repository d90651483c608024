"""Ray-cast renderer: depth is exact z-depth, labels are the hit mesh, colours are plausible."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from scene_recon.synthetic import RaycastRenderer, backproject, look_at_pose
from scene_recon.synthetic.items import label_colors


def _distance_to(meshes, points: np.ndarray) -> np.ndarray:
    scene = o3d.t.geometry.RaycastingScene()
    for mesh in meshes:
        scene.add_triangles(
            o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)), o3d.core.Tensor(np.asarray(mesh.faces, np.uint32))
        )
    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


@pytest.fixture(scope="module")
def renderer(scene_items):
    return RaycastRenderer(scene_items)


@pytest.fixture(scope="module")
def hits(renderer, view_pose, intrinsics):
    return renderer.cast(view_pose, intrinsics)


def test_depth_backprojects_onto_meshes(hits, scene_items, view_pose, intrinsics):
    assert hits.depth.dtype == np.float32 and hits.depth.shape == (120, 160)
    valid = hits.depth > 0
    assert valid.all(), "a closed room: every ray hits something"
    pts = backproject(hits.depth, intrinsics, view_pose)[valid]
    dist = _distance_to([it.mesh for it in scene_items], pts)
    assert dist.max() < 1e-3, f"max distance to the mesh {dist.max() * 1e3:.3f} mm"
    # The renderer's own hit points agree with the back-projection.
    assert np.abs(hits.points[valid] - pts).max() < 1e-3


def test_depth_matches_analytic_floor_plane(hits, view_pose, intrinsics):
    """Rays hitting the floor (label 1, plane z = 0): analytic z-depth = -c_z / (R d)_z."""
    floor = hits.labels == 1
    assert floor.sum() > 500
    u, v = np.meshgrid(np.arange(160), np.arange(120))
    d_cam = np.stack([(u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy, np.ones(u.shape)], -1)
    d_world_z = d_cam @ view_pose[2, :3]
    depth = -view_pose[2, 3] / d_world_z
    assert np.abs(hits.depth[floor] - depth[floor]).max() < 1e-3


def test_open3d_create_rays_pinhole_is_z_depth_but_half_pixel_shifted(renderer, view_pose, intrinsics):
    """Documents why the renderer builds its own rays (REFERENCE.md claim checked)."""
    extrinsic = np.linalg.inv(view_pose)
    k = intrinsics.matrix
    rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(
        o3d.core.Tensor(k), o3d.core.Tensor(extrinsic), intrinsics.width, intrinsics.height
    ).numpy()
    # Direction has unit z in the camera frame -> t_hit is z-depth ...
    d_cam = rays[..., 3:].reshape(-1, 3) @ view_pose[:3, :3]
    np.testing.assert_allclose(d_cam[:, 2], 1.0, atol=1e-5)
    # ... but pixel (u, v) is sampled at (u + 0.5, v + 0.5).
    assert d_cam[0, 0] == pytest.approx((0.5 - intrinsics.cx) / intrinsics.fx, abs=1e-6)
    shifted = type(intrinsics)(intrinsics.fx, intrinsics.fy, intrinsics.cx - 0.5, intrinsics.cy - 0.5, 160, 120)
    ours = renderer.cast(view_pose, shifted).depth
    raw = renderer.cast_rays(rays[..., :3].reshape(-1, 3), rays[..., 3:].reshape(-1, 3))
    np.testing.assert_allclose(raw.t.reshape(120, 160), ours, atol=1e-4)


def test_labels_are_the_hit_mesh(hits, scene_items, view_pose, intrinsics):
    pts = backproject(hits.depth, intrinsics, view_pose)
    labels_seen = set(np.unique(hits.labels).tolist())
    assert {1, 10, 11, 12} <= labels_seen
    assert 0 not in labels_seen
    for item in scene_items:
        mask = hits.labels == item.label
        if not mask.any():
            continue
        dist = _distance_to([item.mesh], pts[mask])
        assert dist.max() < 1e-3, f"label {item.label}: pixel {dist.max():.4f} m off its mesh"
    np.testing.assert_array_equal(
        hits.labels, np.array([0] + [it.label for it in scene_items])[hits.item_index + 1]
    )


def test_normals_are_unit_and_face_the_camera(hits, intrinsics):
    n = hits.normals.reshape(-1, 3)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-4)
    u, v = np.meshgrid(np.arange(160), np.arange(120))
    rays = np.stack([(u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy, np.ones(u.shape)], -1)
    assert (np.sum(n * rays.reshape(-1, 3), axis=1) < 0).all()
    # Floor normals point up in the map frame.
    floor = hits.labels == 1
    np.testing.assert_allclose(hits.normals_world[floor], [[0, 0, 1]] * int(floor.sum()), atol=1e-5)
    assert hits.view_cos.min() >= 0 and hits.view_cos.max() <= 1


def test_no_hit_beyond_max_depth(scene_items, intrinsics):
    from scene_recon.synthetic import RenderConfig

    short = RaycastRenderer(scene_items, RenderConfig(max_depth_m=1.0))
    pose = look_at_pose(np.array([-1.6, -1.2, 1.5]), np.array([1.9, 1.4, 1.0]))  # across the room
    h = short.cast(pose, intrinsics)
    assert (h.depth == 0).any()
    assert (h.depth <= 1.0).all()
    assert ((h.depth == 0) == (h.labels == 0)).all()
    assert (h.item_index[h.depth == 0] == -1).all()


def test_colour_image_is_plausible(renderer, hits, intrinsics, tmp_path):
    rgb = renderer.shade(hits, intrinsics, np.random.default_rng(0))
    assert rgb.shape == (120, 160, 3) and rgb.dtype == np.uint8
    assert 30 < rgb.mean() < 220 and rgb.std() > 10
    means = {lab: rgb[hits.labels == lab].reshape(-1, 3).mean(axis=0) for lab in (10, 11, 12)}
    # Red box, blue box, green sphere: the dominant channel matches the base colour.
    assert np.argmax(means[10]) == 0 and np.argmax(means[11]) == 2 and np.argmax(means[12]) == 1
    for a in means:
        for b in means:
            if a < b:
                assert np.linalg.norm(means[a] - means[b]) > 40
    # Textured: a patterned object is not flat.
    assert rgb[hits.labels == 10].std() > 5
    # Deterministic per seed; noise-free without rng.
    np.testing.assert_array_equal(rgb, renderer.shade(hits, intrinsics, np.random.default_rng(0)))
    clean = renderer.shade(hits, intrinsics, None)
    assert 0 < np.abs(clean.astype(int) - rgb).mean() < 4
    import cv2

    assert cv2.imwrite(str(tmp_path / "color.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))


def test_texture_is_fixed_to_the_surface(renderer, intrinsics):
    """The same floor point seen from two views has the same albedo pattern (world-space texture)."""
    from scene_recon.synthetic import RenderConfig, ShadingConfig

    flat = RaycastRenderer(
        renderer.items,
        RenderConfig(shading=ShadingConfig(ambient=1.0, key_light=0.0, headlight=0.0, vignetting=0.0)),
    )
    pose_a = look_at_pose(np.array([-1.0, -1.0, 1.4]), np.array([0.0, -0.5, 0.0]))
    pose_b = look_at_pose(np.array([1.0, -1.2, 1.6]), np.array([0.0, -0.5, 0.0]))
    ha, hb = flat.cast(pose_a, intrinsics), flat.cast(pose_b, intrinsics)
    ca, cb = flat.shade(ha, intrinsics), flat.shade(hb, intrinsics)
    from scene_recon.synthetic.geometry import project

    floor_a = np.flatnonzero((ha.labels == 1).reshape(-1))
    pts = ha.points.reshape(-1, 3)[floor_a]
    uv, z = project(pts, intrinsics, pose_b)
    px = np.round(uv).astype(int)
    ok = (px[:, 0] >= 0) & (px[:, 0] < 160) & (px[:, 1] >= 0) & (px[:, 1] < 120) & (z > 0)
    ok[ok] &= hb.labels[px[ok, 1], px[ok, 0]] == 1
    assert ok.sum() > 300
    a = ca.reshape(-1, 3)[floor_a[ok]].astype(float)
    b = cb[px[ok, 1], px[ok, 0]].astype(float)
    corr = np.corrcoef(a[:, 0], b[:, 0])[0, 1]
    assert corr > 0.6, f"floor texture correlation across views only {corr:.2f}"


def test_label_colors_are_distinct():
    c = label_colors(np.arange(0, 40))
    assert (c[0] == 0).all()
    d = np.linalg.norm(c[1:, None, :].astype(float) - c[None, 1:, :].astype(float), axis=2)
    assert d[~np.eye(39, dtype=bool)].min() > 5
