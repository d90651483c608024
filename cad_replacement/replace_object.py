"""Replace one observed entity by a posed, scaled and articulated CAD model (paper Sec. 4.2-4.3).

``replace_object(observation, library, config)`` runs matching (Eqs. 7-10), alignment (Eqs. 11-14
as a dense fit), articulation and selection, for either method of ``CadReplacementConfig``:

* ``"paper"``: all 24 orientations per model; L1 box term + Hungarian plane term; every top-k
  candidate gets one dense LM (uniform scale, yaw, translation; Eq. 11) from its box start on all
  points; the candidate with the smallest one-sided AE (Sec. 4.3) wins; joints stay closed.
* ``"ours"``: gravity-restricted orientations + front and class terms, box frames from the
  dominant vertical planes (an open door tilts the observed box, the body's front and sides do
  not); each top-k candidate is screened with a short two-sided robust LM on a small subsample
  (coarse stage: the 4 yaws of each model compete on data, so the dense fit never starts in a
  half-turn minimum), articulated models through their articulation envelope (an open door or a
  pulled-out drawer does not drag the body). The best ``screen_keep`` get joint estimation at the
  screened pose (``articulation``), the full fit (anisotropic scale) at those joint values with
  the open joints refined together with the pose, and the joints searched again; the winner has
  the smallest two-sided AE at its estimated joint values, lightly weighted by the front and class
  terms. When the winner, a procedural model, leaves its front unexplained, its other front layouts
  (``cad.layouts``) compete too (``layout_search``).

The global physical check of Sec. 4.4 consumes ``ObjectReplacement.candidates`` (ranked backups).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import open3d.core as o3c
import trimesh
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from cad_replacement.cad.feature_types import ModelFeatures
from cad_replacement.cad.layouts import layout_variants, resized_variants
from cad_replacement.cad.library import CadEntry
from cad_replacement.cad.model import CadModel
from recon_core.classes import ClassTable, UnknownClassError
from recon_core.geometry.box import GravityBox

from .alignment import (
    AlignmentError,
    AlignmentProblem,
    ModelGeometry,
    Placement,
    PreparedObservation,
    alignment_error,
    box_start,
    box_start_scale,
    posed_scene,
)
from .articulation import ArticulationResult, estimate_joint_values
from .geometry_cache import GeometryCache, library_store
from .matching import MatchCandidate, candidate_classes, default_class_table, match_candidates, observed_planes
from .observation import ObjectObservation, grown_into_unknown, handle_side
from .replace_config import CadReplacementConfig

EPS = 1e-12


class CadSource(Protocol):
    """What replacement needs from a CAD library (``CadLibrary`` satisfies it)."""

    def candidates(self, class_name: str) -> list[tuple[CadEntry, ModelFeatures]]: ...

    def model(self, entry: CadEntry) -> CadModel: ...


@dataclass
class CandidateResult:
    """One aligned candidate: its matching terms, pose, scale, joint values and errors."""

    match: MatchCandidate
    placement: Placement
    ae: AlignmentError
    score: float
    joint_values: dict[str, float]
    stage: str  # "screen" (short fit only) or "full"
    fit_cost: float
    nfev: int
    articulation: ArticulationResult | None = None

    @property
    def key(self) -> str:
        return self.match.entry.key

    @property
    def class_name(self) -> str:
        return self.match.entry.class_name

    @property
    def pose(self) -> NDArray[np.float64]:
        return self.placement.pose

    @property
    def scale(self) -> NDArray[np.float64]:
        return self.placement.scale

    @property
    def yaw(self) -> float:
        return self.placement.yaw

    @property
    def matching_error(self) -> float:
        return self.match.error


@dataclass
class ObjectReplacement:
    """Result for one entity: ranked candidates (best first), the choice and timings (s)."""

    entity_id: int
    name: str
    class_name: str
    method: str
    candidates: list[CandidateResult]
    chosen: CandidateResult | None
    model: CadModel | None
    articulation: ArticulationResult | None
    hypotheses: int
    scored: int
    timings: dict[str, float] = field(default_factory=dict)
    message: str = ""

    @property
    def pose(self) -> NDArray[np.float64] | None:
        """4x4 model frame -> map of the chosen model (apply ``scale`` in the model frame first)."""
        return None if self.chosen is None else self.chosen.pose

    @property
    def scale(self) -> NDArray[np.float64] | None:
        return None if self.chosen is None else self.chosen.scale

    @property
    def joint_values(self) -> dict[str, float]:
        return {} if self.chosen is None else dict(self.chosen.joint_values)

    @property
    def scaled_model(self) -> CadModel | None:
        """The chosen model with its fitted scale applied (use with ``pose`` and ``joint_values``)."""
        if self.model is None or self.chosen is None:
            return None
        return self.model.scaled(self.chosen.scale)


def _posed_samples(
    geom: ModelGeometry, scaled: CadModel, placement: Placement, values: dict[str, float]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The model's surface samples and normals in the map at a scaled, articulated placement.

    A sample in its (unscaled) link frame goes to the closed model frame, is scaled, goes into the
    scaled model's link frame and out again at the joint values: ``P'(q) P'(0)^-1 S P(0) p``.
    """
    names = geom.link_names
    p0 = geom.model.link_poses()
    p1 = scaled.link_poses()
    pq = scaled.link_poses(values)
    s = placement.scale
    # Per link: affine map M_l = P'(q) P'(0)^-1 S P(0) (3x3 + 3), then the rigid placement.
    mats, offs = [], []
    for n in names:
        a = pq[n] @ np.linalg.inv(p1[n]) @ np.diag(np.append(s, 1.0)) @ p0[n]
        mats.append(a[:3, :3])
        offs.append(a[:3, 3])
    m = np.stack(mats)[geom.sample_links]
    o = np.stack(offs)[geom.sample_links]
    pts_model = np.einsum("nij,nj->ni", m, geom.link_samples) + o
    inv_t = np.linalg.inv(m).transpose(0, 2, 1)
    nrm_model = np.einsum("nij,nj->ni", inv_t, geom.link_normals)
    pts = pts_model @ placement.rotation.T + placement.translation
    nrm = nrm_model @ placement.rotation.T
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), EPS)
    return pts, nrm


def _final_error(
    prepared: PreparedObservation,
    geom: ModelGeometry,
    placement: Placement,
    values: dict[str, float],
    cfg: CadReplacementConfig,
    scaled: CadModel | None = None,
) -> AlignmentError:
    """AE of a candidate at its scaled, articulated configuration (exact geometry).

    Self-visibility is that of the articulated configuration: with a door open, the inside of the
    carcass and the door's inner face can be seen (and must then be explained by the points).
    """
    scaled = scaled if scaled is not None else geom.bare_model.scaled(placement.scale)
    rigid = Placement(placement.rotation, placement.translation, np.ones(3))
    scene = posed_scene(scaled.mesh(values), rigid)
    pts, nrm = _posed_samples(geom, scaled, placement, values)
    area = geom.sample_area * float(np.prod(placement.scale)) ** (2.0 / 3.0)
    self_visible = geom.articulated(values).self_visible if values else geom.self_visible
    return alignment_error(prepared, scene, pts, nrm, self_visible, cfg, area)


def replace_object(
    observation: ObjectObservation,
    library: CadSource,
    config: CadReplacementConfig | None = None,
    *,
    cache: GeometryCache | None = None,
    class_table: ClassTable | None = None,
) -> ObjectReplacement:
    """Match, align, articulate and select a CAD model for one observed entity.

    ``cache`` (a ``GeometryCache`` over ``library.model``) should be shared across the objects of
    a scene: models and their raycasting scenes are then built once. Observations are validated on
    construction (``ObservationError``); an entity whose classes have no CAD model returns a result
    with ``chosen=None`` and a message.
    """
    cfg = config or CadReplacementConfig()
    if cfg.method == "ours" and _articulated(observation.class_name, class_table):
        # Doors and drawers show where the front is (their handles, a part open): where that was observed it
        # beats the context's hint from free space, which names either free side of a corner (issue 23).
        seen = _observed_front(observation)
        if seen is not None:
            observation = dataclasses.replace(observation, front_hint=seen)
    cache = cache if cache is not None else GeometryCache(library.model, samples=cfg.ae_model_samples,
                                                                   store=library_store(library))
    timings: dict[str, float] = {}
    t_all = time.perf_counter()
    obs = observation

    t = time.perf_counter()
    prepared = PreparedObservation.build(obs, cfg)
    planes = observed_planes(obs, cfg)
    timings["prepare"] = time.perf_counter() - t

    t = time.perf_counter()
    # Both methods retrieve the observed class plus its interchangeable classes (ours pays a class term).
    classes = candidate_classes(obs.class_name, class_table)
    pool: list[tuple[CadEntry, ModelFeatures]] = []
    for c in classes:
        pool.extend(library.candidates(c))
    match = match_candidates(obs, pool, cfg, planes=planes)
    own = [(e, f) for e, f in pool if e.class_name == obs.class_name]
    if cfg.method == "ours" and cfg.detected_class_fit and own and len(own) < len(pool) \
            and not any(m.entry.class_name == obs.class_name for m in match.candidates):
        # The top-k holds only other classes' orientations (a chair's partial box ranks sofa models
        # first): the detected class's best orientations join, so the acceptance step's class margin
        # compares against a fitted model of the detected class (``detected_class_fit``).
        extra = match_candidates(obs, own, dataclasses.replace(cfg, top_k=2), planes=planes)
        match.candidates.extend(extra.candidates)
    timings["match"] = time.perf_counter() - t
    base = ObjectReplacement(
        obs.entity_id, obs.name, obs.class_name, cfg.method, [], None, None, None, match.hypotheses, match.scored,
        timings,
    )
    if not match.candidates:
        base.message = f"no CAD model for classes {classes}"
        timings["total"] = time.perf_counter() - t_all
        return base

    if cfg.method == "paper":
        results = _align_paper(obs, prepared, match.candidates, cache, cfg, timings)
    else:
        table = class_table or default_class_table()
        round_classes = frozenset(c for c in classes if c in table.names and table.by_name(c).round)
        results = _align_ours(obs, prepared, match.candidates, cache, cfg, timings, round_classes)
    results.sort(key=lambda r: (r.stage != "full", r.score))
    chosen = results[0] if results else None
    base.candidates = results
    base.chosen = chosen
    if chosen is not None:
        base.model = cache.get(chosen.match.entry).model
        base.articulation = chosen.articulation
    timings["total"] = time.perf_counter() - t_all
    return base


def _observed_front(obs: ObjectObservation) -> NDArray[np.float64] | None:
    """``observation.handle_side`` of the observed mesh (None without one: a handle is a few of the
    observation's points, too few to tell it from a door's edge)."""
    if obs.mesh is None or len(obs.mesh.faces) == 0:
        return None
    return handle_side(obs.mesh, obs.gravity_box, obs.neighbours)


def _articulated(class_name: str, table: ClassTable | None) -> bool:
    try:
        return (table or default_class_table()).by_name(class_name).category == "articulated"
    except UnknownClassError:
        return False


#: A part counts as open (``_front_unexplained``) beyond this angle (revolute) or shift (prismatic).
LAYOUT_OPEN_ANGLE = np.radians(5.0)
LAYOUT_OPEN_SHIFT = 0.02

#: Joint changes below which another refit round is not worth it (rad for revolute, m for prismatic).
REFIT_ANGLE = np.radians(2.0)
REFIT_SHIFT = 0.01


def _joints_moved(model: CadModel, before: dict[str, float], after: dict[str, float]) -> bool:
    """Whether any joint value changed enough to refit the pose at the new values."""
    for j in model.movable_joints:
        tol = REFIT_SHIFT if j.type == "prismatic" else REFIT_ANGLE
        if abs(after.get(j.name, 0.0) - before.get(j.name, 0.0)) > tol:
            return True
    return False


def _pose_moved(prob: AlignmentProblem, x0: NDArray[np.float64], x1: NDArray[np.float64]) -> bool:
    """Whether a fit moved the model by more than ``REFIT_SHIFT`` or turned it by ``REFIT_ANGLE``."""
    p0, p1 = prob.placement(x0), prob.placement(x1)
    turn = abs((p1.yaw - p0.yaw + np.pi) % (2.0 * np.pi) - np.pi)
    return bool(turn > REFIT_ANGLE or np.linalg.norm(p1.translation - p0.translation) > REFIT_SHIFT)


#: A screening start: (start score, candidate, its fit problem, start parameters).
_Start = tuple[float, MatchCandidate, AlignmentProblem, NDArray[np.float64]]


def _front_cue_fitted(starts: list[_Start], slots: int) -> list[_Start]:
    """``starts`` (sorted by start score) with the best start of the orientation the front cue names
    moved into the last of the ``slots`` short fits when no start of that orientation holds a slot.

    A box start centres the model in the observed box whichever way it faces, so front and back
    start equally displaced; an observation that reaches beyond the object's front (clutter before a
    screen, the fringe of the desk) shifts the right orientation's start furthest from its surface.
    Ranked on start scores alone, every short fit can go to the back-to-front orientation of some
    model (a monitor turned 180 degrees, issue 22). The cue's orientation then still gets one short
    fit, and the full fit's AE, with the selection factor, decides. No extra fit is spent.
    """
    if len(starts) <= slots or slots < 1:
        return starts
    fronts = np.array([it[1].d_front for it in starts])
    best_front = float(fronts.min())
    if not float(fronts.max()) > best_front + 1e-9:  # no cue, or every start agrees with it
        return starts
    named = np.flatnonzero(fronts <= best_front + 1e-9)
    if named[0] < slots:
        return starts
    out = list(starts)
    out.insert(slots - 1, out.pop(int(named[0])))
    return out


def _selection_factor(m: MatchCandidate, cfg: CadReplacementConfig) -> float:
    return (1.0 + cfg.front_ae_factor * m.d_front) * (1.0 + cfg.class_ae_factor * m.d_class)


#: Ours: a fitted candidate's score grows by this factor times its scale distortion (the largest
#: deviation of a log axis scale from their mean): a model that fits only stretched 1.7x along one axis
#: and squeezed 0.7x along another is the wrong model or turned sideways (issue 23: a two-drawer cabinet
#: turned 90 degrees, stretched over a two-door one's depth, beat the right orientation by its closed
#: drawers' AE and a front hint from the corner's other free side).
DISTORTION_FACTOR = 0.5


def _distortion_factor(scale: NDArray[np.float64]) -> float:
    logs = np.log(np.maximum(np.asarray(scale, dtype=np.float64), EPS))
    return 1.0 + DISTORTION_FACTOR * float(np.max(np.abs(logs - logs.mean())))


#: An observation whose bottom face (points with normals within 25 deg of straight down, at least
#: ``SEEN_BOTTOM_SHARE`` of the points, within ``SEEN_BOTTOM_BAND`` of the lowest percentile) lies more
#: than ``SEEN_BOTTOM_GAP`` (m) above its support plane had its bottom seen: the model stands there (the
#: face's median height), not on the plane. A book lying in a drawer whose support plane came 9 mm low was
#: stretched 1.46x in its 2 cm thickness to reach it. A mapped object in contact with its support never
#: shows its bottom face.
SEEN_BOTTOM_GAP = 0.002
SEEN_BOTTOM_BAND = 0.01
SEEN_BOTTOM_SHARE = 0.02
#: ... and no more than ``SEEN_BOTTOM_BELOW_SHARE`` of the points lie ``SEEN_BOTTOM_BELOW`` (m) below the
#: face: a cabinet's underside on 10 cm legs (0.9 % of its points lower) is not where it stands.
SEEN_BOTTOM_BELOW = 0.02
SEEN_BOTTOM_BELOW_SHARE = 0.002


def seen_bottom(obs: ObjectObservation) -> float:
    """Where the model's bottom goes (``ObjectObservation.bottom_z``) unless its bottom face was seen above it."""
    bottom = obs.bottom_z
    if obs.normals is None or obs.support_z is None or len(obs.points) == 0:
        return bottom
    z = obs.points[:, 2]
    face = (z <= float(np.percentile(z, 1.0)) + SEEN_BOTTOM_BAND) & (obs.normals[:, 2] < -np.cos(np.radians(25.0)))
    if float(np.mean(face)) < SEEN_BOTTOM_SHARE:
        return bottom
    level = float(np.median(z[face]))
    if float(np.mean(z < level - SEEN_BOTTOM_BELOW)) > SEEN_BOTTOM_BELOW_SHARE:
        return bottom  # legs or a plinth reach lower: the face is a carcass's underside, not the bottom
    return level if level - bottom > SEEN_BOTTOM_GAP else bottom


def _align_ours(
    obs: ObjectObservation,
    prepared: PreparedObservation,
    matches: Sequence[MatchCandidate],
    cache: GeometryCache,
    cfg: CadReplacementConfig,
    timings: dict[str, float],
    round_classes: frozenset[str] = frozenset(),
) -> list[CandidateResult]:
    bottom = seen_bottom(obs)
    height = max(obs.gravity_box.z_max - bottom, 1e-3)

    def round_weight(m: MatchCandidate) -> float:
        return cfg.round_weight if m.entry.class_name in round_classes else 0.0

    def grown_frame(m: MatchCandidate, geom: ModelGeometry) -> GravityBox:
        """The candidate's box frame grown into unknown space towards the model's proportions
        (``grown_into_unknown``): the start of a half-seen object is not its seen half."""
        room = obs.room(m.frame)
        if not np.any(room > 0.0):
            return m.frame
        along = np.abs(m.box_rotation) @ np.asarray(geom.size, dtype=np.float64)  # model extents on the box axes
        return grown_into_unknown(m.frame, room, along * (height / max(float(along[2]), 1e-9)))

    # Coarse stage 1: every top-k candidate (all yaws of all models) is scored at its box start.
    t = time.perf_counter()
    starts: list[_Start] = []
    geoms: dict[str, ModelGeometry] = {}
    for m in matches:
        geom = geoms.get(m.entry.key) or cache.get(m.entry)
        geoms[m.entry.key] = geom
        prob = AlignmentProblem(
            geom, m.rotation, bottom, prepared.screen_points, cfg, prepared=prepared,
            point_normals=prepared.screen_normals,
            anisotropy_weight=cfg.anisotropy_weight, height_target=height, height_weight=cfg.height_weight,
            model_samples=max(60, cfg.screen_points), envelope=True, face_reach=cfg.fit_face_reach,
            round_weight=round_weight(m),
        )
        x0 = prob.start(*box_start(grown_frame(m, geom), geom, m.box_rotation, bottom))
        starts.append((prob.score(x0) * _selection_factor(m, cfg), m, prob, x0))
    starts.sort(key=lambda it: it[0])
    starts = _front_cue_fitted(starts, cfg.screen_fits)
    timings["screen_start"] = time.perf_counter() - t
    # Coarse stage 2: a short robust LM on the subsample for the best starts.
    t = time.perf_counter()
    screened: list[tuple[float, MatchCandidate, NDArray[np.float64], float, int]] = []
    per_model: dict[str, int] = {}
    fitted = 0
    for score0, m, prob, x0 in starts:
        # Diversity: at most two orientations of one model get the short fit (a round cup's four
        # equivalent yaws would otherwise fill every slot).
        if fitted >= cfg.screen_fits or per_model.get(m.entry.key, 0) >= 2:
            screened.append((score0 * 10.0, m, x0, 0.0, 1))  # never fitted: ranked behind the fitted ones
            continue
        per_model[m.entry.key] = per_model.get(m.entry.key, 0) + 1
        fitted += 1
        x, cost, nfev = prob.solve(x0, cfg.screen_max_nfev)
        screened.append((prob.score(x) * _selection_factor(m, cfg), m, x, cost, nfev))
    timings["screen"] = time.perf_counter() - t
    screened.sort(key=lambda it: it[0])

    t = time.perf_counter()
    fitter = _FullFit(prepared, cfg, bottom, height, round_weight)
    results: list[CandidateResult] = []
    full_count: dict[str, int] = {}
    screened_x: dict[int, NDArray[np.float64]] = {}
    for score, m, x, cost, nfev in screened:
        geom = geoms[m.entry.key]
        # The full fit compares models; at most two orientations of one model (front/back of a
        # box-like cabinet can be close in screening and are settled by the full two-sided AE).
        if sum(full_count.values()) >= cfg.screen_keep or full_count.get(m.entry.key, 0) >= 2:
            prob = AlignmentProblem(geom, m.rotation, bottom, prepared.screen_points, cfg)
            pl = prob.placement(x)
            nan_ae = AlignmentError(float(score), float(score), 0.0, 0.0)
            results.append(CandidateResult(m, pl, nan_ae, float(score) * 10.0, {}, "screen", cost, nfev))
            continue
        full_count[m.entry.key] = full_count.get(m.entry.key, 0) + 1
        screened_x[id(m)] = x
        results.append(fitter.fit(m, geom, x, cost, nfev))
    if cfg.detected_class_fit and not any(r.stage == "full" and r.class_name == obs.class_name for r in results):
        # Only other classes' models reached the full fit (a chair's partial box ranks sofa orientations
        # first): the detected class's best screened candidate gets one too, so the class margin of the
        # acceptance step compares two fitted models rather than a fitted one against nothing.
        for _score, m, x, cost, nfev in screened:
            if m.entry.class_name == obs.class_name:
                screened_x[id(m)] = x
                results = [r for r in results if r.match is not m]
                results.append(fitter.fit(m, geoms[m.entry.key], x, cost, nfev))
                break
    if cfg.layout_search:
        results.extend(_layout_search(results, screened_x, cache, fitter, cfg))
    timings["align"] = time.perf_counter() - t - fitter.t_art
    timings["articulation"] = fitter.t_art
    return results


class _FullFit:
    """The full fit of one screened candidate (articulation, anisotropic scale, final AE).

    Articulated models: screening fitted the body through the articulation envelope (open doors
    and pulled-out drawers neither drag it nor count as clutter). The joints are estimated at the
    screened pose (1-D searches, ``articulation``); the full fit then runs against the model at
    those joint values (exact configuration: the door's points and the inside it uncovers count)
    with the open joints' values as parameters too (pose and joints refined together), and the
    joints are searched again from the refined pose; while that search moves them, the joint fit
    is repeated (``refine_rounds``). Rigid models: one fit, Eq. (11) with dense residuals.
    """

    def __init__(self, prepared: PreparedObservation, cfg: CadReplacementConfig, bottom: float, height: float,
                 round_weight: Callable[[MatchCandidate], float]) -> None:
        self.prepared, self.cfg, self.bottom, self.height = prepared, cfg, bottom, height
        self.round_weight = round_weight
        self.t_art = 0.0

    def _at_screened_pose(self, m: MatchCandidate, geom: ModelGeometry, x: NDArray[np.float64]
                          ) -> tuple[Placement, CadModel, dict[str, float]]:
        """(placement, scaled model, joint values estimated there) at the screened pose ``x`` (no LM)."""
        pl = AlignmentProblem(geom, m.rotation, self.bottom, self.prepared.fit_points, self.cfg).placement(x)
        scaled = geom.bare_model.scaled(pl.scale)
        values: dict[str, float] = {}
        if geom.model.movable_joints:
            ta = time.perf_counter()
            values = estimate_joint_values(self.prepared.fit_points, scaled, pl.pose, self.cfg).values
            self.t_art += time.perf_counter() - ta
        return pl, scaled, values

    def quick_error(self, m: MatchCandidate, geom: ModelGeometry, x: NDArray[np.float64]) -> float:
        """AE at the screened pose ``x`` with joint values estimated there (no LM): ranks variants."""
        pl, scaled, values = self._at_screened_pose(m, geom, x)
        return _final_error(self.prepared, geom, pl, values, self.cfg, scaled).ae

    def quick_front_error(self, m: MatchCandidate, geom: ModelGeometry, x: NDArray[np.float64]) -> float:
        """``front_error`` at the screened pose ``x`` with joint values estimated there (no LM)."""
        pl, scaled, values = self._at_screened_pose(m, geom, x)
        return self.front_error(geom, pl, values, scaled)

    def front_error(self, geom: ModelGeometry, placement: Placement, values: dict[str, float],
                    scaled: CadModel | None = None) -> float:
        """``front_error`` against this observation."""
        return front_error(self.prepared, geom, placement, values, scaled)

    def fit(self, m: MatchCandidate, geom: ModelGeometry, x: NDArray[np.float64], cost: float,
            nfev: int) -> CandidateResult:
        """The full fit from the screened parameters ``x``; a model with drawers whose fitted carcass reaches
        beyond the observed sides at the front (``SIDE_FRONT_MIN``) is fitted once more from a carcass that
        much shorter, and the better score is kept.

        Drawers pulled out make the observed box deeper than the carcass: a fit that starts from it
        stretches the carcass over them and reads them closed (its front panel lies where the drawers'
        fronts are), and no joint search starts an open drawer from there. The carcass's side panels
        still end where the carcass does (issue 23: bench-office's cabinet, drawers 10-22 cm out, was
        fitted facing its handles 11 cm too deep at AE 33 mm, and sideways with its drawers closed won)."""
        r = self._fit(m, geom, x, cost, nfev)
        if not any(j.type == "prismatic" for j in geom.model.movable_joints):
            return r
        delta = _front_beyond_sides(self.prepared, geom, r.placement, r.joint_values)
        if not delta > SIDE_FRONT_MIN:  # NaN: the sides are not seen
            return r
        pl = r.placement
        depth = float(pl.scale[0] * geom.size[0])
        x2 = x.copy()
        off = 1 if len(x) < 6 else 3  # uniform scale: (log s, dyaw, tx, ty); else (log sx, log sy, log sz, ...)
        if off == 3:
            x2[0] = x[0] + np.log(max(depth - delta, 0.5 * depth) / depth)
        shift = -0.5 * delta * pl.rotation[:2, 0]  # model +x is the front
        x2[off + 1] += shift[0]
        x2[off + 2] += shift[1]
        r2 = self._fit(m, geom, x2, cost, nfev)
        return r2 if r2.score < r.score else r

    def _fit(self, m: MatchCandidate, geom: ModelGeometry, x: NDArray[np.float64], cost: float,
             nfev: int) -> CandidateResult:
        prepared, cfg, bottom = self.prepared, self.cfg, self.bottom
        art = None
        values: dict[str, float] = {}
        if geom.model.movable_joints:
            ta = time.perf_counter()
            pl0 = AlignmentProblem(geom, m.rotation, bottom, prepared.fit_points, cfg).placement(x)
            art = estimate_joint_values(prepared.fit_points, geom.bare_model.scaled(pl0.scale), pl0.pose, cfg)
            self.t_art += time.perf_counter() - ta
            values = art.values
        nfev2 = 0
        max_nfev = cfg.align_max_nfev
        n_base = len(x)
        for _ in range(1 + (cfg.refine_rounds if art is not None else 0)):
            open_joints = [j for j in geom.model.movable_joints if abs(values[j.name] - j.zero_value) > 1e-9]
            prob = AlignmentProblem(
                geom.articulated(values) if values else geom, m.rotation, bottom, prepared.fit_points, cfg,
                prepared=prepared, anisotropy_weight=cfg.anisotropy_weight, height_target=self.height,
                height_weight=cfg.height_weight, model_samples=cfg.align_model_samples,
                face_reach=cfg.fit_face_reach, point_normals=prepared.fit_normals, joints=open_joints,
                round_weight=self.round_weight(m),
            )
            x_start = x[:n_base].copy()
            xj, cost2, nfev3 = prob.solve(np.r_[x_start, np.zeros(len(open_joints))], max_nfev)
            x = xj[:n_base]
            nfev2 += nfev3
            max_nfev = cfg.refine_max_nfev
            pl = prob.placement(x)
            scaled = geom.bare_model.scaled(pl.scale)
            if art is None:
                break
            q_fit = prob.joint_values(xj)
            ta = time.perf_counter()
            art = estimate_joint_values(prepared.fit_points, scaled, pl.pose, cfg)
            self.t_art += time.perf_counter() - ta
            values = art.values
            # Another round when the joints moved, or, with parts open (their inside and their own
            # occlusions make the choice pose-dependent), when the pose moved away from where the
            # fit chose the CAD samples the observation could have seen (fixed per fit).
            if _joints_moved(scaled, q_fit, values):
                continue
            if not (open_joints and _pose_moved(prob, x_start, x)):
                break
        values = art.values if art is not None else scaled.zero_configuration()
        ae = _final_error(prepared, geom, pl, values, cfg, scaled)
        score2 = ae.ae * _selection_factor(m, cfg) * _distortion_factor(pl.scale)
        return CandidateResult(m, pl, ae, score2, values, "full", cost2, nfev + nfev2, art)


#: Front layouts are told apart by their handles (``front_error``): a door's bar stands by its opening edge,
#: a drawer's across its middle, one per front, so where the handles are says which fronts there are and
#: which side a door opens. The whole-object AE cannot tell closed fronts apart: it also scores what lies
#: behind them (a drawer's box, a shelf, the board over a row of doors where the observation reaches
#: inside), which the carcass of another model gets wrong whatever its front (on a cabinet with two doors
#: under two drawers, a three-row chest of drawers on the library's carcass scored 5.7 mm against 8.5 mm
#: for the right layout; issue 23), and the fronts' planes of two models lie a few mm apart.
#: Handles: surface within ``FRONT_SLAB`` (m) behind the closed model's front and more than
#: ``HANDLE_PROUD`` (m) before the front's plane (the median depth of the front-facing surface there).
FRONT_SLAB = 0.08
HANDLE_PROUD = 0.008
#: A handle point is explained by one of the other side within ``HANDLE_REACH`` (m) in the front's plane.
HANDLE_REACH = 0.03
#: A variant is fitted only when its ``front_error`` is at most this (on average half of each side's handle
#: points near one of the other's); the right layouts of the protocol's closed fronts scored 0-0.25, the
#: others 1.1-2.
FRONT_GOOD = 1.0
#: ... and the observation must show at least this many handle points (else NaN: no handles seen).
HANDLE_MIN_POINTS = 20
#: Surface samples drawn on the posed model for its handles.
HANDLE_SAMPLES = 4000


#: A side panel's outer face: within this (m) of the outermost surface facing that side.
SIDE_SLAB = 0.008
#: A fitted carcass whose sides reach this far (m) beyond the observed sides' front is refitted shorter.
SIDE_FRONT_MIN = 0.05


def _side_front(local: NDArray[np.float64], normals_local: NDArray[np.float64]) -> float:
    """How far forward (model x) the outer faces of the two sides reach (model frame, scaled units); NaN
    when neither side shows enough of them."""
    fronts = []
    for sign in (1.0, -1.0):
        facing = sign * normals_local[:, 1] > 0.9
        if np.count_nonzero(facing) < 20:
            continue
        outer = sign * local[facing, 1]
        sel = outer > outer.max() - SIDE_SLAB
        if np.count_nonzero(sel) < 10:
            continue
        fronts.append(float(np.percentile(local[facing][sel, 0], 99)))
    return max(fronts) if fronts else float("nan")


def _front_beyond_sides(prepared: PreparedObservation, geom: ModelGeometry, placement: Placement,
                        values: dict[str, float]) -> float:
    """How far the fitted model's side panels reach beyond the observed ones at the front (m)."""
    if prepared.fit_normals is None:
        return float("nan")
    local = (prepared.fit_points - placement.translation) @ placement.rotation
    obs = _side_front(local, prepared.fit_normals @ placement.rotation)
    g = geom.articulated(values) if values else geom
    mod = _side_front(g.samples * placement.scale, g.normals / placement.scale)
    return mod - obs


def _front_samples(mesh: trimesh.Trimesh, placement: Placement, x_front: float,
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``HANDLE_SAMPLES`` surface samples (map frame) and normals of the faces of a map-frame mesh within
    ``FRONT_SLAB`` behind the front or before it (model frame of ``placement``)."""
    centres = (np.asarray(mesh.triangles_center) - placement.translation) @ placement.rotation
    keep = np.flatnonzero(centres[:, 0] > x_front - FRONT_SLAB)
    if len(keep) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    part = trimesh.Trimesh(mesh.vertices, mesh.faces[keep], process=False)
    if part.area <= 0.0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    samples, faces = trimesh.sample.sample_surface(part, HANDLE_SAMPLES, seed=0)
    return np.asarray(samples), np.asarray(part.face_normals[faces])


def _handles(points: NDArray[np.float64], normals: NDArray[np.float64], placement: Placement,
             x_front: float) -> NDArray[np.float64]:
    """(y, z) in the model frame of the points proud of the front's plane (see ``FRONT_SLAB``)."""
    if len(points) == 0:
        return np.zeros((0, 2))
    local = (points - placement.translation) @ placement.rotation
    slab = local[:, 0] > x_front - FRONT_SLAB
    facing = slab & (normals @ placement.rotation[:, 0] > 0.9)
    if not facing.any():
        return np.zeros((0, 2))
    plane = float(np.median(local[facing, 0]))
    return local[slab & (local[:, 0] > plane + HANDLE_PROUD)][:, 1:]


def front_error(prepared: PreparedObservation, geom: ModelGeometry, placement: Placement,
                values: dict[str, float], scaled: CadModel | None = None) -> float:
    """How badly the model's handles and the observed ones miss each other (0 = every handle point of each
    has one of the other within ``HANDLE_REACH`` in the front's plane, 2 = none has): the share of the
    observed handle points without a model handle point near, plus the share of the model's without an
    observed one. Both surfaces are sampled densely at the front (the observation's mesh; without one, its
    points). NaN when the observation shows no handles there (fewer than ``HANDLE_MIN_POINTS`` points)."""
    obs = prepared.obs
    scaled = scaled if scaled is not None else geom.bare_model.scaled(placement.scale)
    x_front = float(scaled.mesh().bounds[1, 0])
    if obs.mesh is not None and len(obs.mesh.faces):
        seen = _handles(*_front_samples(obs.mesh, placement, x_front), placement, x_front)
    elif obs.normals is not None:
        seen = _handles(obs.points, obs.normals, placement, x_front)
    else:
        return float("nan")
    if len(seen) < HANDLE_MIN_POINTS:
        return float("nan")
    rigid = Placement(placement.rotation, placement.translation, np.ones(3))
    mesh = scaled.mesh(values)
    posed = trimesh.Trimesh(rigid.apply(np.asarray(mesh.vertices, dtype=np.float64)), mesh.faces, process=False)
    model = _handles(*_front_samples(posed, placement, x_front), placement, x_front)
    if len(model) == 0:
        return 2.0
    d_seen, _ = cKDTree(model).query(seen)
    d_model, _ = cKDTree(seen).query(model)
    return float(np.mean(d_seen > HANDLE_REACH) + np.mean(d_model > HANDLE_REACH))


def _parts_open(best: CandidateResult, geom: ModelGeometry) -> bool:
    """Whether the candidate has a door or drawer open (beyond ``LAYOUT_OPEN_ANGLE`` / ``LAYOUT_OPEN_SHIFT``)."""
    for j in geom.model.movable_joints:
        tol = LAYOUT_OPEN_ANGLE if j.type == "revolute" else LAYOUT_OPEN_SHIFT
        if abs(best.joint_values.get(j.name, j.zero_value) - j.zero_value) > tol:
            return True
    return False


def _front_unexplained(best: CandidateResult, geom: ModelGeometry, prepared: PreparedObservation,
                       cfg: CadReplacementConfig) -> bool:
    """Whether the best candidate leaves its front unexplained: a part found open, or at least
    ``layout_outlier_share`` of the points farther than ``layout_outlier_m`` from its surface.

    A closed front hardly tells layouts apart (a drawer's gaps against a door's at the map's
    resolution), and searching it only lets noise pick another layout; an open part, or points
    the model cannot reach, is where the layout shows."""
    scaled = geom.bare_model.scaled(best.placement.scale)
    for j in scaled.movable_joints:
        tol = LAYOUT_OPEN_ANGLE if j.type == "revolute" else LAYOUT_OPEN_SHIFT
        if abs(best.joint_values.get(j.name, j.zero_value) - j.zero_value) > tol:
            return True
    rigid = Placement(best.placement.rotation, best.placement.translation, np.ones(3))
    scene = posed_scene(scaled.mesh(best.joint_values), rigid)
    d = scene.compute_distance(o3c.Tensor(prepared.fit_points.astype(np.float32))).numpy()
    return bool(np.mean(d > cfg.layout_outlier_m) >= cfg.layout_outlier_share)


#: A fitted candidate whose two-sided AE is at most this share of the observed box diagonal (clipped to
#: ``LAYOUT_EXPLAINED_AE``) and that leaves fewer than ``layout_outlier_share`` of the points unexplained
#: already explains the observation: no front layout may replace it (issue 23: an in-library cabinet with
#: three joints became another model's five-drawer layout turned sideways).
LAYOUT_EXPLAINED_REL = 0.005
LAYOUT_EXPLAINED_AE = (0.003, 0.008)
#: The layouts of the best fitted candidate of this many distinct orientations are searched: when the
#: library holds no model with the object's front, the best candidate may be a model turned sideways with
#: its drawers pulled out to cover the body's depth, while the right orientation of the same carcass with
#: the right front explains it (a two-door cabinet fitted as a two-drawer one turned 90 degrees).
LAYOUT_ORIENTATIONS = 2
#: ... when the other orientation's best candidate scores within this factor of the best.
LAYOUT_RIVAL_SCORE = 1.5
#: Two candidates are distinct orientations when their yaws differ by more than this (rad); a variant whose
#: full fit turns it farther than this from the pose it started at is dropped (a new front never turns the
#: carcass it was found on).
LAYOUT_YAW_TOL = np.radians(20.0)


def _yaw_gap(a: float, b: float) -> float:
    return float(abs((a - b + np.pi) % (2.0 * np.pi) - np.pi))


def _explains(r: CandidateResult, geom: ModelGeometry, prepared: PreparedObservation,
              cfg: CadReplacementConfig) -> bool:
    """Whether a fully fitted candidate already explains the observation (no front to search for)."""
    diagonal = float(np.linalg.norm(np.asarray(prepared.obs.gravity_box.size, dtype=np.float64)))
    limit = float(np.clip(LAYOUT_EXPLAINED_REL * diagonal, *LAYOUT_EXPLAINED_AE))
    if not (np.isfinite(r.ae.ae) and r.ae.ae <= limit and r.ae.ae_points <= limit):
        return False
    scaled = geom.bare_model.scaled(r.placement.scale)
    rigid = Placement(r.placement.rotation, r.placement.translation, np.ones(3))
    scene = posed_scene(scaled.mesh(r.joint_values), rigid)
    d = scene.compute_distance(o3c.Tensor(prepared.fit_points.astype(np.float32))).numpy()
    return bool(np.mean(d > cfg.layout_outlier_m) < cfg.layout_outlier_share)


def _layout_search(results: Sequence[CandidateResult], screened_x: dict[int, NDArray[np.float64]],
                   cache: GeometryCache, fitter: _FullFit, cfg: CadReplacementConfig) -> list[CandidateResult]:
    """Full fits of the best candidates' most promising other front layouts (``cad.layouts``).

    Only procedural models of classes with layouts have variants, and they are tried only when
    no fitted candidate already explains the observation (``_explains``: a library model that does is
    never replaced) and the best candidate does not explain the front (``_front_unexplained``). The
    best fitted candidates of the ``LAYOUT_ORIENTATIONS`` best distinct orientations are searched (the
    second only when it scores within ``LAYOUT_RIVAL_SCORE`` of the best and leaves its front
    unexplained too). Each variant keeps the model's carcass, so the screened pose (fitted
    through the articulation envelope, where an open door does not stretch the body) is its start:
    the variants are ranked by their AE there, at joint values estimated there (no LM), and the best
    ``layout_fits`` get the full fit, which must keep the orientation it started in
    (``LAYOUT_YAW_TOL``). A variant must beat the library's own model by ``layout_margin``."""
    full = sorted((r for r in results if r.stage == "full"), key=lambda r: r.score)
    if not full:
        return []
    if any(_explains(r, cache.get(r.match.entry), fitter.prepared, cfg) for r in full[:cfg.screen_keep]):
        return []
    if not _front_unexplained(full[0], cache.get(full[0].match.entry), fitter.prepared, cfg):
        return []
    bases: list[CandidateResult] = []
    for r in full:
        if len(bases) >= LAYOUT_ORIENTATIONS or r.score > LAYOUT_RIVAL_SCORE * full[0].score:
            break
        if all(_yaw_gap(r.yaw, b.yaw) > LAYOUT_YAW_TOL for b in bases):
            bases.append(r)
    searched = []
    for best in bases:
        x = screened_x.get(id(best.match))
        layouts = layout_variants(best.match.entry)
        if x is None or not layouts:
            continue
        if best is not full[0] and not _front_unexplained(best, cache.get(best.match.entry), fitter.prepared, cfg):
            continue
        base_geom = cache.get(best.match.entry)
        variants = [(entry, x) for entry in layouts]
        if len(x) >= 6:  # per-axis scales: a model rebuilt at the fitted width starts at the same size
            width = float(best.placement.scale[1] * base_geom.size[1])
            for entry in resized_variants(best.match.entry, layouts, width):
                xv = x.copy()
                xv[1] += np.log(base_geom.size[1] / cache.get(entry).size[1])
                variants.append((entry, xv))
        searched.append((best, x, variants, base_geom, fitter.quick_front_error(best.match, base_geom, x)))
    # Handles seen at one base's front and not at another's: the latter faces the wrong way (a carcass
    # turned sideways, its drawers pulled out to cover the depth), and no layout of it is the object's.
    handles_seen = any(np.isfinite(it[4]) for it in searched)
    out = []
    for best, _x, variants, base_geom, base_front in searched:
        # A closed front is ranked by its handles (``front_error``); with a part open (its handle turned away,
        # the part's own geometry in view) by the AE, which sees where the open parts are.
        is_open = _parts_open(best, base_geom)
        by_front = bool(np.isfinite(base_front)) and not is_open
        if not np.isfinite(base_front) and (handles_seen or not is_open):
            continue  # no handles in view at this front: nothing tells its layout, or it is not the front
        ranked: list[tuple[float, MatchCandidate, ModelGeometry, NDArray[np.float64]]] = []
        for entry, xv in variants:
            geom = cache.get(entry)
            m = dataclasses.replace(best.match, entry=entry)
            err = fitter.quick_front_error(m, geom, xv) if by_front else fitter.quick_error(m, geom, xv)
            if by_front and not (err < (1.0 - cfg.layout_margin) * base_front and err <= FRONT_GOOD):
                # the library model's own front explains the observed one at least as well, or the variant's
                # handles miss the observed ones as badly (a carcass stretched 1.46x puts every handle elsewhere)
                continue
            ranked.append((err, m, geom, xv))
        ranked.sort(key=lambda it: it[0])
        base_full_front = fitter.front_error(base_geom, best.placement, best.joint_values) \
            if by_front else float("nan")
        for _err, m, geom, xv in ranked[:cfg.layout_fits]:
            r = fitter.fit(m, geom, xv.copy(), 0.0, 0)
            if _yaw_gap(r.yaw, best.yaw) > LAYOUT_YAW_TOL:
                continue
            r.score *= 1.0 + cfg.layout_margin
            if by_front and fitter.front_error(geom, r.placement, r.joint_values) \
                    < (1.0 - cfg.layout_margin) * base_full_front:
                # Same carcass, a front that explains the observed one better: it takes the library model's
                # place in the ranking (the AE also scores what lies behind the front, which the carcass sets).
                r.score = min(r.score, best.score * (1.0 - 1e-3))
            out.append(r)
    return out


def _align_paper(
    obs: ObjectObservation,
    prepared: PreparedObservation,
    matches: Sequence[MatchCandidate],
    cache: GeometryCache,
    cfg: CadReplacementConfig,
    timings: dict[str, float],
) -> list[CandidateResult]:
    bottom = obs.bottom_z
    pts = obs.points
    if len(pts) > cfg.paper_max_points:
        rng = np.random.default_rng(cfg.seed)
        pts = pts[rng.choice(len(pts), cfg.paper_max_points, replace=False)]
    t = time.perf_counter()
    results: list[CandidateResult] = []
    for m in matches:
        geom = cache.get(m.entry)
        prob = AlignmentProblem(geom, m.rotation, bottom, pts, cfg, uniform_scale=True, robust=False, two_sided=False)
        x0 = prob.start(box_start_scale(m.frame, geom, m.box_rotation, bottom, clip=np.inf), m.frame.center[:2])
        x, cost, nfev = prob.solve(x0, cfg.align_max_nfev)
        pl = prob.placement(x)
        values = geom.model.zero_configuration()
        ae = _final_error(prepared, geom, pl, values, cfg)
        # Sec. 4.3: the candidate with the smallest (one-sided) AE is selected.
        results.append(CandidateResult(m, pl, ae, ae.ae_points, values, "full", cost, nfev))
    timings["align"] = time.perf_counter() - t
    timings["articulation"] = 0.0
    return results


__all__ = [
    "CadReplacementConfig", "CadSource", "CandidateResult", "ObjectReplacement", "replace_object", "seen_bottom",
]
