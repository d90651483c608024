"""Support levels of an object kept as its scan (issue 22): what was seen inside it rests where it was seen.

Before, a scan's only support surface was its top: on gen-5151's ground-truth entities the final snap
lifted two books and a cup from a cabinet scan's inner shelves onto its top, 13-30 cm.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cad_replacement.actions import support_spots
from cad_replacement.cad.features import SCAN_TOP_BAND, scan_features
from cad_replacement.export import export_scene
from cad_replacement.layout_models import box_model
from cad_replacement.observed_physics import settle_observed
from cad_replacement.physical_check import SCAN_LEVEL_TOLERANCE_M, snap_to_supports, support_for
from cad_replacement.scene_model import PlacedObject, ReplacedScene
from recon_core.contact_graph import GraphNode
from recon_core.entity import Entity
from recon_core.geometry.box_fit import fit_gravity_box
from recon_core.geometry.transforms import as_mesh
from scene_recon.evaluation.physics import check_mujoco, check_pybullet

#: An open shelf unit 0.8 m wide, 0.4 m deep, 0.9 m tall with boards 2 cm thick: the middle one's top at 0.46 m.
SHELF_TOP = 0.46
UNIT_TOP = 0.90


def _shelf_unit() -> trimesh.Trimesh:
    t = 0.02
    parts = [
        trimesh.creation.box([0.8, 0.4, t]).apply_translation([0.0, 0.0, t / 2]),              # bottom board
        trimesh.creation.box([0.8, 0.4, t]).apply_translation([0.0, 0.0, UNIT_TOP - t / 2]),   # top board
        trimesh.creation.box([0.8, 0.4, t]).apply_translation([0.0, 0.0, SHELF_TOP - t / 2]),  # middle shelf
        trimesh.creation.box([t, 0.4, UNIT_TOP]).apply_translation([-0.4 + t / 2, 0.0, UNIT_TOP / 2]),
        trimesh.creation.box([t, 0.4, UNIT_TOP]).apply_translation([0.4 - t / 2, 0.0, UNIT_TOP / 2]),
        trimesh.creation.box([0.8, t, UNIT_TOP]).apply_translation([0.0, 0.2 - t / 2, UNIT_TOP / 2]),  # back
    ]
    return as_mesh(trimesh.util.concatenate(parts))


def _observed(nid: int, name: str, class_name: str, mesh: trimesh.Trimesh, movable: bool,
              parent: str) -> PlacedObject:
    from cad_replacement.replacer import observed_mesh_object

    node = GraphNode(nid, name, class_name, "object", box=fit_gravity_box(np.asarray(mesh.vertices)), movable=movable)
    obj = observed_mesh_object(node, Entity.from_mesh(nid, name, class_name, mesh), parent,
                               "floating" if movable else "fixed")
    assert obj is not None
    return obj


def _book(nid: int, bottom: float, x: float = 0.0) -> PlacedObject:
    mesh = trimesh.creation.box([0.22, 0.16, 0.03]).apply_translation([x, -0.02, bottom + 0.015])
    return _observed(nid, f"book_{nid}", "book", mesh, True, parent="cabinet_1")


def _bottom(obj: PlacedObject) -> float:
    v = np.asarray(obj.model.links[0].mesh.vertices)
    return float((v @ obj.pose[:3, :3].T + obj.pose[:3, 3])[:, 2].min())


def test_a_scan_has_its_top_and_the_levels_seen_below_it():
    feats = scan_features(_shelf_unit())
    heights = [s.height for s in feats.support_surfaces]
    assert heights[0] == pytest.approx(UNIT_TOP)  # the top: the box's footprint, unbounded above
    assert feats.support_surfaces[0].clearance is None
    assert np.allclose(np.ptp(feats.support_surfaces[0].polygon, axis=0), [0.8, 0.4])
    inner = {round(h, 3): s for h, s in zip(heights[1:], feats.support_surfaces[1:], strict=True)}
    assert set(inner) == {SHELF_TOP, 0.02}  # the middle shelf and the bottom board (the top board is the top)
    assert inner[SHELF_TOP].clearance == pytest.approx(UNIT_TOP - 0.02 - SHELF_TOP, abs=0.01)
    assert all(h < UNIT_TOP - SCAN_TOP_BAND for h in inner)
    # a scan with nothing flat inside it (a sphere) has its top alone
    assert len(scan_features(trimesh.creation.icosphere(radius=0.1)).support_surfaces) == 1


def test_what_was_seen_on_an_inner_shelf_stays_there_and_the_rest_goes_on_top():
    cabinet = _observed(1, "cabinet_1", "cabinet", _shelf_unit(), False, parent="map")
    on_shelf = _book(2, SHELF_TOP)
    above_shelf = _book(3, SHELF_TOP + 0.02, x=0.25)  # mapped 2 cm high: still the shelf
    far = _book(4, SHELF_TOP + 0.16, x=-0.25)  # nothing the scan saw within 3 cm: its top
    scene = ReplacedScene("shelf", [cabinet, on_shelf, above_shelf, far])
    spots = support_spots(cabinet)
    assert support_for(cabinet, on_shelf, spots).height == pytest.approx(SHELF_TOP)
    assert SCAN_LEVEL_TOLERANCE_M < 0.16
    gaps = snap_to_supports(scene)
    assert _bottom(on_shelf) == pytest.approx(SHELF_TOP, abs=1e-6) and gaps["book_2"] < 1e-6
    assert _bottom(above_shelf) == pytest.approx(SHELF_TOP, abs=1e-6)
    assert _bottom(far) == pytest.approx(UNIT_TOP, abs=1e-6)


@pytest.mark.parametrize("check", [check_pybullet, check_mujoco], ids=["pybullet", "mujoco"])
def test_a_book_on_a_scanned_shelf_stays_still(tmp_path, check):
    floor_pose = np.eye(4)
    floor_pose[2, 3] = -0.1  # a box model's origin is its bottom centre: the floor's top at z = 0
    floor = PlacedObject("floor", "floor", box_model("floor", [3.0, 3.0, 0.1]), floor_pose)
    cabinet = _observed(1, "cabinet_1", "cabinet", _shelf_unit(), False, parent="floor")
    book = _book(2, SHELF_TOP)
    scene = ReplacedScene("shelf", [floor, cabinet, book])
    snap_to_supports(scene)
    settle_observed(scene.objects)
    report = check(export_scene(scene, tmp_path / "scene", glb=False).folder, seconds=2.0)
    assert report.loaded and not report.errors
    assert report.still_fraction == 1.0, report.displacement
    assert _bottom(book) == pytest.approx(SHELF_TOP, abs=1e-6)


def _book_on_a_bled_cabinet(tmp_path, drop: bool):
    """A book standing on a cabinet scan whose mask took the book's lower 7 cm (bench-small, draw 1)."""
    floor_pose = np.eye(4)
    floor_pose[2, 3] = -0.1
    floor = PlacedObject("floor", "floor", box_model("floor", [3.0, 3.0, 0.1]), floor_pose)
    body = trimesh.creation.box([0.8, 0.4, 1.0]).apply_translation([0.0, 0.0, 0.5])
    bleed = trimesh.creation.box([0.2, 0.04, 0.07]).apply_translation([0.1, 0.0, 1.035])
    scan = as_mesh(trimesh.util.concatenate([body, bleed]))
    cabinet = _observed(1, "cabinet_1", "cabinet", scan, False, parent="floor")
    book = _observed(2, "book_2", "book", trimesh.creation.box([0.2, 0.03, 0.28]).apply_translation(
        [0.1, 0.0, 1.14]), True, parent="cabinet_1")
    scene = ReplacedScene("bled", [floor, cabinet, book])
    changes = settle_observed(scene.objects, drop=drop, patch=False)
    snap_to_supports(scene)
    changes_after = settle_observed(scene.objects, drop=drop)
    report = check_pybullet(export_scene(scene, tmp_path / f"drop_{drop}", glb=False).folder, seconds=2.0)
    return book, changes, changes_after, report


def test_a_fixed_scan_gives_up_the_pieces_its_mask_took_of_what_stands_on_it(tmp_path):
    book, changes, after, report = _book_on_a_bled_cabinet(tmp_path, drop=True)
    assert _bottom(book) == pytest.approx(1.0, abs=1e-6)  # on the cabinet's own top, not on the bleed
    assert changes["cabinet_1"]["dropped"] > 0 and after["cabinet_1"]["patches"] == 1
    assert report.loaded and report.still_fraction == 1.0, report.displacement
    _book, _c, _a, kept = _book_on_a_bled_cabinet(tmp_path, drop=False)
    assert kept.still_fraction == 0.0, kept.displacement  # the bleed, kept, throws the book off


def test_a_fixed_scan_with_nothing_on_it_keeps_its_pieces_beside_one_that_drops():
    # the fridge beside the bled cabinet carries nothing: nothing of it is dropped, and no piece is looked up
    fridge = _observed(5, "fridge_5", "fridge", trimesh.creation.box([0.6, 0.6, 1.6]).apply_translation(
        [1.5, 0.0, 0.8]), False, parent="map")
    chair = _observed(6, "chair_6", "chair", trimesh.creation.box([0.4, 0.4, 0.9]).apply_translation(
        [1.0, 0.0, 0.45]), True, parent="map")
    pieces = len(fridge.model.links[0].collisions or ())
    changes = settle_observed([fridge, chair], patch=False)
    assert "fridge_5" not in changes and len(fridge.model.links[0].collisions or ()) == pieces
    assert settle_observed([fridge], patch=False) == {}  # alone: no piece of anything is built


def _observed_on_the_floor(nid: int, name: str, class_name: str, mesh: trimesh.Trimesh, movable: bool,
                           parent: str) -> PlacedObject:
    """A scan whose mapped box the graph grew down to the floor (z = 0) below what the camera saw of it."""
    from cad_replacement.replacer import observed_mesh_object

    v = np.asarray(mesh.vertices)
    foot = np.c_[v[:, :2], np.zeros(len(v))]
    node = GraphNode(nid, name, class_name, "object", box=fit_gravity_box(np.r_[v, foot]), movable=movable)
    obj = observed_mesh_object(node, Entity.from_mesh(nid, name, class_name, mesh), parent,
                               "floating" if movable else "fixed")
    assert obj is not None
    return obj


def _floor() -> PlacedObject:
    floor_pose = np.eye(4)
    floor_pose[2, 3] = -0.1  # a box model's origin is its bottom centre: the floor's top at z = 0
    return PlacedObject("floor", "floor", box_model("floor", [3.0, 3.0, 0.1]), floor_pose)


def test_a_scan_whose_foot_was_not_seen_stays_where_it_was_seen_with_what_stands_on_it():
    """gen-7373's corner cabinet: its lower front (24 cm) hidden behind a chair. Resting its lowest *seen*
    point on the floor sank the scan by 24 cm and the cup on its top with it."""
    seen = trimesh.creation.box([0.55, 0.8, 0.76]).apply_translation([0.0, 0.0, 0.24 + 0.38])  # 0.24-1.00 m
    cabinet = _observed_on_the_floor(1, "cabinet_1", "cabinet", seen, False, parent="floor")
    cup = _observed(2, "cup_2", "cup", trimesh.creation.cylinder(radius=0.04, height=0.1).apply_translation(
        [0.1, 0.0, 1.05]), True, parent="cabinet_1")
    assert cabinet.resting_height() == pytest.approx(0.0, abs=1e-9)  # its box's bottom, below the scan
    assert _bottom(cabinet) == pytest.approx(0.24, abs=1e-6)
    gaps = snap_to_supports(ReplacedScene("corner", [_floor(), cabinet, cup]))
    assert gaps["cabinet_1"] < 1e-6 and _bottom(cabinet) == pytest.approx(0.24, abs=1e-6)
    assert _bottom(cup) == pytest.approx(1.0, abs=1e-6)
    # a CAD model (or a scan that reaches its box's bottom) still rests with its lowest point
    whole = _observed(3, "cabinet_3", "cabinet", trimesh.creation.box([0.5, 0.5, 0.8]).apply_translation(
        [2.0, 0.0, 0.5]), False, parent="floor")
    assert whole.resting_height() == pytest.approx(0.1, abs=1e-6)


@pytest.mark.parametrize("check", [check_pybullet, check_mujoco], ids=["pybullet", "mujoco"])
def test_a_movable_scan_seen_without_its_legs_stands_on_the_floor_where_it_was_seen(tmp_path, check):
    seat_and_back = as_mesh(trimesh.util.concatenate([
        trimesh.creation.box([0.45, 0.45, 0.05]).apply_translation([0.0, 0.0, 0.45]),
        trimesh.creation.box([0.45, 0.05, 0.45]).apply_translation([0.0, 0.2, 0.7]),
    ]))  # 0.425-0.925 m: the legs below the seat unmapped
    chair = _observed_on_the_floor(1, "chair_1", "chair", seat_and_back, True, parent="floor")
    scene = ReplacedScene("legless", [_floor(), chair])
    snap_to_supports(scene)
    assert _bottom(chair) == pytest.approx(0.425, abs=1e-6)  # not dropped onto the floor
    shapes = chair.model.links[0].collisions or ()
    lows = [float((np.asarray(s.mesh.vertices) @ s.origin[:3, :3].T + s.origin[:3, 3])[:, 2].min())
            if s.mesh is not None else float(s.origin[2, 3] - s.size[2] / 2) for s in shapes]
    assert shapes and min(lows) == pytest.approx(0.0, abs=1e-6)  # its collision reaches its box's bottom (link frame)
    report = check(export_scene(scene, tmp_path / "scene", glb=False).folder, seconds=2.0)
    assert report.loaded and not report.errors
    assert report.still_fraction == 1.0, report.displacement


def test_a_scans_top_is_its_highest_level_not_a_piece_of_what_stood_on_it():
    """gen-5151's table scan carried 2-5 cm pieces of the microwave and books on it up to 11 cm above its top:
    its highest point put them all 11 cm up."""
    top = trimesh.creation.box([0.8, 0.6, 0.03]).apply_translation([0.0, 0.0, 0.75 - 0.015])
    legs = [trimesh.creation.box([0.04, 0.04, 0.72]).apply_translation([x, y, 0.36])
            for x in (-0.36, 0.36) for y in (-0.26, 0.26)]
    junk = [trimesh.creation.box([0.05, 0.04, h]).apply_translation([x, 0.1, 0.75 + h / 2])
            for x, h in ((-0.2, 0.11), (0.1, 0.06), (0.25, 0.03))]
    feats = scan_features(as_mesh(trimesh.util.concatenate([top, *legs, *junk])))
    assert feats.box_size[2] == pytest.approx(0.86, abs=1e-6)
    assert feats.support_surfaces[0].height == pytest.approx(0.75, abs=1e-6)
    # a scan with nothing flat enough on it keeps its highest point as its top
    ball = scan_features(trimesh.creation.icosphere(radius=0.1))
    assert ball.support_surfaces[0].height == pytest.approx(0.1, abs=1e-3)


def test_a_scan_piece_reaching_into_the_corner_of_what_stands_on_it_is_cut_at_its_bottom(tmp_path):
    """bench-small, draw 1: a cell box of the cabinet scan, mostly beside the book standing on the cabinet's
    top but reaching 2 cm up into its corner, is not dropped (it lies mostly outside the book) and threw the
    book 13 cm once the book stood on the cabinet's own top instead of on the bled pieces."""
    from cad_replacement.collision import box_shape
    from cad_replacement.observed_physics import _clipped_under

    cabinet = _observed(1, "cabinet_1", "cabinet", trimesh.creation.box([0.8, 0.4, 1.0]).apply_translation(
        [0.0, 0.0, 0.5]), False, parent="floor")
    book = _observed(2, "book_2", "book", trimesh.creation.box([0.2, 0.03, 0.28]).apply_translation(
        [0.0, 0.0, 1.14]), True, parent="cabinet_1")
    corner = box_shape([0.08, -0.1, 0.95], [0.3, 0.1, 1.02])  # link frame = the cabinet's bottom centre
    side = box_shape([0.09, -0.1, 0.5], [0.3, 0.1, 1.5])  # rising past the book's top: the scan's own
    below = box_shape([-0.1, -0.1, 0.9], [0.1, 0.1, 1.0])  # under the book, not into it
    sliver = box_shape([-0.05, -0.01, 0.999], [0.05, 0.01, 1.0005])
    assert cabinet.pose[2, 3] == pytest.approx(0.0, abs=1e-9)
    out, clipped, gone = _clipped_under(cabinet, [corner, side, below, sliver], [book])
    assert clipped == 1 and gone == 0 and len(out) == 4
    top = out[0].origin[2, 3] + 0.5 * out[0].size[2]
    assert top == pytest.approx(1.0, abs=1e-9) and out[1] is side and out[2] is below and out[3] is sliver
    # in a simulator: a scan with such a piece (mostly beside the book: the probe test keeps it), settled,
    # keeps the book still
    corner = box_shape([0.095, -0.1, 0.95], [0.5, 0.1, 1.02])
    floor = _floor()
    from dataclasses import replace as dc_replace

    from cad_replacement.cad.model import Link

    link = cabinet.model.links[0]
    cabinet.model = dc_replace(cabinet.model, links=(Link(link.name, link.mesh, link.color, collisions=(
        box_shape([-0.4, -0.2, 0.0], [0.4, 0.2, 1.0]), corner), inertial=link.inertial),))
    book_pose = np.eye(4)
    book_pose[2, 3] = 1.0  # a box model's origin is its bottom centre
    model_book = PlacedObject("book_2", "book", box_model("book", [0.2, 0.03, 0.28]), book_pose, parent="cabinet_1",
                              support="floating", movable=True)
    scene = ReplacedScene("corner", [floor, cabinet, model_book])
    snap_to_supports(scene)
    changes = settle_observed(scene.objects)
    assert changes["cabinet_1"]["clipped"] == 1, changes
    report = check_pybullet(export_scene(scene, tmp_path / "scene", glb=False).folder, seconds=2.0)
    assert report.loaded and report.still_fraction == 1.0, report.displacement


def test_a_movable_scan_reaching_a_few_millimetres_into_what_is_above_it_is_cut_below_it():
    """The 7-Scenes kitchen (stride 4): a chair pushed under a table, its seat's cell boxes 9 mm into the
    table's apron (too shallow for the probe test, 1 cm); PyBullet pushed the chair 2.4 cm out."""
    from cad_replacement.observed_physics import CLIP_TOLERANCE, _cleared_below, _PlacedPieces

    table = _observed(1, "table_1", "table", as_mesh(trimesh.util.concatenate([
        trimesh.creation.box([1.2, 0.8, 0.04]).apply_translation([0.0, 0.0, 0.73]),    # top
        trimesh.creation.box([1.2, 0.04, 0.1]).apply_translation([0.0, -0.38, 0.66]),  # apron
        *[trimesh.creation.box([0.05, 0.05, 0.61]).apply_translation([x, y, 0.305])
          for x in (-0.57, 0.57) for y in (-0.37, 0.37)]])), False, parent="floor")
    seat = trimesh.creation.box([0.45, 0.45, 0.05]).apply_translation([0.0, -0.45, 0.594])  # top 9 mm into the apron
    chair = _observed(2, "chair_2", "chair", seat, True, parent="floor")
    pieces = list(chair.model.links[0].collisions or ())
    out, clipped, gone = _cleared_below(chair, pieces, [_PlacedPieces(table)])
    assert clipped >= 1 and gone == 0 and len(out) == len(pieces)
    tops = [float(s.origin[2, 3] + 0.5 * s.size[2]) for s in out if s.kind == "box"]
    assert max(tops) <= 0.61 - CLIP_TOLERANCE + 1e-9  # below the apron's bottom (0.61 m)
    # a piece reaching deeper is the probe test's (dropped there), one clear of the table is kept as it is
    clear = _observed(3, "chair_3", "chair", trimesh.creation.box([0.45, 0.45, 0.05]).apply_translation(
        [0.0, -1.2, 0.5]), True, parent="floor")
    kept = list(clear.model.links[0].collisions or ())
    assert _cleared_below(clear, kept, [_PlacedPieces(table)]) == (kept, 0, 0)


def test_a_scan_moved_by_an_action_rests_as_the_physical_check_rests_it():
    """Actions (``apply_action`` move) and the physical check share one bottom (``PlacedObject.resting_height``):
    a chair scan seen without its legs, moved across the floor, keeps its seat at the height it was seen."""
    from cad_replacement.actions import SceneAction, apply_action

    seat = trimesh.creation.box([0.45, 0.45, 0.05]).apply_translation([0.0, 0.0, 0.45])  # 0.425-0.475 m
    chair = _observed_on_the_floor(1, "chair_1", "chair", seat, True, parent="floor")
    scene = ReplacedScene("move", [_floor(), chair])
    target = chair.pose.copy()
    target[0, 3] += 1.0
    moved = apply_action(scene, SceneAction("move", object_name="chair_1", pose=target)).object("chair_1")
    assert moved.pose[0, 3] == pytest.approx(chair.pose[0, 3] + 1.0)
    assert moved.resting_height() == pytest.approx(0.0, abs=1e-6) and _bottom(moved) == pytest.approx(0.425, abs=1e-6)
