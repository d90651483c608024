"""Evaluation of a replaced scene against a generated scene's ground truth (issue: stage 4, item 10).

Per ground-truth object: the replaced object it corresponds to (same or interchangeable class,
nearest box centre within ``MATCH_RADIUS_M``, one-to-one by the Hungarian method), then the CAD
metrics of ``cad_metrics.evaluate_object`` (pose success: translation <= 10 cm, yaw <= 15 deg up to
the model's symmetry, size <= 15 %; front flips; joint types, hinge axes, joint values). Scene-wide:
interpenetration of every overlapping pair (solids), support gaps (bottom of each supported object
against the top of what carries it), and the physics check of the exported folder in PyBullet and
MuJoCo (movable objects that stay within 2 cm over 2 s).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from cad_replacement.actions import support_spots
from cad_replacement.cad.library import CadLibrary
from cad_replacement.cad.model import CadModel
from cad_replacement.layout_models import box_model
from cad_replacement.matching import candidate_classes
from cad_replacement.physical_check import pair_penetrations
from cad_replacement.scene_model import MAP_ROOT, PlacedObject, ReplacedScene
from recon_core.contact_graph import ContactGraph, SupportEdge
from recon_core.errors import InputError
from recon_core.geometry.box import GravityBox
from scene_recon.evaluation.cad_metrics import evaluate_object, failures_by_class, summarize
from scene_recon.synthetic.scene import GroundTruthScene

#: A replaced object further than this (m, box centres) from a ground-truth object is not its match.
MATCH_RADIUS_M = 0.5


@dataclass
class _Alignment:
    ae: float = float("nan")
    ae_points: float = float("nan")
    ae_model: float = float("nan")


@dataclass
class _Chosen:
    """The chosen candidate of a replaced object, as ``evaluate_object`` reads it."""

    key: str
    class_name: str
    pose: np.ndarray
    scale: np.ndarray
    joint_values: dict[str, float]
    ae: _Alignment

    @property
    def yaw(self) -> float:
        return float(np.arctan2(self.pose[1, 0], self.pose[0, 0]))


@dataclass
class _Replacement:
    name: str
    class_name: str
    chosen: _Chosen
    model: CadModel
    timings: dict[str, float] = field(default_factory=dict)


def _library_model(library: CadLibrary, cad_id: str) -> CadModel | None:
    entry = library.entry(cad_id)
    return None if entry is None else library.model(entry)


def scene_from_folder(folder: str | Path, library: CadLibrary) -> tuple[ReplacedScene, dict[str, dict[str, Any]]]:
    """The replaced scene of a `scene-recon replace` folder, rebuilt from replacement.json and the library.

    An object kept as its observed mesh (no CAD model explained it) comes back as a box stand-in of its
    recorded size (``cad_id`` observed..., model source ``box``): it carries its children in the support
    tree, as in the exported scene, but it has no CAD pose to score and no mesh to measure penetration
    with, so `evaluate_scene` leaves stand-ins out of both."""
    path = Path(folder) / "replacement.json"
    if not path.is_file():
        raise InputError(f"{path} not found: expected a folder written by `scene-recon replace`")
    data = json.loads(path.read_text(encoding="utf-8"))
    if "scene" not in data:
        raise InputError(f"{path} has no scene description: re-run `scene-recon replace`")
    objects: list[PlacedObject] = []
    names: set[str] = {MAP_ROOT}
    for o in data["scene"]["objects"]:
        if o["cad_id"].startswith(("box", "observed")):
            model = box_model(o["class_name"], o["model_size"])
        else:
            base = _library_model(library, o["cad_id"])
            if base is None:
                continue
            model = base.scaled(o["scale"])
        parent = o["parent"] if o["parent"] in names else MAP_ROOT
        objects.append(PlacedObject(o["name"], o["class_name"], model, np.array(o["pose"]), parent=parent,
                                    parent_link=o["parent_link"] if parent != MAP_ROOT else "",
                                    support=o["support"], movable=o["movable"], entity_id=o["entity_id"],
                                    joint_values=o["joint_values"], scale=np.array(o["scale"]), cad_id=o["cad_id"]))
        names.add(o["name"])
    return ReplacedScene(data["scene"]["name"], objects), {r["name"]: r for r in data.get("objects_detail", [])}


def _model_box(obj: PlacedObject) -> GravityBox:
    """The placed CAD model's own box as a gravity box (a model lying on its side included)."""
    f = obj.model.features
    rot = obj.pose[:3, :3]
    up = int(np.argmax(np.abs(rot[2])))  # the model axis that points (anti)parallel to gravity
    hx, hy = (a for a in range(3) if a != up)
    yaw = float(np.arctan2(rot[1, hx], rot[0, hx]))
    size = np.maximum(np.array([f.box_size[hx], f.box_size[hy], f.box_size[up]]), 1e-6)
    return GravityBox(rot @ f.box_center + obj.pose[:3, 3], size, yaw)


def replaced_graph(graph: ContactGraph, scene: ReplacedScene) -> ContactGraph:
    """The contact graph the replaced scene implies: the input graph's nodes that were placed, each
    under the parent it rests on in the scene and with the box of its CAD model.

    Comparing its GED to the input graph's (both against the ground truth) shows whether stage 4
    kept the support structure it was given (the issue: "GED of the graph unchanged by replacement").
    """
    by_name = {n.name: nid for nid, n in graph.nodes.items()}
    out = ContactGraph(name=graph.name, frame_id=graph.frame_id, nodes={graph.root_id: graph.nodes[graph.root_id]},
                       root_id=graph.root_id)
    placed = {o.name: o for o in scene if o.name in by_name}
    for name, obj in placed.items():
        nid = by_name[name]
        node = graph.nodes[nid]
        box = _model_box(obj) if obj.model.source != "box" else node.box
        out.nodes[nid] = dataclasses.replace(node, box=box, box_unrefined=box)
    for name, obj in placed.items():
        nid = by_name[name]
        parent = by_name.get(obj.parent) if obj.parent != MAP_ROOT else None
        edge = graph.supports.get(nid)
        parent_id = parent if parent in out.nodes else graph.root_id
        if edge is not None:
            out.supports[nid] = dataclasses.replace(edge, parent_id=parent_id)
        else:
            out.supports[nid] = SupportEdge(parent_id, nid)
    out.proximal = [(a, b) for a, b in graph.proximal if a in out.nodes and b in out.nodes]
    return out


def evaluate_scene(scene: ReplacedScene, records: dict[str, dict[str, Any]], ground_truth: GroundTruthScene,
                   library: CadLibrary, physics_folder: str | Path | None = None,
                   graph: ContactGraph | None = None) -> dict[str, Any]:
    """Figures of one replaced scene (see module doc); with the input ``graph``, its GED against the
    ground truth before and after replacement too."""
    gt_objects = [e for e in ground_truth.entities if e.model_seed is not None]
    placed = [o for o in scene if o.cad_id and not o.cad_id.startswith(("box", "observed"))]
    centres_gt = np.array([e.box.center for e in gt_objects]) if gt_objects else np.zeros((0, 3))
    centres = np.array([o.pose[:3, :3] @ o.model.features.box_center + o.pose[:3, 3] for o in placed]) \
        if placed else np.zeros((0, 3))
    cost = np.full((len(gt_objects), len(placed)), 1e6)
    for i, e in enumerate(gt_objects):
        ok = set(candidate_classes(e.class_name))
        for j, o in enumerate(placed):
            d = float(np.linalg.norm(centres_gt[i] - centres[j]))
            if o.class_name in ok and d <= MATCH_RADIUS_M:
                cost[i, j] = d
    rows, cols = linear_sum_assignment(cost) if cost.size else (np.zeros(0, int), np.zeros(0, int))
    evals = []
    gt_classes = []
    matched = 0
    for i, j in zip(rows, cols, strict=True):
        if cost[i, j] >= 1e6:
            continue
        gt, obj = gt_objects[i], placed[j]
        base = _library_model(library, obj.cad_id)
        if base is None:
            continue
        rec = records.get(obj.name, {})
        cand = next((c for c in rec.get("candidates", []) if c.get("cad_id") == obj.cad_id), {})
        chosen = _Chosen(obj.cad_id, obj.class_name, obj.pose, obj.scale, obj.joint_values,
                         _Alignment(*(_number(cand.get(k)) for k in ("alignment_error", "ae_points", "ae_model"))))
        rep = _Replacement(obj.name, obj.class_name, chosen, base, dict(rec.get("timings", {})))
        gt_model = ground_truth.model_of(gt)
        assert gt_model is not None
        evals.append(evaluate_object(rep, gt_model, gt.pose, gt.joint_values))  # type: ignore[arg-type]
        gt_classes.append(gt.class_name)
        matched += 1
    # stand-ins of observed meshes rebuilt from a folder (see scene_from_folder) have no geometry to measure
    measured = [o for o in scene if not (o.cad_id.startswith("observed") and o.model.source == "box")]
    penetrations = pair_penetrations(ReplacedScene(scene.name, measured, frame_id=scene.frame_id))
    worst = max((d for _a, _b, d in penetrations), default=0.0)
    gaps = []
    for obj in scene:
        if obj.parent == MAP_ROOT or obj.model.source == "box":
            continue
        parent = scene.object(obj.parent)
        heights = [s.height for s in support_spots(parent)]
        bottom = min(float((m.vertices @ obj.pose[:3, :3].T + obj.pose[:3, 3])[:, 2].min())
                     for m in obj.model.posed_link_meshes(obj.joint_values).values() if len(m.vertices))
        gaps.append(min(abs(bottom - h) for h in heights))
    out: dict[str, Any] = {
        "ground_truth_objects": len(gt_objects), "replaced_objects": len(placed), "matched": matched,
        "objects": summarize(evals), "per_object": [_object_figures(e) for e in evals],
        "objects_by_class": failures_by_class(evals, gt_classes),
        "max_interpenetration_m": worst,
        "interpenetrating_pairs_over_1cm": sum(1 for _a, _b, d in penetrations if d > 0.01),
        "support_gap_median_m": float(np.median(gaps)) if gaps else None,
        "support_gap_max_m": float(np.max(gaps)) if gaps else None,
    }
    if graph is not None:
        from scene_recon.evaluation.graph_ground_truth import ground_truth_graph
        from scene_recon.evaluation.graph_metrics.ged import graph_edit_distance

        gt_graph = ground_truth_graph(ground_truth)
        before = graph_edit_distance(graph, gt_graph)
        after = graph_edit_distance(replaced_graph(graph, scene), gt_graph)
        out["ged_before"] = before.to_dict()
        out["ged_after"] = after.to_dict()
        out["ged_unchanged"] = after.total == before.total and after.wrong_support == before.wrong_support
    if physics_folder is not None:
        from scene_recon.evaluation.physics import check_mujoco, check_pybullet

        out["physics"] = {"pybullet": check_pybullet(physics_folder).to_dict(),
                          "mujoco": check_mujoco(physics_folder).to_dict()}
    return out


def _number(value: Any) -> float:
    """A recorded figure as a float (NaN when the record has none)."""
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else float("nan")


#: Why a per-object figure has no finite value (JSON holds null and this reason beside it, never NaN).
_UNDEFINED = {
    "ae_points": "not recorded: the chosen candidate in replacement.json has no ae_points (written by an older "
                 "replace, or the candidate was screened only, never fitted)",
    "ae_model": "not recorded: the chosen candidate in replacement.json has no ae_model (written by an older "
                "replace, or the candidate was screened only, never fitted)",
    "ae": "not recorded: the chosen candidate has no alignment_error in replacement.json",
}
_NO_CHOICE = "no CAD model was chosen for this object"


def _object_figures(e: Any) -> dict[str, Any]:
    """One object's figures with NaN/inf replaced by None and ``<key>_null_reason`` beside them."""
    out: dict[str, Any] = {}
    for key, value in e.__dict__.items():
        if isinstance(value, float) and not np.isfinite(value):
            out[key] = None
            out[f"{key}_null_reason"] = _NO_CHOICE if not e.chosen else _UNDEFINED.get(
                key, "not a number" if np.isnan(value) else "infinite")
        else:
            out[key] = value
    return out


__all__ = ["MATCH_RADIUS_M", "evaluate_scene", "replaced_graph", "scene_from_folder"]
