"""Stage 4 as one ROS-free pipeline: contact graph + node geometry -> a replaced, interactive scene.

``CadReplacer.replace(graph, entities)`` walks the contact graph from the root (parents first):

* layout nodes (floor, walls, ceiling) become box models fitted to their boxes (a floor seen as a
  plane still gets a slab to stand on);
* every object node becomes an ``ObjectObservation`` (its mesh samples, its refined gravity box,
  the height of the supporting plane of its support edge (Eq. 11's constraint), the side facing
  open space) and goes through ``replace_object`` (matching Eqs. 7-10, alignment Eqs. 11-14,
  articulation); the ranked candidates go to the global physical check (Sec. 4.4), which picks one
  per object and rests it on its support;
* an object whose class has no CAD model, or whose fitted models do not explain its observation
  (``acceptance``: AE and coverage limits, the class margin), keeps its observed mesh as a one-link
  model, so nothing mapped is lost and nothing exported is worse than what was seen; its record says
  why. Observed meshes are made fit for a simulator (``observed_physics``), a floor slab reaches
  under everything on it and what the graph hangs on a wall is mounted there.

Cost follows what changed: results are cached per node by (entity revision, parent, box), so an
update of one entity re-matches that entity only; models and their ray-casting scenes are built
once per library model (``GeometryCache``).
"""

from __future__ import annotations

import copy
import hashlib
import logging
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import trimesh

from cad_replacement.acceptance import (
    ClassSizes,
    ae_limit,
    class_size_range,
    fit_figures,
    judge,
    placed_error,
    rejection,
)
from cad_replacement.alignment import PreparedObservation
from cad_replacement.cad.features import scan_features
from cad_replacement.cad.model import CadModel, Link
from cad_replacement.collision import observed_collisions
from cad_replacement.geometry_cache import GeometryCache, library_store
from cad_replacement.layout_models import MIN_LAYOUT_THICKNESS, box_model
from cad_replacement.observation import (
    HANDLE_SLAB,
    MAX_FOOTPRINT_SHARE,
    MESH_SAMPLES,
    ObjectObservation,
    ObservationError,
    carried_footprint_points,
    clean_entity_points,
    front_direction_from_context,
)
from cad_replacement.observed_physics import settle_observed
from cad_replacement.replace_config import CadReplacementConfig
from cad_replacement.replace_object import CadSource, CandidateResult, ObjectReplacement, replace_object
from cad_replacement.scene_model import MAP_ROOT, PlacedObject, ReplacedScene
from cad_replacement.workers import ReplaceWorkers, open3d_threads, resolve_workers
from recon_core.classes import ClassTable, UnknownClassError, load_class_table
from recon_core.contact_graph import ContactGraph, GraphNode, SupportEdge
from recon_core.entity import Entity
from recon_core.geometry.box import GravityBox
from recon_core.geometry.box_fit import fit_gravity_box
from recon_core.geometry.plane import Plane
from recon_core.geometry.plane_fit import sample_mesh
from scene_graph.blas import single_blas_thread

log = logging.getLogger(__name__)

LAYOUT = "layout"
#: Colour of objects kept as their observed mesh (no CAD model for their class).
OBSERVED_RGBA = (0.55, 0.6, 0.7, 1.0)

#: A global physical check: (scene of first choices, ranked alternatives per object name) -> scene.
PhysicalCheck = Callable[[ReplacedScene, Mapping[str, Sequence[PlacedObject]]], ReplacedScene]


@dataclass
class ReplacementRecord:
    """What ``replacement.json`` says about one node: its candidates, the choice and the timings."""

    node_id: int
    name: str
    class_name: str
    kind: str  # "cad" | "layout" | "observed_mesh"
    cad_id: str = ""
    candidates: list[dict[str, Any]] = field(default_factory=list)
    pose: list[list[float]] = field(default_factory=list)
    scale: list[float] = field(default_factory=list)
    joint_values: dict[str, float] = field(default_factory=dict)
    alignment_error: float | None = None
    matching_error: float | None = None
    timings: dict[str, float] = field(default_factory=dict)
    message: str = ""
    reused: bool = False
    #: Why the object is kept as its observed mesh although it has CAD candidates ("AE 54 mm > limit
    #: 30 mm (chair/p3)"; ``acceptance``); "" when a CAD model stands for it.
    reason: str = ""
    #: The detected class when a model of another class replaced it (``acceptance``: class margin).
    substituted_from: str = ""
    #: Fit quality of the exported model (or of the rejected best candidate): ``ae`` two-sided,
    #: ``ae_points`` the paper's AE, ``ae_model``, ``coverage``, ``view_coverage``, ``ae_limit`` (m or shares).
    fit: dict[str, Any] = field(default_factory=dict)
    #: The class margin's comparison (detected vs other class best AE), when both were fitted.
    class_comparison: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass
class ReplacementResult:
    scene: ReplacedScene
    records: list[ReplacementRecord]
    timings: dict[str, float]

    @property
    def rematched(self) -> int:
        """Objects matched and aligned in this call (CAD models, and observed meshes whose candidates
        the acceptance gate refused), not reused from an earlier call."""
        return sum(1 for r in self.records if not r.reused and (r.kind == "cad" or (
            r.kind == "observed_mesh" and bool(r.candidates))))


@dataclass
class _Cached:
    key: tuple[Any, ...]
    replacement: ObjectReplacement | None
    record: ReplacementRecord
    #: The observation the replacement was made for (the physical check's backups are judged on it).
    obs: ObjectObservation | None = None


@dataclass
class _Job:
    """A node to (re)match: its cache key and observation, or why it has none."""

    node: GraphNode
    key: tuple[Any, ...]
    obs: ObjectObservation | None
    failure: ObservationError | None


#: Largest gap (m) between a supported object's observed bottom and its supporting plane that is
#: taken as occlusion of the bottom; a larger gap means the graph picked a plane below the real one.
MAX_SUPPORT_GAP = 0.03


def support_height(edge: SupportEdge | None, parent: GraphNode | None, child_box: GravityBox | None = None,
                   max_size: float | None = None) -> float | None:
    """z of the plane a supported object stands on (Eq. 11's constraint), or ``None``.

    The support edge's plane when it is horizontal, else the parent's box top. When the child's
    observed bottom lies more than ``MAX_SUPPORT_GAP`` above that (a mapped cabinet offers its shelf
    planes too, and the edge may name one below the top the bottle stands on), the parent's
    highest upward plane under the child's bottom is used, or the child's bottom itself.

    Except on the layout (the floor): an object the graph stands on the floor whose class can be
    as tall as its observed top is above the floor (``max_size``, the class table's ``max_size_m``)
    reaches down to it: its lower part (table legs, a chair's frame, a plinth) was not segmented
    with it, as happens on mapped tables whose top alone got the label. A cup seen 70 cm above
    the floor cannot be that tall and keeps its own bottom.
    """
    plane: Plane | None = edge.plane if edge is not None else None
    z: float | None = None
    if plane is not None and plane.normal[2] > 0.9:
        z = float(-plane.d / plane.normal[2])
    elif parent is not None and parent.box is not None:
        z = parent.box.z_max
    if z is not None and child_box is not None and z > child_box.z_max:
        # a support above the whole object carries nothing of it (a ceiling taken for the floor would lift
        # every object 1.7 m; docs/REAL_DATA_TUM.md): the object keeps its own bottom
        return child_box.z_min
    if z is None or child_box is None or child_box.z_min - z <= MAX_SUPPORT_GAP:
        return z
    if parent is not None and parent.category == LAYOUT and max_size is not None \
            and child_box.z_max - z <= max_size:
        return z
    bottom = child_box.z_min
    ups = [float(-p.plane.d / p.plane.normal[2]) for p in (parent.planes if parent is not None else [])
           if p.plane.normal[2] > 0.9]
    under = [h for h in ups if z <= h <= bottom + 0.5 * MAX_SUPPORT_GAP]
    return max(under) if under and bottom - max(under) <= MAX_SUPPORT_GAP else bottom


def layout_object(node: GraphNode, parent: str = MAP_ROOT,
                  room_center: np.ndarray | None = None) -> PlacedObject | None:
    """A box model for a layout node; the floor's top stays where the floor surface was seen."""
    if node.box is None:
        return None
    box = node.box
    size = np.maximum(np.asarray(box.size, dtype=np.float64), MIN_LAYOUT_THICKNESS)
    pose = box.pose()
    if node.class_name == "floor":
        # the slab's top is the floor plane (the largest upward plane), not the top of the floor
        # entity's box, which clutter and fringe lift on mapped floors
        up = [p.plane for p in node.planes if p.plane.normal[2] > 0.9]
        top = -max(up, key=lambda p: p.area).d if up else box.z_max
        pose[2, 3] = top - size[2]
    else:
        pose[2, 3] = box.z_min
        if node.class_name == "wall" and room_center is not None:
            pose[:3, 3] = _wall_slab_centre(node, pose, size, room_center)
    return PlacedObject(node.name, node.class_name, box_model(node.class_name, size), pose, parent=parent,
                        entity_id=node.id, cad_id=f"box/{node.class_name}")


def _wall_slab_centre(node: GraphNode, pose: np.ndarray, size: np.ndarray, room_center: np.ndarray) -> np.ndarray:
    """Bottom centre of a wall slab whose room-side face lies on the wall's room-side plane.

    A mapped wall is a thin shell of surface; centring a slab of ``MIN_LAYOUT_THICKNESS`` on it
    pushes half the slab into the room, where furniture standing against the wall then collides.
    Of the wall's vertical planes, the one nearest the room centre (in front of which the room
    lies) is its room side; the slab extends behind it, away from the room.
    """
    best: tuple[float, np.ndarray, float] | None = None
    for sp in node.planes:
        p = sp.plane
        if abs(p.normal[2]) >= 0.3:
            continue
        n = np.array([p.normal[0], p.normal[1], 0.0])
        n /= max(float(np.linalg.norm(n)), 1e-12)
        d = float(p.signed_distance(room_center[None, :])[0])
        if d < 0.0:  # orient the normal towards the room
            n, d = -n, -d
        if best is None or d < best[0]:
            best = (d, n, float(p.signed_distance(pose[None, :3, 3])[0]) * (1.0 if n @ p.normal[:3] > 0 else -1.0))
    if best is None:
        return pose[:3, 3]
    _, n, offset = best  # offset: the box centre's height above the room-side plane, along n
    k = int(np.argmax(np.abs(pose[:2, :3].T @ n[:2])))  # the box axis across the wall
    return pose[:3, 3] - (offset + 0.5 * float(size[k])) * n


def _room_center(graph: ContactGraph) -> np.ndarray | None:
    """A point inside the room: the floor's box centre, else the mean centre of the object boxes."""
    floors = [n.box for n in graph.nodes.values() if n.class_name == "floor" and n.box is not None]
    if floors:
        return np.asarray(max(floors, key=lambda b: b.footprint_area).center, dtype=np.float64)
    boxes = [n.box.center for n in graph.nodes.values() if n.category != LAYOUT and n.box is not None]
    return np.mean(np.asarray(boxes, dtype=np.float64), axis=0) if boxes else None


def observed_mesh_object(node: GraphNode, entity: Entity, parent: str, support: str) -> PlacedObject | None:
    """The observed mesh itself as a one-link model (origin at the bottom centre of its box)."""
    if not entity.has_faces or node.box is None:
        return None
    pose = node.box.bottom_pose()
    mesh = entity.mesh().copy()
    mesh.apply_transform(np.linalg.inv(pose))
    # collides as its hull (``observed_collisions``): convex decomposition of a partial scan is slow and
    # meaningless, and would run again at every map update; a movable one grounded, so a one-sided scan stands
    grounded = node.movable  # a fixed one (a table) keeps the space under it free
    # grounded to the box's bottom (its origin) when the scan does not reach it (``PlacedObject.resting_height``)
    link = Link("body", mesh, OBSERVED_RGBA,
                collisions=lambda: observed_collisions(mesh, grounded=grounded, ground_z=0.0))
    model = CadModel(node.class_name, f"observed_{node.id}", (link,), (), scan_features(mesh),
                     source="observed")
    return PlacedObject(node.name, node.class_name, model, pose, parent=parent, support=support,
                        movable=node.movable, entity_id=node.id, cad_id="observed")


def rest_on(obj: PlacedObject, z: float) -> None:
    """Move ``obj`` vertically so the bottom it rests with (``PlacedObject.resting_height``) is at height ``z``."""
    obj.pose[2, 3] += z - obj.resting_height()


class CadReplacer:
    """Contact graph + node entities -> ``ReplacedScene``; incremental across calls."""

    def __init__(self, library: CadSource, config: CadReplacementConfig | None = None,
                 class_table: ClassTable | None = None, physical_check: PhysicalCheck | None = None,
                 workers: ReplaceWorkers | None = None) -> None:
        """``workers``: a pool to share with other replacers of the same library (a node that starts
        over keeps its warm workers); by default the replacer starts its own per ``config.workers``."""
        self.library = library
        self.config = config or CadReplacementConfig()
        self.class_table = class_table or load_class_table()
        self.physical_check = physical_check
        self.cache = GeometryCache(library.model, samples=self.config.ae_model_samples,
                                   store=library_store(library))
        self._results: dict[int, _Cached] = {}
        self._class_sizes: dict[str, tuple[np.ndarray, np.ndarray] | None] = {}
        self._owns_workers = workers is None
        if workers is None:
            n_workers = resolve_workers(self.config.workers)
            workers = ReplaceWorkers(library, n_workers) if n_workers > 1 else None
        self._workers = workers

    @property
    def _reads_observed_space(self) -> bool:
        """Ours reads the map's observed/unknown grid where an entity carries one; the paper's method
        (and ``observed_space: false``) does not."""
        return self.config.observed_space and self.config.method != "paper"

    def round_body(self, class_name: str) -> bool:
        """Whether the class table declares the class a solid of revolution (the fit may turn its yaw freely)."""
        try:
            return bool(self.class_table.by_name(class_name).round)
        except UnknownClassError:
            return False

    def _max_size(self, class_name: str) -> float | None:
        """The class table's largest extent of a class (None: unknown class or not given)."""
        try:
            return self.class_table.by_name(class_name).max_size_m
        except UnknownClassError:
            return None

    # ------------------------------------------------------------------ per node
    def _observation(self, node: GraphNode, entity: Entity, graph: ContactGraph,
                     walls: list[Plane], obstacles: list[GravityBox]) -> ObjectObservation:
        edge = graph.supports.get(node.id)
        parent = graph.nodes.get(edge.parent_id) if edge is not None else None
        box = node.box
        assert box is not None
        others = [b for b in obstacles if b is not box]
        front = front_direction_from_context(box, others, walls)
        # The voted core only: the mapper's fringe fill joins background along depth edges (a 5 cm
        # bottle grows to 17 cm against the cabinet behind it) and the fit would stretch to cover it.
        core_v, core_f = entity.core_mesh()
        trimmed = len(core_f) < len(entity.faces)
        mesh = trimesh.Trimesh(core_v, core_f, process=False)
        support_z = support_height(edge, parent, node.box_unrefined or box, self._max_size(node.class_name))
        if len(mesh.faces) == 0:
            raise ObservationError(f"{node.name!r}: mesh is empty")
        points, normals = sample_mesh(mesh, MESH_SAMPLES, 0)
        children = [b for c, e in graph.supports.items()
                    if e.parent_id == node.id and c in graph.nodes and (b := graph.nodes[c].box) is not None]
        keep = clean_entity_points(points, normals, support_z, children)
        if trimmed or not keep.all():
            points, normals = points[keep], normals[keep]
        # the top hidden under what this object carries (observation.carried_footprint_points)
        top_z = float(np.quantile(points[:, 2], 0.98))
        spacing = float(np.sqrt(max(mesh.area, 1e-9) / MESH_SAMPLES))
        extra, extra_normals = carried_footprint_points(top_z, children, spacing,
                                                        int(MAX_FOOTPRINT_SHARE * len(points)))
        if len(extra):
            points, normals = np.concatenate([points, extra]), np.concatenate([normals, extra_normals])
        if trimmed or not keep.all() or len(extra):
            refit = fit_gravity_box(points)
            bottom = min(refit.z_min, support_z) if support_z is not None else refit.z_min
            box = refit.with_z_range(bottom, refit.z_max)
        return ObjectObservation(node.id, node.name, node.class_name, points, box=box, normals=normals,
                                 support_z=support_z, front_hint=front, mesh=mesh,
                                 observed_space=entity.observed_space if self._reads_observed_space else None,
                                 walls=tuple(walls), neighbours=_touching(box, others),
                                 loads=tuple(children))

    def _node_job(self, node: GraphNode, entity: Entity, graph: ContactGraph, walls: list[Plane],
                  obstacles: list[GravityBox]) -> _Cached | _Job:
        """The node's cached result when nothing it depends on changed, else the job replacing it."""
        edge = graph.supports.get(node.id)
        box_key = None if node.box is None else tuple(
            round(float(v), 4) for v in (*node.box.center, *node.box.size, node.box.yaw))
        # The observation depends on more than the node itself (the support height from the parent's box,
        # the children cut off, the front from the walls and the other boxes): it is part of the key, so an
        # incremental replacement (the ROS node, graph after graph) ends where a batch one (`replace`) does.
        obs: ObjectObservation | None = None
        failure: ObservationError | None = None
        try:
            obs = self._observation(node, entity, graph, walls, obstacles)
        except ObservationError as exc:
            failure = exc
        key: tuple[Any, ...] = (entity.revision, len(entity.vertices), edge.parent_id if edge else None, box_key,
                                _observation_digest(obs))
        cached = self._results.get(node.id)
        if cached is not None and cached.key == key:
            cached.record.reused = True
            return cached
        return _Job(node, key, obs, failure)

    def _finish(self, job: _Job, outcome: ObjectReplacement | BaseException) -> _Cached:
        """Record a job's outcome (a replacement, or the ``ObservationError`` that stopped it)."""
        node = job.node
        record = ReplacementRecord(node.id, node.name, node.class_name, "cad")
        replacement: ObjectReplacement | None = None
        if isinstance(outcome, ObservationError):
            record.message = f"not matched: {outcome}"
        elif isinstance(outcome, BaseException):
            raise outcome
        else:
            replacement = outcome
            record.timings = dict(replacement.timings)
            record.message = replacement.message
            assert job.obs is not None
            verdict = judge(replacement, job.obs, self.config,
                            self.class_sizes({c.class_name for c in replacement.candidates}),
                            round_body=self.round_body(job.obs.class_name))
            record.candidates = [
                {"cad_id": c.key, "class_name": c.class_name, "matching_error": c.matching_error,
                 "alignment_error": c.ae.ae, "score": c.score, "stage": c.stage, "scale": c.scale.tolist(),
                 "yaw": c.yaw, **{k: v for k, v in fit_figures(c).items() if k != "ae"},
                 "accepted": not why, "rejected": why}
                for c, why in zip(replacement.candidates, verdict.rejections, strict=True)]
            record.reason = verdict.reason
            record.substituted_from = verdict.substituted_from
            record.class_comparison = verdict.class_comparison
            shown = verdict.accepted[0] if verdict.accepted else next(
                (c for c in replacement.candidates if c.stage == "full"), None)
            if shown is not None:
                record.fit = {**fit_figures(shown), "cad_id": shown.key, "ae_limit": verdict.ae_limit}
                record.alignment_error = record.fit["ae"]
                record.matching_error = float(shown.matching_error)
            # Only accepted candidates may be placed, as the choice or as the physical check's backups;
            # screened-only ones of the chosen class follow as backups the check judges when it asks for
            # them (``_RankedAlternatives``: their AE at the screened placement, then the gate).
            replacement.candidates = verdict.accepted + verdict.backups if verdict.accepted else []
            replacement.chosen = verdict.accepted[0] if verdict.accepted else None
            replacement.model = None if replacement.chosen is None else \
                self.cache.get(replacement.chosen.match.entry).model
            if verdict.reason and record.candidates:
                record.message = "; ".join(m for m in (record.message, f"observed mesh kept: {verdict.reason}") if m)
        result = _Cached(job.key, replacement, record, job.obs)
        self._results[node.id] = result
        return result

    def class_sizes(self, classes: Iterable[str]) -> ClassSizes:
        """The library's size range of each of ``classes`` (``acceptance.class_size_range``; a class
        without models has none), computed once per class."""
        for name in classes:
            if name not in self._class_sizes:
                boxes = [f.box_size for _, f in self.library.candidates(name)]
                self._class_sizes[name] = class_size_range(boxes) if boxes else None
        return {n: r for n in classes if (r := self._class_sizes.get(n)) is not None}

    def _replace_here(self, obs: ObjectObservation) -> ObjectReplacement | BaseException:
        try:
            return replace_object(obs, self.library, self.config, cache=self.cache, class_table=self.class_table)
        except ObservationError as exc:
            return exc

    def _replace_nodes(self, graph: ContactGraph, entities: Mapping[int, Entity], walls: list[Plane],
                       obstacles: list[GravityBox]) -> dict[int, _Cached]:
        """Every object node's result: reused when nothing it depends on changed, else (re)matched.

        With workers, each job is sent off as soon as its observation is built, largest objects first
        (they take longest: articulated furniture), so the workers stay evenly busy while this process
        builds the rest. Workers start only for a scene with ``parallel_min_objects`` objects; once they
        run (warm), updates use them too. A broken pool falls back to in-process replacement."""
        todo = [graph.nodes[nid] for nid in object_node_ids(graph)
                if entities.get(nid) is not None and not entities[nid].is_empty]
        todo.sort(key=lambda n: -(n.box.volume if n.box is not None else 0.0))
        workers = self._workers
        if workers is not None and not workers.started and len(todo) < self.config.parallel_min_objects:
            workers = None
        done: dict[int, _Cached] = {}
        pending: list[tuple[_Job, Future[ObjectReplacement] | None]] = []
        for node in todo:
            item = self._node_job(node, entities[node.id], graph, walls, obstacles)
            if isinstance(item, _Cached):
                done[node.id] = item
            elif item.obs is None:
                failure = item.failure or ObservationError(f"{node.name!r}: no observation")
                done[node.id] = self._finish(item, failure)
            else:
                future = workers.submit(item.obs, self.config, self.class_table) if workers is not None else None
                pending.append((item, future))
        for job, future in pending:
            assert job.obs is not None
            outcome = workers.result(future) if workers is not None and future is not None else None
            done[job.node.id] = self._finish(job, outcome if outcome is not None else self._replace_here(job.obs))
        return done

    @property
    def workers_running(self) -> bool:
        """Whether objects are being replaced in worker processes (a pool started and not failed)."""
        return self._workers is not None and self._workers.started

    def close(self) -> None:
        """Stop the worker processes this replacer started, if any (a later ``replace`` starts them again)."""
        if self._workers is not None and self._owns_workers:
            self._workers.close()

    def __enter__(self) -> CadReplacer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ scene
    def replace(self, graph: ContactGraph, entities: Mapping[int, Entity], name: str = "") -> ReplacementResult:
        """Replace every node of ``graph`` (``entities``: node id -> its geometry in the map frame).

        Runs with one BLAS thread: the fits multiply matrices of a few hundred points, far too small
        for OpenBLAS threads to pay: on 2 cores a kitchen scene (18 objects, warm caches) took 4.5-5.1 s
        and 6.7-7.3 CPU s with them, 4.1-4.2 s and 4.4-4.5 CPU s with one (``scene_graph.blas``).
        With a worker pool, Open3D runs on one thread here too (``workers.open3d_threads``)."""
        with single_blas_thread(), open3d_threads(1 if self._workers is not None else None):
            return self._replace(graph, entities, name)

    def _replace(self, graph: ContactGraph, entities: Mapping[int, Entity], name: str) -> ReplacementResult:
        t0 = time.perf_counter()
        graph.validate()
        walls = [p.plane for n in graph.nodes.values() if n.category == LAYOUT and n.class_name == "wall"
                 for p in n.planes if abs(p.plane.normal[2]) < 0.3]
        obstacles = [n.box for n in graph.nodes.values() if n.box is not None and n.id != graph.root_id]
        objects: list[PlacedObject] = []
        records: list[ReplacementRecord] = []
        alternatives: dict[str, Sequence[PlacedObject]] = {}
        names = {nid: n.name for nid, n in graph.nodes.items()}
        placed: set[str] = set()
        room_center = _room_center(graph)
        done = self._replace_nodes(graph, entities, walls, obstacles)
        # Then place every node, parents first.
        for nid, _depth in graph.walk():
            if nid == graph.root_id:
                continue
            node = graph.nodes[nid]
            edge = graph.supports.get(nid)
            parent = MAP_ROOT if edge is None or edge.parent_id == graph.root_id else names[edge.parent_id]
            if parent != MAP_ROOT and parent not in placed:
                parent = MAP_ROOT  # the parent could not be placed: the object stands on the map
            support = edge.joint if edge is not None and edge.joint in ("fixed", "floating") else "fixed"
            mounted = support == "floating" and edge is not None and _hangs_on_wall(graph, edge)
            if mounted:
                # a wall carries nothing from below: an object the graph hangs on one (a screen, or its
                # fallback for an object on an unmapped counter) is mounted there, not dropped in simulation
                support = "fixed"
            obj: PlacedObject | None
            if node.category == LAYOUT:
                obj = layout_object(node, parent, room_center)
                record = ReplacementRecord(nid, node.name, node.class_name, "layout", cad_id="box")
            else:
                entity = entities.get(nid)
                if entity is None or entity.is_empty:
                    records.append(ReplacementRecord(nid, node.name, node.class_name, "skipped",
                                                     message="no geometry for this node"))
                    continue
                cached = done[nid]
                record = copy.copy(cached.record)  # notes of this scene (mount, switches) stay out of the cache
                obj = self._placed(node, cached.replacement, parent, support)
                if obj is None:
                    obj = observed_mesh_object(node, entity, parent, support)
                    record.kind = "observed_mesh"
                elif cached.replacement is not None:
                    alternatives[obj.name] = _RankedAlternatives(self, node, cached.replacement, parent, support,
                                                                 cached.obs, entity)
            if obj is None:
                record.kind = "skipped"
                records.append(record)
                continue
            if node.category != LAYOUT and edge is not None:
                z = support_height(edge, graph.nodes[edge.parent_id], node.box_unrefined or node.box,
                                   self._max_size(node.class_name))
                if z is not None:
                    rest_on(obj, z)
            if node.category != LAYOUT and mounted:
                note = f"mounted on {parent} (a wall carries nothing from below): fixed joint"
                if note not in record.message:
                    record.message = "; ".join(m for m in (record.message, note) if m)
            record.pose = obj.pose.tolist()
            record.scale = obj.scale.tolist()
            record.joint_values = dict(obj.joint_values)
            record.cad_id = record.cad_id or obj.cad_id
            objects.append(obj)
            placed.add(obj.name)
            records.append(record)
        for obj in objects:
            if obj.class_name == "floor" and obj.model.source == "box":
                _floor_under_children(obj, objects)
        _note_settled(records, settle_observed(objects, patch=False))
        scene = ReplacedScene(name or graph.name or "scene", objects, frame_id=graph.frame_id)
        scene.validate()
        t1 = time.perf_counter()
        if self.physical_check is not None:
            scene = self.physical_check(scene, alternatives)
            _note_switches(scene, records, alternatives)
        # again after the check: it may have moved an object into an observed neighbour (snap, push-outs)
        _note_settled(records, settle_observed(scene.objects))
        t2 = time.perf_counter()
        live = {n.id for n in graph.nodes.values()}
        for stale in set(self._results) - live:
            del self._results[stale]
        return ReplacementResult(scene, records, {"objects_s": t1 - t0, "physical_check_s": t2 - t1,
                                                  "total_s": t2 - t0})

    def _placed(self, node: GraphNode, rep: ObjectReplacement | None, parent: str, support: str,
                index: int = 0) -> PlacedObject | None:
        """The ``index``-th ranked candidate of ``rep`` as a placed object (None when there is none)."""
        if rep is None or index >= len(rep.candidates):
            return None
        return self._placed_candidate(node, rep.candidates[index], parent, support)

    def _placed_candidate(self, node: GraphNode, cand: CandidateResult, parent: str, support: str) -> PlacedObject:
        """One candidate as a placed object."""
        model = self.cache.get(cand.match.entry).model.scaled(cand.scale)
        return PlacedObject(node.name, cand.class_name, model, cand.pose.copy(), parent=parent, support=support,
                            movable=node.movable, entity_id=node.id, joint_values=dict(cand.joint_values),
                            scale=cand.scale, cad_id=cand.key)


class _RankedAlternatives(Sequence[PlacedObject]):
    """The ranked backup candidates (2nd, 3rd, ...) of one object, built only when asked for.

    The physical check usually needs none or one of them; scaling a CAD model for all top-k
    candidates of every object up front cost more than matching the whole scene.
    """

    def __init__(self, replacer: CadReplacer, node: GraphNode, rep: ObjectReplacement, parent: str,
                 support: str, obs: ObjectObservation | None = None, entity: Entity | None = None) -> None:
        self._args = (replacer, node, rep, parent, support)
        self._obs = obs
        self._entity = entity
        #: the object's scan, once the physical check asked for it (``scan``)
        self.built_scan: PlacedObject | None = None
        self._prepared: PreparedObservation | None = None
        self._built: dict[int, PlacedObject | None] = {}
        #: The candidate behind each built alternative (a screened one with its AE measured where it is placed).
        self.built_candidates: dict[int, CandidateResult] = {}
        self._len = max(len(rep.candidates) - 1, 0)
        #: selection scores (lower is better) of the choice and of each alternative: how much worse a
        #: backup fits, for checks that trade fit for consistency (``physical_check.fit_supports``)
        self.chosen_score = float(rep.candidates[0].score) if rep.candidates else float("inf")
        self.scores = [float(c.score) for c in rep.candidates[1:]]

    def __len__(self) -> int:
        return self._len

    def __getitem__(self, index: int) -> PlacedObject:  # type: ignore[override]
        if not 0 <= index < self._len:
            raise IndexError(index)
        if index not in self._built:
            replacer, node, rep, parent, support = self._args
            listed = rep.candidates[index + 1]
            cand = listed if listed.stage == "full" else self._judged(listed)
            if cand is None:  # fails the gate: the first choice again (no switch can come of it)
                self._built[index] = replacer._placed_candidate(node, rep.candidates[0], parent, support)
            else:
                self._built[index] = replacer._placed(node, rep, parent, support, index + 1)
                self.built_candidates[index] = cand
        obj = self._built[index]
        if obj is None:  # pragma: no cover - every ranked candidate has a model
            raise IndexError(index)
        return obj

    def scan(self) -> PlacedObject | None:
        """The object as its observed mesh, for a check that finds no model consistent with what was seen
        (``PhysicalCheck._fit_supports``: what stands inside it); None without geometry or for the paper's
        method, which always places a model."""
        replacer, node, _rep, parent, support = self._args
        if self._entity is None or replacer.config.method == "paper":
            return None
        if self.built_scan is None:
            self.built_scan = observed_mesh_object(node, self._entity, parent, support)
        return self.built_scan

    def _judged(self, cand: CandidateResult) -> CandidateResult | None:
        """A screened-only backup with its AE where it would be placed, or None when it fails the gate."""
        replacer = self._args[0]
        if self._obs is None:
            return None
        if self._prepared is None:
            self._prepared = PreparedObservation.build(self._obs, replacer.config)
        judged = placed_error(self._prepared, cand, replacer.cache.get(cand.match.entry), replacer.config)
        cfg = replacer.config
        ok = not cfg.accept_gate or not rejection(judged, ae_limit(self._obs, cfg), cfg,
                                                  replacer.class_sizes([judged.class_name]),
                                                  replacer.round_body(self._obs.class_name))
        return judged if ok else None


def _note_switches(scene: ReplacedScene, records: list[ReplacementRecord],
                   alternatives: Mapping[str, Sequence[PlacedObject]]) -> None:
    """Records of objects the physical check gave another candidate name it, with its fit figures."""
    by_name = {r.name: r for r in records}
    for obj in scene:
        alts = alternatives.get(obj.name)
        record = by_name.get(obj.name)
        if not isinstance(alts, _RankedAlternatives) or record is None:
            continue
        if alts.built_scan is not None and obj is alts.built_scan:
            held = sorted(o.name for o in scene if o.parent == obj.name)
            record.reason = (f"no model of it has room where {', '.join(held)} stood inside it "
                             f"({record.cad_id} and its alternatives): its scan holds them where they were seen")
            record.message = "; ".join(m for m in (record.message, f"physical check: {record.cad_id} -> "
                                                   "observed mesh") if m)
            record.kind, record.cad_id = "observed_mesh", "observed"
            record.pose, record.scale, record.joint_values = obj.pose.tolist(), obj.scale.tolist(), {}
            continue
        for index, cand in alts.built_candidates.items():
            built = alts._built.get(index)
            if built is not None and built.model is obj.model:
                first = record.cad_id
                record.cad_id = cand.key
                record.fit = {**fit_figures(cand), "cad_id": cand.key, "ae_limit": record.fit.get("ae_limit")}
                record.alignment_error = record.fit["ae"]
                record.message = "; ".join(m for m in (record.message, f"physical check: {first} -> {cand.key}")
                                           if m)
                break


def object_node_ids(graph: ContactGraph) -> list[int]:
    """The graph's nodes stage 4 replaces by a model: neither the root nor layout (each needs its entity)."""
    return [nid for nid, n in graph.nodes.items() if nid != graph.root_id and n.category != LAYOUT]


__all__ = ["CadReplacer", "PhysicalCheck", "ReplacementRecord", "ReplacementResult", "layout_object",
           "object_node_ids", "observed_mesh_object", "rest_on", "support_height"]


#: Margin (m) by which a floor slab reaches beyond the footprint of what stands on it.
FLOOR_MARGIN = 0.05


def _floor_under_children(floor: PlacedObject, objects: Sequence[PlacedObject]) -> None:
    """Grow a floor slab to reach under everything standing on it: the mapped floor ends where the
    camera stopped seeing it, and a chair beyond that edge tipped off the slab in simulation."""
    inv = np.linalg.inv(floor.pose)
    size = np.asarray(floor.model.size, dtype=np.float64)
    lo, hi = -0.5 * size[:2], 0.5 * size[:2]
    new_lo, new_hi = lo.copy(), hi.copy()
    for child in objects:
        if child.parent != floor.name:
            continue
        for mesh in child.model.posed_link_meshes(child.joint_values).values():
            if not len(mesh.vertices):
                continue
            v = np.asarray(mesh.vertices, np.float64) @ child.pose[:3, :3].T + child.pose[:3, 3]
            local = v @ inv[:3, :3].T + inv[:3, 3]
            new_lo = np.minimum(new_lo, local[:, :2].min(axis=0) - FLOOR_MARGIN)
            new_hi = np.maximum(new_hi, local[:, :2].max(axis=0) + FLOOR_MARGIN)
    if np.allclose(new_lo, lo) and np.allclose(new_hi, hi):
        return
    centre = 0.5 * (new_lo + new_hi)
    floor.model = box_model(floor.class_name, [*(new_hi - new_lo), size[2]])
    floor.pose[:3, 3] += floor.pose[:3, :2] @ centre


def _note_settled(records: list[ReplacementRecord], changes: Mapping[str, Mapping[str, int]]) -> None:
    """Say in the records what ``settle_observed`` changed on objects kept as their observed mesh."""
    by_name = {r.name: r for r in records}
    for name, change in changes.items():
        rec = by_name.get(name)
        parts = [f"{change['dropped']} pieces inside other objects dropped" if change["dropped"] else "",
                 f"{change['clipped']} pieces cut where they met another object" if change.get("clipped") else "",
                 f"{change['patches']} support patches" if change["patches"] else ""]
        note = ", ".join(p for p in parts if p)
        if rec is not None and note:
            rec.message = "; ".join(m for m in (rec.message, f"observed mesh: {note}") if m)


def _touching(box: GravityBox, others: Sequence[GravityBox]) -> tuple[GravityBox, ...]:
    """The boxes among ``others`` that reach within ``HANDLE_SLAB`` of ``box`` (footprint and height): the
    only neighbours whose surface can lie where this object's handles would (``handle_side``), so only a
    change next to the object changes its observation."""
    grown = GravityBox(box.center, np.asarray(box.size, np.float64) + np.array([2.0, 2.0, 0.0]) * HANDLE_SLAB,
                       box.yaw)
    return tuple(b for b in others if grown.z_overlap(b) > 0.0 and grown.footprint_intersection(b) > 0.0)


def _hangs_on_wall(graph: ContactGraph, edge: SupportEdge) -> bool:
    """Whether a support edge hangs its child on a wall. Stage 4 models a wall as a vertical slab, so it
    carries nothing from below, whatever plane of the mapped wall (a shelf strip, a counter's edge
    seen with it) the graph found under the child."""
    parent = graph.nodes.get(edge.parent_id)
    return parent is not None and parent.category == LAYOUT and parent.class_name == "wall"


def _observation_digest(obs: ObjectObservation | None) -> str:
    """A fingerprint of everything an observation hands to matching and alignment."""
    if obs is None:
        return ""
    h = hashlib.sha1(np.ascontiguousarray(obs.points, np.float64).tobytes())
    if obs.normals is not None:
        h.update(np.ascontiguousarray(obs.normals, np.float64).tobytes())
    box = obs.box
    extra = (None if box is None else (*box.center, *box.size, box.yaw), obs.support_z,
             None if obs.front_hint is None else tuple(np.asarray(obs.front_hint, float)))
    h.update(repr(extra).encode())
    h.update(repr([(*b.center, *b.size, b.yaw) for b in obs.neighbours]).encode())
    h.update(repr([(*b.center, *b.size, b.yaw) for b in obs.loads]).encode())
    if obs.observed_space is not None:  # the grid, and the walls that bound its room
        space = obs.observed_space
        h.update(repr((*space.origin, space.cell, space.shape)).encode())
        h.update(space.packed().tobytes())
        h.update(repr([(*w.normal, w.d) for w in obs.walls]).encode())
    return h.hexdigest()
