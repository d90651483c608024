"""3D panoptic quality / instance mAP (scene_recon.evaluation.map_metrics) on cases with known answers."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np
import pytest
import trimesh

from recon_core.classes import load_class_table
from recon_core.entity import Entity, save_entities
from scene_recon.cli import main
from scene_recon.evaluation.map_metrics import (
    PAPER_CLASSES,
    MetricsConfig,
    Segment,
    average_precision,
    contact_mask,
    evaluate_panoptic_map,
    evaluate_point_labels,
    ground_truth_as_predictions,
    sample_surface_points,
)
from scene_recon.synthetic.scene import build_scene

TABLE = load_class_table()


@dataclass
class GT:
    """Minimal ground-truth entity (the fields the evaluation reads from SceneEntity)."""

    id: int
    class_id: int
    class_name: str
    is_thing: bool
    mesh: trimesh.Trimesh | None


def box(size, center) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=size, transform=trimesh.transformations.translation_matrix(center))


def gt(eid: int, cls: str, mesh: trimesh.Trimesh | None) -> GT:
    info = TABLE.by_name(cls)
    return GT(eid, info.id, cls, info.is_thing, mesh)


def pred(eid: int, cls: str, *meshes: trimesh.Trimesh, confidence: float = 1.0) -> Entity:
    """A predicted entity; several meshes are merged into one entity; cls 'unknown' is class -1."""
    cid, thing = (-1, True) if cls == "unknown" else (TABLE.by_name(cls).id, TABLE.by_name(cls).is_thing)
    mesh = trimesh.util.concatenate(list(meshes)) if meshes else trimesh.Trimesh()
    v = np.asarray(mesh.vertices, float).reshape(-1, 3)
    f = np.asarray(mesh.faces, np.int64).reshape(-1, 3)
    return Entity(eid, cls, v, f, class_id=cid, instance_id=eid, is_thing=thing, confidence=confidence)


FLOOR = box((4, 4, 0.1), (0, 0, -0.05))
CUBE_A = box((0.5, 0.5, 0.5), (-1, -1, 0.25))  # on the floor
CUBE_B = box((0.5, 0.5, 0.5), (1, 1, 0.25))  # on the floor


# ------------------------------------------------------------------------------------------ whole protocol


def test_perfect_prediction_scores_100():
    table = box((1.2, 0.8, 0.75), (0, 1, 0.375))
    book = box((0.2, 0.3, 0.01), (0, 1, 0.755))  # thin object lying on the table: its top stays visible
    wall_a, wall_b = box((4, 0.1, 2), (0, -2.05, 1)), box((0.1, 4, 2), (-2.05, 0, 1))
    truth = [gt(1, "floor", FLOOR), gt(2, "wall", wall_a), gt(3, "wall", wall_b), gt(4, "table", table),
             gt(5, "book", book), gt(6, "box", CUBE_A), gt(7, "box", CUBE_B)]
    r = evaluate_panoptic_map(ground_truth_as_predictions(truth), truth)
    assert (r.pq, r.sq, r.rq, r.map) == (100.0, 100.0, 100.0, 100.0)
    assert (r.pq_stuff, r.pq_things) == (100.0, 100.0)
    assert set(r.per_class) == {"floor", "wall", "table", "book", "box"}
    assert r.per_class["wall"].tp == 1 and r.per_class["wall"].ap is None  # stuff: one merged segment, no AP
    assert r.per_class["box"].tp == 2 and r.per_class["box"].ap == 100.0
    assert r.counts["contact_points"] > 0  # cube bottoms, floor under them, book bottom, ...
    assert r.counts["gt_entities_seen"] == 7 and r.counts["gt_entities_unobserved"] == 0
    json.dumps(r.to_dict())  # JSON-ready


def test_same_inputs_same_numbers():
    truth = [gt(1, "floor", FLOOR), gt(2, "box", CUBE_A)]
    # the cube's top 15 cm are mapped but not recognised: IoU = 0.7 m^2 / 1.25 m^2 of visible surface
    lower, upper = box((0.5, 0.5, 0.35), (-1, -1, 0.175)), box((0.5, 0.5, 0.15), (-1, -1, 0.425))
    preds = [pred(1, "floor", FLOOR), pred(2, "box", lower), pred(3, "unknown", upper)]
    a, b = evaluate_panoptic_map(preds, truth), evaluate_panoptic_map(preds, truth)
    assert a.per_class["box"].sq == b.per_class["box"].sq
    assert a.per_class["box"].sq == pytest.approx(100 * 0.7 / 1.25, abs=1.5)


def test_missing_instance_is_a_false_negative():
    truth = [gt(1, "floor", FLOOR), gt(2, "box", CUBE_A), gt(3, "box", CUBE_B)]
    # the second cube is reconstructed but not recognised (class "unknown"): observed, so a miss
    preds = [pred(1, "floor", FLOOR), pred(2, "box", CUBE_A), pred(3, "unknown", CUBE_B)]
    r = evaluate_panoptic_map(preds, truth)
    c = r.per_class["box"]
    assert (c.tp, c.fp, c.fn) == (1, 0, 1)
    assert c.rq == pytest.approx(100 * 1 / (1 + 0.5 * 0 + 0.5 * 1))  # 2/3
    assert c.sq == pytest.approx(100) and c.pq == pytest.approx(200 / 3)
    assert c.ap == pytest.approx(50)  # recall reaches 1/2 at precision 1
    assert "unknown" not in r.per_class
    assert r.pq == pytest.approx((100 + 200 / 3) / 2)  # class average: floor and box


def test_prediction_split_in_thirds_matches_nothing():
    cube = box((1, 1, 1), (0, 0, 0.5))
    thirds = [box((1 / 3, 1, 1), (x, 0, 0.5)) for x in (-1 / 3, 0, 1 / 3)]  # IoU 7/18, 4/18, 7/18
    r = evaluate_panoptic_map([pred(i, "box", m) for i, m in enumerate(thirds, 1)], [gt(1, "box", cube)])
    c = r.per_class["box"]
    assert (c.tp, c.fp, c.fn, c.pq, c.ap) == (0, 3, 1, 0.0, 0.0)


def test_iou_of_exactly_one_half_is_not_a_match():
    """Strictly greater than 0.5: two halves of a segment match nothing; 51/49 matches once."""
    gt_seg, preds = [Segment(12, "chair", True)], [Segment(12, "chair", True), Segment(12, "chair", True)]
    gt_labels = np.zeros(100, np.int64)
    half = evaluate_point_labels(gt_labels, np.repeat([0, 1], 50), gt_seg, preds).per_class["chair"]
    assert (half.tp, half.fp, half.fn, half.pq) == (0, 2, 1, 0.0)
    r = evaluate_point_labels(gt_labels, np.repeat([0, 1], [51, 49]), gt_seg, preds)
    c = r.per_class["chair"]
    assert (c.tp, c.fp, c.fn) == (1, 1, 0)
    assert c.sq == pytest.approx(51) and c.rq == pytest.approx(100 / 1.5) and c.pq == pytest.approx(51 / 1.5)
    assert r.matches == [{"class": "chair", "gt": [], "pred": [], "iou": pytest.approx(51)}]


def test_void_points_are_removed_from_predictions():
    """Kirillov et al.: IoU ignores predicted points on void GT; mostly-void predictions are not FPs."""
    gt_seg = [Segment(12, "chair", True)]
    preds = [Segment(12, "chair", True), Segment(12, "chair", True)]
    gt_labels = np.array([0] * 10 + [-1] * 30)
    pred_labels = np.array([0] * 10 + [0] * 10 + [1] * 20)  # pred 0: 10 chair + 10 void; pred 1: all void
    r = evaluate_point_labels(gt_labels, pred_labels, gt_seg, preds)
    c = r.per_class["chair"]
    assert (c.tp, c.fp, c.fn, c.sq) == (1, 0, 0, 100.0)
    assert r.counts["pred_segments_void"] == 1


def test_wrong_class_is_a_false_positive_and_a_false_negative():
    chair = box((0.5, 0.5, 0.9), (0, 0, 0.45))
    r = evaluate_panoptic_map([pred(1, "table", chair)], [gt(1, "chair", chair)])
    assert (r.per_class["chair"].tp, r.per_class["chair"].fn, r.per_class["chair"].pq) == (0, 1, 0.0)
    assert (r.per_class["table"].tp, r.per_class["table"].fp, r.per_class["table"].pq) == (0, 1, 0.0)
    assert r.per_class["chair"].ap == 0.0 and r.per_class["table"].ap is None  # table not in the GT
    assert r.map == 0.0 and r.pq == 0.0


def test_prediction_covering_two_instances_matches_the_bigger_one():
    big, small = box((1, 1, 1), (0, 0, 0.5)), box((0.4, 0.4, 0.4), (1, 0, 0.2))
    r = evaluate_panoptic_map([pred(1, "box", big, small)], [gt(1, "box", big), gt(2, "box", small)])
    c = r.per_class["box"]
    assert (c.tp, c.fp, c.fn) == (1, 0, 1)
    expected_iou = big.area / (big.area + small.area)  # all points of both transfer to the one prediction
    assert c.sq == pytest.approx(100 * expected_iou, abs=1.5)
    assert r.matches[0]["gt"] == [1] and r.matches[0]["pred"] == [1]


def test_stuff_is_one_segment_per_class_on_both_sides():
    wall_a, wall_b = box((4, 0.1, 2), (0, -2, 1)), box((0.1, 3, 2), (-3, 0, 1))
    # two GT walls, one predicted wall entity covering both
    r = evaluate_panoptic_map([pred(1, "wall", wall_a, wall_b)], [gt(1, "wall", wall_a), gt(2, "wall", wall_b)])
    assert (r.per_class["wall"].tp, r.per_class["wall"].fp, r.per_class["wall"].fn) == (1, 0, 0)
    assert r.pq == 100.0 and r.pq_stuff == 100.0 and r.map == 0.0  # no thing classes: mAP over nothing
    # one GT wall, predicted in two pieces
    halves = [box((2, 0.1, 2), (x, -2, 1)) for x in (-1, 1)]
    r = evaluate_panoptic_map([pred(1, "wall", halves[0]), pred(2, "wall", halves[1])], [gt(1, "wall", wall_a)])
    assert (r.per_class["wall"].tp, r.per_class["wall"].fp, r.per_class["wall"].pq) == (1, 0, 100.0)
    assert r.matches[0]["pred"] == [1, 2]


def test_unobserved_ground_truth_is_ignored():
    far = box((0.5, 0.5, 0.5), (8, 8, 0.25))  # nothing reconstructed near it
    truth = [gt(1, "floor", FLOOR), gt(2, "box", CUBE_A), gt(3, "box", far)]
    r = evaluate_panoptic_map([pred(1, "floor", FLOOR), pred(2, "box", CUBE_A)], truth)
    assert (r.per_class["box"].tp, r.per_class["box"].fn, r.pq) == (1, 0, 100.0)
    assert r.counts["gt_entities_unobserved"] == 1 and r.counts["gt_entities_seen"] == 2


def test_class_filter_makes_other_classes_void():
    chair, sofa = box((0.5, 0.5, 0.9), (0, 0, 0.45)), box((2, 0.9, 0.8), (0, 2, 0.4))
    truth = [gt(1, "chair", chair), gt(2, "sofa", sofa)]
    preds = [pred(1, "chair", chair), pred(2, "chair", sofa)]  # the sofa taken for a chair
    assert evaluate_panoptic_map(preds, truth).per_class["chair"].fp == 1
    r = evaluate_panoptic_map(preds, truth, classes=["chair"])
    assert list(r.per_class) == ["chair"]
    assert (r.per_class["chair"].tp, r.per_class["chair"].fp, r.pq) == (1, 0, 100.0)  # on void: no FP
    assert r.counts["pred_segments_void"] == 1


def test_high_confidence_false_positive_lowers_ap():
    truth = [gt(1, "floor", FLOOR), gt(2, "box", CUBE_A), gt(3, "box", CUBE_B)]
    hallucinated = box((0.5, 0.5, 0.5), (0, 0, 1.5))  # floating in free space: no GT point transfers to it
    crumb = box((0.03, 0.03, 0.03), (0, 0, 1.0))  # 0.0054 m^2: below min_fp_area, ignored

    def run(fp_confidence):
        preds = [pred(1, "floor", FLOOR), pred(2, "box", CUBE_A, confidence=0.8),
                 pred(3, "box", CUBE_B, confidence=0.7), pred(4, "box", hallucinated, confidence=fp_confidence),
                 pred(5, "box", crumb, confidence=0.95)]
        return evaluate_panoptic_map(preds, truth).per_class["box"]

    # ranked: FP (0.9), TP, TP -> precision 0, 1/2, 2/3 at recall 0, 1/2, 1 -> envelope 2/3 -> AP = 2/3
    first = run(0.9)
    assert (first.tp, first.fp, first.fn) == (2, 1, 0)
    assert first.ap == pytest.approx(100 * (0.5 * 2 / 3 + 0.5 * 2 / 3))
    assert first.rq == pytest.approx(100 * 2 / 2.5)
    last = run(0.1)  # ranked last it costs no precision before full recall
    assert last.ap == pytest.approx(100.0) and last.fp == 1


def test_average_precision_by_hand():
    assert average_precision(np.array([True, False, True]), 2) == pytest.approx(0.5 * 1 + 0.5 * 2 / 3)
    assert average_precision(np.array([False, True, True]), 2) == pytest.approx(2 / 3)
    assert average_precision(np.array([True, True]), 4) == pytest.approx(0.5)  # recall never passes 1/2
    assert average_precision(np.array([], bool), 3) == 0.0
    assert math.isnan(average_precision(np.array([True]), 0))


def test_degenerate_inputs():
    truth = [gt(1, "floor", FLOOR), gt(2, "box", CUBE_A), gt(3, "box", None), gt(4, "box", trimesh.Trimesh())]
    r = evaluate_panoptic_map([], truth)  # nothing mapped: nothing observed, nothing to score
    assert (r.pq, r.sq, r.rq, r.map, r.per_class) == (0.0, 0.0, 0.0, 0.0, {})
    assert r.counts["gt_entities_unobserved"] == 2  # entities without geometry are not counted at all
    r = evaluate_panoptic_map([pred(1, "floor", FLOOR), pred(2, "box"), pred(3, "box", CUBE_A)], truth)
    assert r.pq == 100.0  # the empty predicted mesh is skipped
    r = evaluate_panoptic_map([pred(1, "box", CUBE_A)], [])  # no ground truth: the prediction is an FP
    assert (r.per_class["box"].fp, r.pq, r.map) == (1, 0.0, 0.0)
    assert evaluate_panoptic_map([], []).pq == 0.0
    with pytest.raises(ValueError):
        MetricsConfig(sample_spacing=0)


def test_sampling_density_and_contact_mask():
    table = box((1, 1, 0.75), (0, 0, 0.375))
    book = box((0.2, 0.3, 0.01), (0, 0, 0.755))
    meshes = [(np.asarray(m.vertices), np.asarray(m.faces)) for m in (table, book)]
    points, owner, normals = sample_surface_points(meshes, 0.01, seed=3)
    assert len(points) == pytest.approx((table.area + book.area) / 0.01**2, rel=0.02)
    assert np.all(np.diff(owner) >= 0)
    hidden = contact_mask(points, normals, owner, meshes, 0.02)
    on_book = owner == 1
    top = on_book & (points[:, 2] > 0.7599)
    bottom = on_book & (points[:, 2] < 0.7501)
    assert hidden[bottom].all() and not hidden[top].any()  # 1 cm thick: the top is not a contact
    under_book = ~on_book & (points[:, 2] > 0.7499) & (np.abs(points[:, 0]) < 0.09) & (np.abs(points[:, 1]) < 0.14)
    elsewhere = ~on_book & (points[:, 2] > 0.7499) & (np.abs(points[:, 0]) > 0.15)
    assert hidden[under_book].all() and not hidden[elsewhere].any()


# ------------------------------------------------------------------------------------------ real scenes


def test_generated_scene_ground_truth_as_prediction_scores_100():
    scene = build_scene(12, 0)
    r = evaluate_panoptic_map(ground_truth_as_predictions(scene), scene)
    assert (r.pq, r.sq, r.rq, r.map) == (100.0, 100.0, 100.0, 100.0)
    assert {"floor", "wall"} <= set(r.per_class) and r.counts["gt_entities_unobserved"] == 0
    paper = evaluate_panoptic_map(ground_truth_as_predictions(scene), scene, classes=PAPER_CLASSES)
    assert set(paper.per_class) <= set(PAPER_CLASSES) and paper.pq == 100.0


def test_25_entity_scene_is_fast():
    scene = build_scene(25, 0)
    assert len(scene.entities) >= 25
    r = evaluate_panoptic_map(ground_truth_as_predictions(scene), scene)
    assert r.pq == 100.0
    assert r.elapsed_s < 4.0  # budget 2 s; ~0.6 s measured on 2 idle cores, slack for a loaded machine


# ------------------------------------------------------------------------------------------ command line


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A generated scene's ground-truth folder beside a (not rendered) bag path, and a perfect map."""
    root = tmp_path_factory.mktemp("evalmap")
    scene = build_scene(3, 1)
    scene.save(root / "rec_groundtruth")
    save_entities(ground_truth_as_predictions(scene), root / "map")
    return root


def test_cli_json_and_bag_path(recording, capsys):
    assert main(["eval-map", str(recording / "map"), str(recording / "rec_groundtruth"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["averages"]["all"]["pq"] == 100.0 and out["averages"]["map"] == 100.0
    assert out["units"] == "percent" and "floor" in out["per_class"]
    # the bag path: the ground truth beside it is found
    assert main(["eval-map", str(recording / "map"), str(recording / "rec"), "--json", "--classes", "paper"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["per_class"]) <= set(PAPER_CLASSES)


def test_cli_table_and_errors(recording, capsys):
    assert main(["eval-map", str(recording / "map"), str(recording / "rec_groundtruth"),
                 "--sample-spacing", "0.03"]) == 0
    out = capsys.readouterr().out
    assert "PQ" in out and "mAP@0.5: 100.0" in out and "floor *" in out
    assert main(["eval-map", str(recording / "nope"), str(recording / "rec_groundtruth")]) == 2
    assert "map folder" in capsys.readouterr().err
    assert main(["eval-map", str(recording / "map"), str(recording / "missing")]) == 2
    assert "scene.json" in capsys.readouterr().err
    assert main(["eval-map", str(recording / "map"), str(recording / "rec_groundtruth"), "--classes", "dragon"]) == 2
    assert "unknown class" in capsys.readouterr().err
