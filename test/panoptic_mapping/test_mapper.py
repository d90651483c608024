"""The mapper's steps on hand-made frames with known answers, and the whole mapper on a tiny scene."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from testsupport.tiny_room import EYES, IDS, INTR, render_frame, room_meshes, room_renderer

from panoptic_mapping.config import FusionConfig, MapperConfig
from panoptic_mapping.depth_segmentation import segment_depth
from panoptic_mapping.fusion import BACKGROUND, PanopticMasks, fuse
from panoptic_mapping.mapper import ClassMeta, PanopticMapper
from panoptic_mapping.pipeline import class_metas

FLOOR, TABLE, CUP, CHAIR = 1, 10, 19, 12


@pytest.fixture(scope="module")
def tiny_scene():
    meshes = room_meshes()
    return meshes, room_renderer(meshes)


_frame = render_frame


def _gt_masks(labels: np.ndarray, classes=None) -> PanopticMasks:
    classes = classes or {1: FLOOR, 2: TABLE, 3: CUP, 4: CHAIR}
    n = 5
    cls = np.full(n, BACKGROUND, np.int32)
    thing = np.zeros(n, bool)
    for k, c in classes.items():
        cls[k], thing[k] = c, c != FLOOR
    return PanopticMasks(labels, cls, thing, np.ones(n))


def test_depth_segmentation_separates_objects_but_not_convex_faces(tiny_scene):
    _, renderer = tiny_scene
    frame, gt = _frame(renderer, (0.0, 0.0, 1.5))
    geo, _pts, normals = segment_depth(frame.depth, INTR, MapperConfig().depth_segmentation)
    # the table's top and front face (a convex edge) are one segment; floor and table differ
    table_segs = np.unique(geo[(gt == IDS["table"]) & (geo > 0)], return_counts=True)
    dominant = table_segs[0][np.argmax(table_segs[1])]
    assert table_segs[1].max() / (gt == IDS["table"]).sum() > 0.8
    # the floor lies in other segments: at most a sliver of floor pixels shares the table's segment
    floor = (gt == IDS["floor"]) & (geo > 0)
    assert np.mean(geo[floor] == dominant) < 0.05
    assert np.allclose(np.linalg.norm(normals[geo > 0], axis=1), 1.0, atol=1e-4)


def test_split_keeps_an_instance_geometry_cannot_separate():
    h, w = 40, 40
    geo = np.ones((h, w), np.int32)  # one geometric segment: a desk top with a flat "keyboard"
    pan = np.zeros((h, w), np.int32)
    pan[:, :] = 1  # desk mask
    pan[10:16, 10:20] = 2  # keyboard mask fully inside the segment, 60 of 1600 pixels
    masks = PanopticMasks(pan, np.array([BACKGROUND, TABLE, CUP]), np.array([False, True, True]), np.ones(3))
    pts = np.zeros((h, w, 3), np.float32)
    full = fuse(geo, masks, pts, FusionConfig(), full=True, min_points=10)
    base = fuse(geo, masks, pts, FusionConfig(), full=False, min_points=10)
    assert full.num_split == 1 and full.count == 2
    kb = full.image[12, 12]
    assert full.class_id[kb] == CUP and full.class_id[full.image[30, 30]] == TABLE
    assert base.count == 1 and base.class_id[1] == TABLE  # Voxblox++: the keyboard is lost


def test_euclidean_clustering_drops_far_parts_of_an_instance():
    h, w = 30, 60
    geo = np.zeros((h, w), np.int32)
    geo[:, :20] = 1  # chair
    geo[:, 40:] = 2  # far floor piece the chair mask bleeds onto
    pan = np.zeros((h, w), np.int32)
    pan[:, :20] = 1
    pan[:, 40:] = 1
    pts = np.zeros((h, w, 3), np.float32)
    pts[:, :20, 2] = 1.0
    pts[:, 40:, 2] = 3.0  # 2 m behind
    masks = PanopticMasks(pan, np.array([BACKGROUND, CHAIR]), np.array([False, True]), np.ones(2))
    full = fuse(geo, masks, pts, FusionConfig(), full=True, min_points=10)
    assert full.num_clustered_out == 1
    assert full.class_id[full.image[5, 5]] == CHAIR and full.class_id[full.image[5, 50]] == BACKGROUND
    base = fuse(geo, masks, pts, FusionConfig(), full=False, min_points=10)
    assert base.class_id[base.image[5, 50]] == CHAIR


def test_small_mask_share_makes_background():
    geo = np.ones((20, 20), np.int32)
    pan = np.zeros((20, 20), np.int32)
    pan[:3, :] = 1  # 15 % of the segment, and the mask is not contained enough to split (it is: disable split)
    masks = PanopticMasks(pan, np.array([BACKGROUND, TABLE]), np.array([False, True]), np.ones(2))
    out = fuse(geo, masks, np.zeros((20, 20, 3), np.float32), FusionConfig(split=False), full=True, min_points=1)
    assert out.class_id[1] == BACKGROUND


def _mapper(mode="full", keyframes=False) -> PanopticMapper:
    cfg = MapperConfig(mode=mode, downsample=1)
    cfg.keyframes.enabled = keyframes
    cfg.tsdf.voxel_size_m = 0.02
    cfg.fusion.min_segment_points = 40
    cfg.depth_segmentation.min_segment_pixels = 20
    return PanopticMapper(cfg, class_metas())


def _run(mapper, renderer, shuffle_ids: bool):
    rng = np.random.default_rng(0)
    for i, eye in enumerate(EYES):
        frame, gt = _frame(renderer, eye, index=i)
        classes = {1: FLOOR, 2: TABLE, 3: CUP, 4: CHAIR}
        if shuffle_ids:  # a network's instance ids change from frame to frame
            perm = rng.permutation([2, 3, 4])
            remap = np.array([0, 1, *perm])
            gt = remap[gt]
            classes = {1: FLOOR, **{int(remap[k]): classes[k] for k in (2, 3, 4)}}
        mapper.integrate(frame, _gt_masks(gt, classes))


def test_mapper_tracks_instances_across_frames_and_extracts_entities(tiny_scene):
    meshes, renderer = tiny_scene
    mapper = _mapper()
    _run(mapper, renderer, shuffle_ids=True)
    ents = mapper.entities()
    unknown = [e for e in ents if e.class_id == BACKGROUND]
    assert len(unknown) <= 1 and all(e.id == 0 and e.class_name == "unknown" for e in unknown)
    ents = [e for e in ents if e.class_id != BACKGROUND]
    by_class = {}
    for e in ents:
        by_class.setdefault(e.class_name, []).append(e)
    # one entity per object despite per-frame instance ids changing every frame
    assert sorted(by_class) == ["chair", "cup", "floor", "table"]
    assert all(len(v) == 1 for v in by_class.values()), {k: len(v) for k, v in by_class.items()}
    for name, e in [(n, by_class[n][0]) for n in ("table", "cup", "chair")]:
        mesh = meshes[name]
        # the entity's vertices lie on its object's surface (within a voxel or two)
        d = np.abs(trimesh.proximity.signed_distance(mesh, e.vertices))
        assert np.median(d) < 0.02, name
        assert e.confidence > 0.9
    assert by_class["floor"][0].instance_id == 0 and not by_class["floor"][0].is_thing


def test_keyframe_gating_reduces_segmentation_calls(tiny_scene):
    _, renderer = tiny_scene
    mapper = _mapper(keyframes=True)
    mapper.config.keyframes.min_translation_m = 0.4
    mapper.config.keyframes.max_interval_s = 10.0
    calls = 0
    for i in range(6):
        frame, gt = _frame(renderer, (0.0, 0.02 * i, 1.4), index=i)
        if mapper.is_keyframe(frame):
            mapper.mark_keyframe(frame)
            calls += 1
            mapper.integrate(frame, _gt_masks(gt))
        else:
            mapper.integrate(frame, None)
    assert calls == 1
    assert {e.class_name for e in mapper.entities()} >= {"table", "floor"}


def test_instance_merging_eq5_and_extraction_eq6():
    mapper = PanopticMapper(MapperConfig(), {TABLE: ClassMeta("table", True, "rigid"),
                                             CHAIR: ClassMeta("chair", True, "rigid")})
    c = mapper.counts
    l1, l2, l3 = c.new_label(), c.new_label(), c.new_label()
    p1, p2, p3 = c.new_instance(), c.new_instance(), c.new_instance()
    # p1 and p2 were both predicted on segments l1 and l2 (a split instance): shared votes dominate
    c.add(l1, TABLE, p1, 8)
    c.add(l1, TABLE, p2, 6)
    c.add(l2, TABLE, p2, 7)
    c.add(l2, TABLE, p1, 5)
    # p3 (mostly on its own segment l4) overlaps p1 only marginally on l3:
    # shared = 20 + 1 = 21 < 0.5 * (p1: 14 + p3: 50)
    l4 = c.new_label()
    c.add(l3, TABLE, p3, 20)
    c.add(l3, TABLE, p1, 1)
    c.add(l4, TABLE, p3, 30)
    merged = mapper._merge_instances(0.5, 10)
    assert merged == 1
    assert set(c.instance_votes(l1, TABLE)) == {p1} and set(c.instance_votes(l2, TABLE)) == {p1}
    assert c.instance_votes(l3, TABLE) == {p3: 20, p1: 1}
    # Eq. (6): l3's class is table and its instance the argmax p3
    c.add(l3, CHAIR, p3, 3)
    assert c.segment_class(l3) == (TABLE, 21, 24)


def test_baseline_tracks_instances_without_class(tiny_scene):
    _, renderer = tiny_scene
    full, base = _mapper("full"), _mapper("baseline")
    _run(full, renderer, shuffle_ids=False)
    _run(base, renderer, shuffle_ids=False)
    assert {e.class_name for e in base.entities()} >= {"table", "floor"}
    assert base.config.mode == "baseline" and not base.full


def test_save_load_round_trip_resumes(tiny_scene, tmp_path):
    _, renderer = tiny_scene
    mapper = _mapper()
    _run(mapper, renderer, shuffle_ids=False)
    before = {(e.class_name, len(e.vertices)) for e in mapper.entities()}
    mapper.save(tmp_path / "m")
    assert not list((tmp_path / "m").glob("*.pkl"))
    again = PanopticMapper.load(tmp_path / "m")
    after = {(e.class_name, len(e.vertices)) for e in again.entities()}
    assert before == after
    # the resumed map continues exactly like the original would have
    frame, gt = _frame(renderer, (0.2, 0.1, 1.5), index=9)
    mapper.integrate(frame, _gt_masks(gt))
    again.integrate(frame, _gt_masks(gt))
    assert again.counts.next_label == mapper.counts.next_label
    assert again.counts.phi == mapper.counts.phi
    with pytest.raises(FileNotFoundError):
        PanopticMapper.load(tmp_path / "missing")


def test_mask_on_edge_pixels_is_rescued_in_full_mode_only():
    geo = np.zeros((20, 20), np.int32)
    geo[:, 10:] = 1  # a segment; the left half is all depth-edge pixels
    pan = np.zeros((20, 20), np.int32)
    pan[5:10, 2:8] = 1  # a small object's mask, entirely on edge pixels
    pts = np.zeros((20, 20, 3), np.float32)
    pts[..., 2] = 1.0
    masks = PanopticMasks(pan, np.array([BACKGROUND, CUP]), np.array([False, True]), np.ones(2))
    full = fuse(geo, masks, pts, FusionConfig(), full=True, min_points=10)
    assert full.count == 2 and full.class_id[full.image[6, 3]] == CUP
    off = fuse(geo, masks, pts, FusionConfig(rescue_edge_masks=False), full=True, min_points=10)
    assert off.image[6, 3] == 0


def test_memory_grows_with_observed_surface_only(tiny_scene):
    _, renderer = tiny_scene
    mapper = _mapper()
    frame, gt = _frame(renderer, EYES[0], index=0)
    mapper.integrate(frame, _gt_masks(gt))
    blocks = mapper.tsdf.num_blocks
    for i in range(1, 4):  # the same view again: nothing new is allocated
        frame, gt = _frame(renderer, EYES[0], index=i)
        mapper.integrate(frame, None)
    assert mapper.tsdf.num_blocks == blocks
    frame, gt = _frame(renderer, (0.0, 0.0, 1.5), target=(-1.5, -1.0, 0.3), index=9)  # looks elsewhere
    mapper.integrate(frame, None)
    assert mapper.tsdf.num_blocks > blocks
    assert mapper.tsdf.memory_bytes() == mapper.tsdf.num_blocks * 8**3 * 16


def test_empty_map_extracts_nothing_without_error(tiny_scene):
    mapper = _mapper()
    assert mapper.entities() == []
    _, renderer = tiny_scene
    frame, gt = _frame(renderer, EYES[0], index=0)
    mapper.integrate(frame, _gt_masks(gt))  # one frame: voxel weights stay below the mesh threshold
    mapper.config.tsdf.mesh_weight_threshold = 1e9
    mapper._entity_cache = None
    assert all(len(e.faces) == 0 for e in mapper.entities())


def test_fringe_fill_is_marked_after_the_voted_core(tiny_scene):
    """The fill (extraction.fill_radius_m) completes an entity's surface, but its vertices carry no
    votes of their own: they come last and ``core_vertices`` counts the voted ones before them."""
    _, renderer = tiny_scene
    mapper = _mapper()
    _run(mapper, renderer, shuffle_ids=False)
    # faces given to the entity of two of their three vertices carry a neighbour's vertex along: that vertex is
    # the neighbour's vote, not this entity's core; only the fill is compared here
    mapper.config.extraction.face_majority = False
    # voted surface no view measured is fringe too (test_free_space): only the fill is compared here
    mapper.config.free_space.enabled = False
    mapper.config.extraction.fill_radius_m = 0.0
    bare = {e.id: e for e in mapper.entities() if e.class_id != BACKGROUND}
    mapper.config.extraction.fill_radius_m = 0.08
    mapper._entity_cache = None  # the extraction settings changed, not the map
    filled = {e.id: e for e in mapper.entities() if e.class_id != BACKGROUND}
    assert bare.keys() == filled.keys()
    fringed = 0
    for eid, e in filled.items():
        core = len(e.vertices) if e.core_vertices < 0 else e.core_vertices
        fringed += len(e.vertices) - core
        # every vertex the unfilled extraction gives the entity is voted: it lies in the core
        as_set = {tuple(p) for p in np.round(e.vertices[:core], 6)}
        assert all(tuple(p) in as_set for p in np.round(bare[eid].vertices, 6)), e.name
        v, f = e.core_mesh(min_faces=1)
        assert len(v) == core and (len(f) == 0 or f.max() < core)
    assert fringed > 0  # the fill did join unvoted vertices, and they were told apart


def test_a_still_camera_adds_one_frame_per_interval_and_a_move_is_never_skipped(tiny_scene):
    """Frames of a camera standing still add nothing (the same surfaces from the same place) once its
    first views are in (a surface is meshed from 2 observations): they are skipped whole, except one
    every static.max_interval_s (a still camera keeps seeing a changing scene); a frame that moved
    more than static.max_translation_m always counts."""
    import dataclasses

    _, renderer = tiny_scene
    mapper = _mapper()
    still, _ = _frame(renderer, EYES[0])
    integrated = []
    for i in range(45):  # 1.5 s at 30 Hz, with 1 mm / 0.05 deg of tracker jitter
        jitter = np.eye(4)
        jitter[:3, 3] = 0.001 * np.sin(i)
        c, s = np.cos(np.radians(0.05 * np.sin(i))), np.sin(np.radians(0.05 * np.sin(i)))
        jitter[:2, :2] = [[c, -s], [s, c]]
        frame = dataclasses.replace(still, pose=still.pose @ jitter, timestamp_ns=i * 33_333_333, index=i)
        if not mapper.is_static(frame):
            mapper.integrate_geometry(frame)
            integrated.append(i)
    # the first static.min_views (3) views, then the first frame a second after the last one integrated
    assert integrated == [0, 1, 2, 33]
    pose = still.pose.copy()
    pose[:3, 3] += [0.01, 0.0, 0.0]  # 1 cm: a move
    assert not mapper.is_static(dataclasses.replace(still, pose=pose, timestamp_ns=32 * 33_333_333))
    mapper.config.static.enabled = False
    assert not mapper.is_static(dataclasses.replace(still, timestamp_ns=32 * 33_333_333))
