"""Free-space evidence (`panoptic_mapping.free_space`, issue 22 item 4): a point a stored view looked
through is told apart from one it saw and one hidden behind a nearer surface; the silhouette's margin,
the view store's thinning and its saved state."""

from __future__ import annotations

import numpy as np
import pytest
from testsupport.tiny_room import box, render_frame, room_meshes, room_renderer, tiny_mapper_config

from panoptic_mapping.config import FreeSpaceConfig
from panoptic_mapping.free_space import FreeSpaceViews
from panoptic_mapping.fusion import BACKGROUND, PanopticMasks
from panoptic_mapping.mapper import PanopticMapper
from panoptic_mapping.pipeline import class_metas

K = np.array([[100.0, 0.0, 49.5], [0.0, 100.0, 39.5], [0.0, 0.0, 1.0]])


def _views(cfg: FreeSpaceConfig | None = None) -> FreeSpaceViews:
    return FreeSpaceViews(cfg or FreeSpaceConfig(enabled=True), voxel_size_m=0.02)


def _wall_with_plate() -> np.ndarray:
    """Depth of a camera at the origin looking along +z: a wall at 2 m, a plate at 1 m over the left half."""
    depth = np.full((80, 100), 2.0, np.float32)
    depth[:, :50] = 1.0
    return depth


def test_seen_looked_through_and_hidden_points():
    views = _views()
    views.add(_wall_with_plate(), K, np.eye(4))
    # right half (wall at 2 m): on the wall, 0.5 m in front of it, 0.5 m behind it
    pts = np.array([[0.5, 0.0, 2.0], [0.25, 0.0, 1.5], [0.75, 0.0, 2.5],
                    # left half (plate at 1 m): on the plate, behind it (hidden, as a shadow is)
                    [-0.5, 0.0, 1.0], [-0.75, 0.0, 1.5]])
    c = views.count(pts)
    assert c.seen.tolist() == [1, 0, 0, 1, 0]
    assert c.through.tolist() == [0, 1, 0, 0, 0]
    # outside the image, or behind the camera: neither
    far = views.count(np.array([[50.0, 0.0, 2.0], [0.0, 0.0, -1.0]]))
    assert far.seen.tolist() == [0, 0] and far.through.tolist() == [0, 0]


def test_the_rule_needs_several_views_and_more_than_saw_the_point():
    views = _views(FreeSpaceConfig(enabled=True, min_through=2, through_ratio=1.0, min_seen=0))
    p = np.array([[0.25, 0.0, 1.5]])  # in front of the wall
    views.add(_wall_with_plate(), K, np.eye(4))
    assert not views.carved(p)[0]  # one view is not enough
    views.add(_wall_with_plate(), K, np.eye(4))
    assert views.carved(p)[0]
    # a point seen as often as looked through stays
    c = views.count(p)
    c.seen[:] = c.through
    assert not c.carved(2, 1.0)[0]


def test_a_point_measured_in_fewer_than_min_seen_views_is_carved():
    views = _views(FreeSpaceConfig(enabled=True, min_seen=2))
    on_wall, hidden = np.array([[0.5, 0.0, 2.0]]), np.array([[-0.75, 0.0, 1.5]])
    views.add(_wall_with_plate(), K, np.eye(4))
    assert views.carved(on_wall)[0] and views.carved(hidden)[0]  # one view measured the wall: not enough
    views.add(_wall_with_plate(), K, np.eye(4))
    assert not views.carved(on_wall)[0] and views.carved(hidden)[0]  # behind the plate: never measured


def test_the_fine_surface_has_a_tolerance_of_its_own():
    """2.5 cm behind the plate (where the 5 mm fine surface's truncation band closes a face seen from one side)
    is within the room's 2 cm + 1 cm/m, so a room vertex there counts as measured; with the fine surface's
    fixed part (1 cm) it does not, and a fine vertex on the plate still does."""
    views = _views()
    fine = FreeSpaceConfig().fine_tolerance_m
    assert fine == pytest.approx(0.01)
    views.add(_wall_with_plate(), K, np.eye(4))
    behind, on = np.array([[-0.3, 0.0, 1.025]]), np.array([[-0.3, 0.0, 1.006]])
    assert views.count(behind).seen[0] == 1
    counted = views.count(behind, base_tolerance_m=fine)
    assert counted.seen[0] == 0 and counted.through[0] == 0  # hidden, not looked through
    assert views.count(on, base_tolerance_m=fine).seen[0] == 1
    views.add(_wall_with_plate(), K, np.eye(4))
    assert not views.carved(behind)[0] and views.carved(behind, base_tolerance_m=fine)[0]


def test_a_silhouette_edge_is_not_looked_through():
    """The wall's pixels right beside the plate's edge must not look through the plate's own border."""
    edge = np.array([[-0.02, 0.0, 1.0]])  # on the plate, 2 cm inside its edge
    tight = _views(FreeSpaceConfig(enabled=True, downsample=1, edge_margin_px=0))
    wide = _views(FreeSpaceConfig(enabled=True, downsample=1, edge_margin_px=2))
    shifted = np.eye(4)
    shifted[0, 3] = -0.03  # the view's pose 3 cm off: the point lands one pixel beyond the plate's edge
    for views in (tight, wide):
        views.add(_wall_with_plate(), K, shifted)
    assert tight.count(edge).through[0] == 1
    assert wide.count(edge).through[0] == 0


def test_views_are_thinned_over_the_whole_recording_and_saved():
    views = _views(FreeSpaceConfig(enabled=True, max_views=4))
    for i in range(10):
        pose = np.eye(4)
        pose[0, 3] = i
        views.add(_wall_with_plate(), K, pose)
    assert len(views) <= 4
    xs = [p[0, 3] for p in views.poses]
    assert xs[0] == 0 and xs[-1] >= 6  # spread from the first frame to late ones, not the first four
    other = _views(FreeSpaceConfig(enabled=True, max_views=4))
    other.load_state(views.state())
    pts = np.random.default_rng(0).uniform([-1, -0.5, 0.5], [1, 0.5, 2.5], (200, 3))
    a, b = views.count(pts), other.count(pts)
    assert np.array_equal(a.seen, b.seen) and np.array_equal(a.through, b.through)
    assert other.stride == views.stride and other.offered == views.offered


def test_views_of_a_camera_whose_resolution_changed_save_and_load():
    views = _views()
    views.add(_wall_with_plate(), K, np.eye(4))
    views.add(np.full((60, 90), 2.0, np.float32), K, np.eye(4))  # another resolution mid-recording
    other = _views()
    other.load_state(views.state())
    assert [d.shape for d in other.depth_mm] == [(40, 50), (30, 45)]
    assert all(np.array_equal(a, b) for a, b in zip(views.near_mm, other.near_mm, strict=True))
    empty = _views()
    empty.load_state(_views().state())
    assert len(empty) == 0


def test_depth_is_stored_at_the_configured_stride():
    views = _views(FreeSpaceConfig(enabled=True, downsample=2))
    views.add(_wall_with_plate(), K, np.eye(4))
    assert views.depth_mm[0].shape == (40, 50)
    assert views.count(np.array([[0.5, 0.0, 2.0]])).seen[0] == 1


# ---------------------------------------------------------------------------------------------- in the mapper
BOOK_BACK_X = 1.52  # the book stands on the table, x 1.50-1.52: its front faces the cameras, its back does not


def _map_book(fine: bool) -> PanopticMapper:
    """A 2 cm book standing on the tiny room's table, mapped from ten views in front of it, free space on;
    `fine`: small things on the 5 mm grid as well (`fine_surface`, the default)."""
    meta = class_metas()
    book = next(k for k, v in meta.items() if v.name == "book")
    meshes = room_meshes()
    meshes["cup"] = box([1.50, -0.10, 0.70], [BOOK_BACK_X, 0.10, 0.95])
    renderer = room_renderer(meshes)
    cfg = tiny_mapper_config(min_segment_points=50, min_segment_pixels=50)
    cfg.free_space.enabled = True
    cfg.fine_surface.enabled = fine
    mapper = PanopticMapper(cfg, meta)
    cls = np.array([BACKGROUND, 1, 10, book, 12], np.int32)  # floor, table, book, chair
    eyes = [(0.4, y, z) for y in (-0.6, -0.3, 0.0, 0.3, 0.6) for z in (1.2, 1.6)]
    for i, eye in enumerate(eyes):
        frame, gt = render_frame(renderer, eye, target=(1.51, 0.0, 0.8), index=i)
        mapper.integrate(frame, PanopticMasks(gt.astype(np.int32), cls, cls > 1, np.ones(5)))
    return mapper


@pytest.fixture(scope="module")
def book_map():
    """The book on the room's 2 cm grid alone: its truncation band is what the free-space test carves."""
    return _map_book(fine=False)


def _book(mapper: PanopticMapper, **settings) -> tuple[np.ndarray, np.ndarray]:
    """(all vertices, core vertices) of the book entity under these `free_space` settings."""
    for key, value in settings.items():
        setattr(mapper.config.free_space, key, value)
    mapper._entity_cache = None
    book = next(e for e in mapper.entities() if e.class_name == "book")
    return book.vertices, book.core_mesh(min_faces=1)[0]


def test_the_surface_no_view_measured_behind_a_book_leaves_its_core(book_map):
    """The truncation band closes the book 4 cm behind its front face; no view measured that surface. It stays
    the entity's surface (panoptic quality counts it) but as fringe: what fitting reads is the core."""
    shadow = BOOK_BACK_X + 0.01
    before, core_before = _book(book_map, enabled=False)
    after, core_after = _book(book_map, enabled=True, min_seen=2)
    assert len(after) == len(before)
    assert (core_before[:, 0] > shadow).sum() >= 10
    assert (core_after[:, 0] > shadow).sum() * 2 < (core_before[:, 0] > shadow).sum()
    front = np.abs(core_before[:, 0] - 1.50) < 0.011
    assert (np.abs(core_after[:, 0] - 1.50) < 0.011).sum() == front.sum()  # the seen face stays core
    _book(book_map, min_seen=0)


def test_a_saved_map_keeps_its_views(book_map, tmp_path):
    _book(book_map, min_seen=2)
    book_map.save(tmp_path)
    again = PanopticMapper.load(tmp_path)
    assert len(again.free_space) == len(book_map.free_space) == 10
    for a, b in zip(_book(again, min_seen=2), _book(book_map), strict=True):
        assert np.array_equal(np.sort(a, axis=0), np.sort(b, axis=0))
    _book(book_map, min_seen=0)


def test_with_the_fine_surface_the_books_core_is_its_true_thickness(book_map):
    """The default map (5 mm surface of small things, free space on): what fitting reads of the 2 cm book lies
    within a few millimetres of its true faces, where the 2 cm grid alone (`book_map`) closes it centimetres
    behind."""
    _, core = _book(_map_book(fine=True))
    assert len(core) >= 100
    lo, hi = np.percentile(core[:, 0], [1, 99])
    assert lo >= 1.49 and hi <= BOOK_BACK_X + 0.008, (lo, hi)
    _, coarse_core = _book(book_map, enabled=True, min_seen=2)
    assert np.percentile(coarse_core[:, 0], 99) > BOOK_BACK_X + 0.015  # the 2 cm grid alone: centimetres behind


def test_a_point_measured_by_few_of_its_things_views_is_carved_with_a_share():
    """Ten views measure a thing's points on the plate; only two of them measure its point on the wall (the
    other eight stand where a nearer surface hides it): enough for `min_seen` (2), not for a quarter of the
    thing's median (10). Another thing's point measured twice, with a median of two, stays."""
    views = _views(FreeSpaceConfig(enabled=True, min_seen=2))
    for _ in range(2):
        views.add(_wall_with_plate(), K, np.eye(4))
    for _ in range(8):
        views.add(np.full((80, 100), 1.0, np.float32), K, np.eye(4))  # a plate over the whole image
    plate = [[-0.3, 0.0, 1.0], [-0.25, 0.05, 1.0], [-0.35, -0.05, 1.0], [-0.2, 0.1, 1.0]]
    pts = np.array([*plate, [0.3, 0.0, 2.0], [0.35, 0.05, 2.0]])
    owner = np.array([7, 7, 7, 7, 7, 9])
    assert views.count(pts).seen.tolist() == [10, 10, 10, 10, 2, 2]
    assert not views.carved(pts).any()
    assert not views.carved(pts, owner=owner).any()  # no share: the absolute rule alone
    assert views.carved(pts, owner=owner, min_seen_share=0.25).tolist() == [False] * 4 + [True, False]


def test_the_mapper_tests_the_fine_surface_with_its_own_tolerance(monkeypatch):
    """Extraction tests the room's surface with the room's tolerance and the small things' fine surface with
    `free_space.fine_tolerance_m`; a looser one keeps more of the fine book's surface as core."""
    mapper = _map_book(fine=True)
    calls: list[float | None] = []
    shares: list[float] = []
    carved = FreeSpaceViews.carved

    def spy(self, points, base_tolerance_m=None, owner=None, min_seen_share=0.0):
        calls.append(base_tolerance_m)
        shares.append(min_seen_share if owner is not None else -1.0)
        return carved(self, points, base_tolerance_m, owner, min_seen_share)

    monkeypatch.setattr(FreeSpaceViews, "carved", spy)
    mapper.config.free_space.fine_tolerance_m = 0.0
    _, strict = _book(mapper)
    assert calls == [None, 0.0]
    assert shares == [-1.0, mapper.config.free_space.fine_min_seen_share]  # the share for the fine surface only
    mapper.config.free_space.fine_tolerance_m = 0.05
    _, loose = _book(mapper)
    assert calls[2:] == [None, 0.05]
    assert len(loose) > len(strict)


def test_observed_is_what_views_looked_at_up_to_their_readings():
    views = _views(FreeSpaceConfig(enabled=True, min_seen=2))
    views.add(_wall_with_plate(), K, np.eye(4))
    pts = np.array([[0.25, 0.0, 1.5], [0.5, 0.0, 2.0],  # in front of the wall, on it: observed
                    [0.75, 0.0, 2.5], [-0.75, 0.0, 1.5],  # behind the wall, behind the plate: unknown
                    [50.0, 0.0, 2.0], [0.0, 0.0, -1.0]])  # outside the image, behind the camera: unknown
    assert views.observed(pts, 0.01).tolist() == [True, True, False, False, False, False]
    assert not views.observed(pts, 0.01, min_views=2).any()  # one view is not two
    views.add(_wall_with_plate(), K, np.eye(4))
    assert views.observed(pts, 0.01, min_views=2).tolist() == [True, True, False, False, False, False]
    # the grid counts a cell as observed when min_seen views did
    grid = views.observed_space(np.array([0.2, -0.1, 1.4]), np.array([0.8, 0.1, 2.6]), 12)
    assert grid is not None and grid.observed_at(np.array([[0.3, 0.0, 1.5]]))[0]
    assert not grid.observed_at(np.array([[0.3, 0.0, 2.4]]))[0]  # behind the wall
    assert _views().observed_space(np.zeros(3), np.ones(3), 4) is None  # no views: no grid


def test_the_observed_grid_is_attached_to_things_only_when_asked(book_map):
    book_map.config.free_space.observed_grid = True
    book_map._entity_cache = None
    try:
        ents = book_map.entities()
        book = next(e for e in ents if e.class_name == "book")
        assert all(e.observed_space is None for e in ents if not e.is_thing)
        space = book.observed_space
        assert space is not None and max(space.shape) == book_map.config.free_space.observed_grid_cells
        # in front of the book (where the cameras stood) observed; the space behind it, hidden, unknown;
        # the table the book stands on is another entity's surface: taken, so observed
        assert space.observed_at(np.array([[1.42, 0.0, 0.85]]))[0]
        assert not space.observed_at(np.array([[BOOK_BACK_X + 0.06, 0.0, 0.85]]))[0]
        assert space.observed_at(np.array([[1.7, 0.0, 0.69]]))[0]
    finally:
        book_map.config.free_space.observed_grid = False
        book_map._entity_cache = None
    assert all(e.observed_space is None for e in book_map.entities())
