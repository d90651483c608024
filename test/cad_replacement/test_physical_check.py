"""Global physical check: candidates that sink into other objects are replaced by ones that do not."""

from __future__ import annotations

import numpy as np
import pytest

from cad_replacement.cad import build_model
from cad_replacement.layout_models import box_model
from cad_replacement.physical_check import PhysicalCheck, pair_penetrations
from cad_replacement.scene_model import PlacedObject, ReplacedScene


def _pose(x: float, y: float, z: float, yaw: float = 0.0) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    t = np.eye(4)
    t[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    t[:3, 3] = (x, y, z)
    return t


@pytest.fixture()
def scene_and_alternatives():
    wall = box_model("wall", (0.1, 3.0, 2.5))
    table = build_model("table", 0)
    fridge = build_model("fridge", 0)
    top = float(table.size[2])
    # the first choice for the fridge stands 5 cm inside the wall; the second candidate is clear of it
    depth = float(fridge.size[0])
    wall_face = 1.0
    bad = PlacedObject("fridge_1", "fridge", fridge, _pose(wall_face - 0.5 * depth + 0.05, 0, 0, np.pi), parent="floor")
    good = PlacedObject("fridge_1", "fridge", fridge, _pose(wall_face - 0.5 * depth - 0.01, 0, 0, np.pi),
                        parent="floor")
    scene = ReplacedScene("room", [
        PlacedObject("floor", "floor", box_model("floor", (6, 6, 0.05)), _pose(0, 0, -0.05)),
        PlacedObject("wall_1", "wall", wall, _pose(wall_face + 0.05, 0, 0), parent="floor"),
        PlacedObject("table_1", "table", table, _pose(-1.5, 0, 0), parent="floor"),
        bad,
        PlacedObject("cup_1", "cup", build_model("cup", 0), _pose(-1.5, 0, top), parent="table_1",
                     support="floating", movable=True),
    ])
    return scene, {"fridge_1": [good]}


def test_the_check_swaps_a_candidate_sunk_into_the_wall(scene_and_alternatives):
    scene, alternatives = scene_and_alternatives
    before = {(a, b): d for a, b, d in pair_penetrations(scene)}
    assert before[("wall_1", "fridge_1")] > 0.03
    check = PhysicalCheck()
    fixed = check(scene, alternatives)
    report = check.last_report
    assert report.switches == {"fridge_1": 1}
    assert report.max_penetration_after <= 0.01
    after = {(a, b): d for a, b, d in pair_penetrations(fixed)}
    assert after.get(("wall_1", "fridge_1"), 0.0) <= 0.01
    assert report.pairs_tested < report.pairs_total  # the broad phase skipped far pairs
    assert fixed.object("cup_1").pose.tolist() == scene.object("cup_1").pose.tolist()


def test_containment_is_not_a_collision_for_solids_but_is_for_hulls():
    cabinet = build_model("cabinet", 1)
    level = min((s for s in cabinet.features.support_surfaces if s.enclosed), key=lambda s: s.height)
    cup = build_model("cup", 0)
    centre = np.asarray(level.polygon).mean(axis=0)
    scene = ReplacedScene("inside", [
        PlacedObject("cabinet_1", "cabinet", cabinet, _pose(0, 0, 0)),
        PlacedObject("cup_1", "cup", cup, _pose(float(centre[0]), float(centre[1]), float(level.height)),
                     parent="cabinet_1", support="floating", movable=True),
    ])
    solid = {(a, b): d for a, b, d in pair_penetrations(scene)}
    hull = {(a, b): d for a, b, d in pair_penetrations(scene, hulls=True)}
    assert solid[("cabinet_1", "cup_1")] <= 0.01  # resting on a shelf level inside: fine
    assert hull[("cabinet_1", "cup_1")] > 0.03  # the paper's hull test calls it a collision


def test_snap_puts_an_object_over_the_edge_back_onto_its_surface_and_never_into_a_closed_drawer():
    cabinet = build_model("cabinet", 0)
    bottle = build_model("bottle", 0)
    cab = PlacedObject("cabinet_1", "cabinet", cabinet, _pose(0, 0, 0), parent="floor")
    top = float(cabinet.size[2])
    half_depth = 0.5 * float(cabinet.size[0])
    # the bottle's centre hangs 1 cm past the front edge, and it sits a little below the top
    on_edge = PlacedObject("bottle_1", "bottle", bottle, _pose(half_depth + 0.01, 0, top - 0.04),
                           parent="cabinet_1", support="floating", movable=True)
    scene = ReplacedScene("room", [
        PlacedObject("floor", "floor", box_model("floor", (6, 6, 0.05)), _pose(0, 0, -0.05)), cab, on_edge])
    from cad_replacement.actions import support_spots
    from cad_replacement.physical_check import snap_to_supports

    snap_to_supports(scene)
    moved = scene.object("bottle_1")
    bottom = min(float((m.vertices @ moved.pose[:3, :3].T + moved.pose[:3, 3])[:, 2].min())
                 for m in moved.model.posed_link_meshes().values())
    assert abs(bottom - top) < 1e-3  # on the top, not on a drawer bottom below it
    assert moved.parent_link in ("", cabinet.root_link)
    spot = next(s for s in support_spots(cab) if abs(s.height - top) < 1e-3)
    from recon_core.geometry.polygon import points_in_polygon

    centre = moved.pose[:2, 3] + moved.pose[:2, :2] @ bottle.features.box_center[:2]
    assert points_in_polygon(centre[None], spot.polygon)[0]
    assert centre[0] < half_depth - 0.25 * min(bottle.size[:2]) + 1e-6  # a margin from the edge



@pytest.mark.parametrize(("sunk", "moved"), [(0.04, True), (0.3, False)])
def test_an_object_sunk_into_a_wall_with_no_better_candidate_is_pushed_out(sunk: float, moved: bool):
    """Every candidate is fitted to the same points, so a cabinet a few cm too deep stays in the wall
    whatever the switch; it moves out across the wall (with what stands on it), a deep one does not."""
    wall = box_model("wall", (0.1, 3.0, 2.5))
    cabinet = build_model("cabinet", 0)
    cup = build_model("cup", 0)
    depth, top = float(cabinet.size[0]), float(cabinet.size[2])
    wall_face = 1.0
    x = wall_face - 0.5 * depth + sunk
    scene = ReplacedScene("room", [
        PlacedObject("floor", "floor", box_model("floor", (6, 6, 0.05)), _pose(0, 0, -0.05)),
        PlacedObject("wall_1", "wall", wall, _pose(wall_face + 0.05, 0, 0), parent="floor"),
        PlacedObject("cabinet_1", "cabinet", cabinet, _pose(x, 0, 0, np.pi), parent="floor"),
        PlacedObject("cup_1", "cup", cup, _pose(x, 0, top), parent="cabinet_1", support="floating", movable=True),
    ])
    check = PhysicalCheck()
    fixed = check(scene, {})
    report = check.last_report
    after = {frozenset((a, b)): d for a, b, d in pair_penetrations(fixed)}
    into_wall = after.get(frozenset(("cabinet_1", "wall_1")), 0.0)
    if moved:
        assert report.wall_pushes["cabinet_1"] == pytest.approx(sunk, abs=0.01)
        assert into_wall <= 0.005
        shift = fixed.object("cabinet_1").pose[:3, 3] - np.array([x, 0.0, 0.0])
        assert shift[0] < 0.0 and abs(shift[1]) < 1e-9  # into the room, across the wall only
        cup_shift = fixed.object("cup_1").pose[:2, 3] - np.array([x, 0.0])
        np.testing.assert_allclose(cup_shift, shift[:2], atol=1e-9)  # the cup went with it
    else:
        assert "cabinet_1" not in report.wall_pushes
        assert into_wall > 0.04  # still through the wall: the pose is wrong, not a few cm off


def test_snap_measures_height_in_the_map_for_a_book_lying_on_a_shelf():
    """A book lying on its side is as tall as it is thick: it fits a shelf lower than the book is
    long and must stay there (the model's z is horizontal once it lies)."""
    from cad_replacement.actions import support_spots
    from cad_replacement.physical_check import snap_to_supports

    cabinet = build_model("cabinet", 0)
    cab = PlacedObject("cabinet_1", "cabinet", cabinet, _pose(0, 0, 0), parent="floor")
    shelves = [sp for sp in support_spots(cab) if sp.clearance is not None and sp.link == cabinet.root_link]
    assert shelves
    book = build_model("book", 0)
    thick, long_side = float(np.min(book.size)), float(book.size[2])
    shelf = next((sp for sp in shelves if thick < 0.8 * sp.clearance and sp.clearance < 0.9 * long_side), None)
    assert shelf is not None, "procedural cabinet seed 0 is expected to have a shelf lower than book seed 0"
    lying = np.eye(4)
    lying[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # model z -> map y: the book lies on a cover
    pose = _pose(*shelf.polygon.mean(axis=0), 0.0) @ lying
    obj = PlacedObject("book_1", "book", book, pose, parent="cabinet_1", support="floating", movable=True)
    lowest = float((book.mesh().vertices @ pose[:3, :3].T + pose[:3, 3])[:, 2].min())
    obj.pose[2, 3] += shelf.height - lowest + 0.004  # 4 mm above the shelf
    scene = ReplacedScene("room", [PlacedObject("floor", "floor", box_model("floor", (6, 6, 0.05)),
                                                _pose(0, 0, -0.05)), cab, obj])
    gaps = snap_to_supports(scene)
    assert gaps["book_1"] == pytest.approx(0.004, abs=1e-6)  # onto the same shelf, not the top
    moved = scene.object("book_1")
    bottom = float((book.mesh().vertices @ moved.pose[:3, :3].T + moved.pose[:3, 3])[:, 2].min())
    assert bottom == pytest.approx(shelf.height, abs=1e-6)


@pytest.mark.parametrize(("overhang", "moved_in"), [(0.025, True), (0.09, False)])
def test_a_book_overhanging_a_shelf_side_is_moved_wholly_inside_when_a_short_shift_does_it(overhang, moved_in):
    """A shelf inside a cabinet has walls: a lying book whose footprint sticks 2.5 cm past the shelf's
    outline sits on the side wall and the simulator pushes it off (seen in PyBullet and MuJoCo). The
    snap shifts it wholly inside; 9 cm off, the fit is wrong about where the book is and it stays."""
    from cad_replacement.actions import support_spots
    from cad_replacement.physical_check import CONTAINED_MARGIN, _footprint_corners, _inside_margin, snap_to_supports

    cabinet = build_model("cabinet", 0)
    cab = PlacedObject("cabinet_1", "cabinet", cabinet, _pose(0, 0, 0), parent="floor")
    book = build_model("book", 0)
    lying = np.eye(4)
    lying[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    thick = float(book.size[1])
    shelf = next(sp for sp in support_spots(cab) if sp.clearance is not None and sp.clearance > 1.2 * thick
                 and sp.link == cabinet.root_link)
    lo, hi = shelf.polygon.min(axis=0), shelf.polygon.max(axis=0)
    obj = PlacedObject("book_1", "book", book, _pose(0.0, 0.0, 0.0) @ lying, parent="cabinet_1",
                       support="floating", movable=True)
    corners = _footprint_corners(obj)
    # the footprint's far side `overhang` past the shelf's +y side, centred in x
    obj.pose[0, 3] += 0.5 * (lo[0] + hi[0]) - corners[:, 0].mean()
    obj.pose[1, 3] += hi[1] + overhang - corners[:, 1].max()
    obj.pose[2, 3] += shelf.height - float((book.mesh().vertices @ obj.pose[:3, :3].T + obj.pose[:3, 3])[:, 2].min())
    scene = ReplacedScene("room", [PlacedObject("floor", "floor", box_model("floor", (6, 6, 0.05)),
                                                _pose(0, 0, -0.05)), cab, obj])
    snap_to_supports(scene)
    worst = float(_inside_margin(_footprint_corners(scene.object("book_1")), shelf.polygon).min())
    if moved_in:
        assert worst >= CONTAINED_MARGIN - 1e-6
    else:
        assert worst < -0.05


def test_into_surface_finds_the_shortest_move_or_says_it_does_not_fit():
    from cad_replacement.physical_check import _into_surface

    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    foot = np.array([[-0.1, 0.2], [0.2, 0.2], [0.2, 0.5], [-0.1, 0.5]])
    assert np.allclose(_into_surface(foot, square, 0.0), [0.1, 0.0])
    assert np.allclose(_into_surface(foot, square[::-1], 0.01), [0.11, 0.0])  # either winding
    corner = np.array([[0.9, 0.95], [1.1, 0.95], [1.1, 1.05], [0.9, 1.05]])
    assert np.allclose(_into_surface(corner, square, 0.0), [-0.1, -0.05])  # two sides at once
    assert np.allclose(_into_surface(foot + 0.3, square, 0.0), [0.0, 0.0])  # already inside
    assert _into_surface(foot * 10, square, 0.0) is None  # larger than the surface


def test_neighbours_on_one_surface_are_slid_apart_after_the_snap():
    """Two boxes fitted side by side overlap by 1.5 cm (library models a little too big): the smaller
    slides away along the line between them and both stay on the table."""
    from cad_replacement.physical_check import separate_neighbours
    from cad_replacement.solids import ObjectSolids

    table = build_model("table", 0)
    top = float(table.size[2])
    big, small = box_model("box", (0.2, 0.2, 0.15)), box_model("box", (0.1, 0.1, 0.1))
    scene = ReplacedScene("room", [
        PlacedObject("floor", "floor", box_model("floor", (6, 6, 0.05)), _pose(0, 0, -0.05)),
        PlacedObject("table_1", "table", table, _pose(0, 0, 0), parent="floor"),
        PlacedObject("box_1", "box", big, _pose(0.0, 0.0, top), parent="table_1", support="floating", movable=True),
        PlacedObject("box_2", "box", small, _pose(0.135, 0.0, top), parent="table_1", support="floating",
                     movable=True),
    ])
    solids = {o.name: ObjectSolids(o, False) for o in scene}
    before = {frozenset((a, b)): d for a, b, d in pair_penetrations(scene)}
    assert before[frozenset(("box_1", "box_2"))] == pytest.approx(0.015, abs=0.002)
    moved = separate_neighbours(scene, solids, 0.01)
    assert list(moved) == ["box_2"] and moved["box_2"] == pytest.approx(0.017, abs=0.002)
    after = {frozenset((a, b)): d for a, b, d in pair_penetrations(scene)}
    assert after.get(frozenset(("box_1", "box_2")), 0.0) <= 0.001
    assert scene.object("box_1").pose[:3, 3].tolist() == [0.0, 0.0, top]
    assert scene.object("box_2").pose[1, 3] == pytest.approx(0.0) and scene.object("box_2").pose[0, 3] > 0.15


class _Scored(list):
    """Alternatives as the replacer hands them over: ranked, with their selection scores."""

    def __init__(self, items, scores, chosen_score):
        super().__init__(items)
        self.scores, self.chosen_score = scores, chosen_score


def _shelf_with_cup(alternative_score: float | None):
    # shelf seed 2 has boards at 0.08/0.51/0.93 m, seed 3 at 0.05/0.34/0.62 m: a cup seen standing at
    # 0.336 m fits seed 3 and would be lifted 17 cm onto seed 2's board by the snap
    chosen, other = build_model("shelf", 2), build_model("shelf", 3)
    board = min((s.height for s in other.features.support_surfaces), key=lambda h: abs(h - 0.336))
    scene = ReplacedScene("room", [
        PlacedObject("floor", "floor", box_model("floor", (6, 6, 0.05)), _pose(0, 0, -0.05)),
        PlacedObject("shelf_1", "shelf", chosen, _pose(0, 0, 0), parent="floor"),
        PlacedObject("cup_1", "cup", build_model("cup", 0), _pose(0, 0, board), parent="shelf_1",
                     support="floating", movable=True),
    ])
    alt = PlacedObject("shelf_1", "shelf", other, _pose(0, 0, 0), parent="floor")
    alts = [alt] if alternative_score is None else _Scored([alt], [alternative_score], 1.0)
    return scene, {"shelf_1": alts}, board


def test_a_support_without_a_surface_where_its_object_stands_switches_to_one_that_has_it():
    scene, alternatives, board = _shelf_with_cup(None)
    check = PhysicalCheck()
    fixed = check(scene, alternatives)
    assert "shelf_1" in check.last_report.support_switches
    before, after = check.last_report.support_switches["shelf_1"]
    assert before > 0.1 and after < 0.02
    assert fixed.object("shelf_1").model.model_id == alternatives["shelf_1"][0].model.model_id
    assert fixed.object("cup_1").pose[2, 3] == pytest.approx(board, abs=0.02)  # not lifted a board up


def test_a_much_worse_fitting_support_alternative_is_not_taken_for_consistency():
    scene, alternatives, board = _shelf_with_cup(10.0)  # 10x the choice's score
    check = PhysicalCheck()
    fixed = check(scene, alternatives)
    assert check.last_report.support_switches == {}
    assert abs(fixed.object("cup_1").pose[2, 3] - board) > 0.1  # snapped onto the chosen shelf's board
    paper = PhysicalCheck(method="paper")
    scene, alternatives, _board = _shelf_with_cup(None)
    paper(scene, alternatives)
    assert paper.last_report.support_switches == {}  # the paper's check has no such step


class _WithScan(_Scored):
    """Alternatives that also offer the object's scan, as ``replacer._RankedAlternatives`` does."""

    def __init__(self, items, scores, chosen_score, scan):
        super().__init__(items, scores, chosen_score)
        self._scan = scan
        self.asked = 0

    def scan(self):
        self.asked += 1
        return self._scan


def _scan_of(mesh, name: str = "shelf_1") -> PlacedObject:
    from cad_replacement.replacer import observed_mesh_object
    from recon_core.contact_graph import GraphNode
    from recon_core.entity import Entity
    from recon_core.geometry.box_fit import fit_gravity_box

    node = GraphNode(1, name, "shelf", "object", box=fit_gravity_box(np.asarray(mesh.vertices)), movable=False)
    obj = observed_mesh_object(node, Entity.from_mesh(1, name, "shelf", mesh), "floor", "fixed")
    assert obj is not None
    return obj


@pytest.mark.parametrize("scan_holds", [True, False])
def test_a_support_whose_models_all_lift_what_was_seen_inside_it_gives_way_to_its_scan(scan_holds: bool):
    import trimesh

    scene, alternatives, board = _shelf_with_cup(10.0)  # the one model that holds the cup fits 10x worse
    seen = build_model("shelf", 3).mesh()  # the scan: boards where the camera saw them (0.34 m among them)
    solid = trimesh.creation.box(seen.extents).apply_translation(seen.bounds.mean(axis=0))  # no inner level
    alts = _WithScan(alternatives["shelf_1"], [10.0], 1.0, _scan_of(seen if scan_holds else solid))
    check = PhysicalCheck()
    fixed = check(scene, {"shelf_1": alts})
    assert alts.asked == 1
    cup_z = fixed.object("cup_1").pose[2, 3]
    if scan_holds:
        assert fixed.object("shelf_1").model.source == "observed"
        before, after = check.last_report.support_switches["shelf_1"]
        assert before > 0.1 and after < 0.02
        assert cup_z == pytest.approx(board, abs=0.02)  # where it was seen, not a board up
    else:
        assert fixed.object("shelf_1").model.source != "observed" and check.last_report.support_switches == {}
        assert abs(cup_z - board) > 0.1


def test_a_child_a_few_centimetres_off_its_support_model_keeps_the_model():
    scene, alternatives, board = _shelf_with_cup(10.0)
    chosen = scene.object("shelf_1").model
    nearest = min((s.height for s in chosen.features.support_surfaces), key=lambda h: abs(h - board))
    scene.object("cup_1").pose[2, 3] = nearest + 0.05  # 5 cm off a board of the chosen model
    alts = _WithScan(alternatives["shelf_1"], [10.0], 1.0, _scan_of(build_model("shelf", 3).mesh()))
    fixed = PhysicalCheck()(scene, {"shelf_1": alts})
    assert alts.asked == 0 and fixed.object("shelf_1").model is chosen
