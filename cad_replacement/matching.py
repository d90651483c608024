"""Ranking-based CAD matching (paper Sec. 4.2, Eqs. 7-10): which models, in which orientation.

For one observed entity ``x`` every CAD model ``y`` of its class (and of the classes the class
table marks as interchangeable, ``confusable_with``) is tried in a set of discrete orientations
relative to the observed gravity-aligned box ``B_x``; each oriented candidate gets the Matching
Error

    D(x, y) = w1 d_s + w2 d_pi + w3 d_b  (+ w_front d_front + w_class d_class for "ours"),   (Eq. 7)

with the relative box-size difference d_s (Eq. 8), the plane term d_pi with the optimal plane
assignment found by the Hungarian method and constrained to map supporting planes onto supporting
planes (Eq. 9), and the upright bias d_b = 1 + g.z(y) (Eq. 10). The ``top_k`` lowest survive.

Orientations. The paper discretises into the 24 axis-aligned rotations for every model. Gravity
is known here, so "ours" keeps z up and tries the 4 quarter-turn yaws that align the model's box
axes with the observed box axes; only classes whose policy says they may lie on a side (books,
boxes) get the other axis permutations, and none is ever upside down.

Pruning. d_s, d_b and the front/class terms are computed for all hypotheses at once; they are a
lower bound of D (d_pi >= 0). Hypotheses are scored in increasing bound order and the Hungarian
step stops as soon as the bound cannot beat the current k-th best.
"""

from __future__ import annotations

import functools
import heapq
import itertools
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from cad_replacement.cad.feature_types import ModelFeatures
from cad_replacement.cad.library import CadEntry
from recon_core.classes import ClassTable, load_class_table
from recon_core.errors import UnknownClassError
from recon_core.geometry.box import GravityBox
from recon_core.geometry.plane import SUPPORT_NORMAL_COS
from recon_core.geometry.plane_fit import extract_planes

from .observation import ObjectObservation
from .replace_config import CadReplacementConfig

EPS = 1e-12


@dataclass(frozen=True)
class ClassPolicy:
    """Per-class knowledge matching needs and the class table does not hold.

    ``may_lie_down``: the object is found lying on a side often enough that the non-upright axis
    permutations are worth trying (never upside down). ``front_facing``: the object has a
    functional front (doors, drawers, a seat, a screen) that faces open space, so the front hint
    applies; cups or tables do not.
    """

    may_lie_down: bool = False
    front_facing: bool = True


#: Class policies (data, not scattered ifs); classes missing here get ``DEFAULT_POLICY``.
CLASS_POLICIES: Mapping[str, ClassPolicy] = {
    "book": ClassPolicy(may_lie_down=True, front_facing=False),
    "box": ClassPolicy(may_lie_down=True, front_facing=False),
    "bag": ClassPolicy(may_lie_down=False, front_facing=False),
    "cup": ClassPolicy(may_lie_down=False, front_facing=False),
    "bottle": ClassPolicy(may_lie_down=False, front_facing=False),
    "table": ClassPolicy(may_lie_down=False, front_facing=False),
}
DEFAULT_POLICY = ClassPolicy()


def class_policy(class_name: str) -> ClassPolicy:
    return CLASS_POLICIES.get(class_name, DEFAULT_POLICY)


def _rot_z(angle: float) -> NDArray[np.float64]:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _all_rotations() -> NDArray[np.float64]:
    """The 24 rotations of the cube (signed permutation matrices with det +1)."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            m[np.arange(3), perm] = signs
            if np.linalg.det(m) > 0.5:
                out.append(m)
    return np.array(out)


#: The 24 axis-aligned rotations (paper Sec. 4.2) and the 4 upright quarter turns among them.
ALL_ROTATIONS: NDArray[np.float64] = _all_rotations()
UPRIGHT_ROTATIONS: NDArray[np.float64] = np.array([np.rint(_rot_z(k * 0.5 * np.pi)) for k in range(4)])


#: Upright yaws that stay distinct under a class's symmetry (0: round, 4: quarter turn, 2: half turn).
_DISTINCT_YAWS = {0: 1, 4: 1, 2: 2}


def _class_symmetry(class_name: str) -> int | None:
    try:
        return default_class_table().by_name(class_name).symmetry
    except UnknownClassError:
        return None


def orientation_set(class_name: str, method: str) -> NDArray[np.float64]:
    """Rotations (model frame -> box frame) tried for a class: 24 for the paper, gravity-restricted for ours."""
    if method == "paper":
        return ALL_ROTATIONS
    if class_policy(class_name).may_lie_down:
        return ALL_ROTATIONS[ALL_ROTATIONS[:, 2, 2] > -0.5]  # every permutation except upside down
    # A class whose every instance looks the same after a quarter (half) turn (``symmetry`` in the
    # class table: bottles) needs one (two) of the four yaws: the others fit the same.
    symmetry = _class_symmetry(class_name)
    return UPRIGHT_ROTATIONS[:_DISTINCT_YAWS.get(symmetry, 4) if symmetry is not None else 4]


@dataclass(frozen=True, eq=False)
class MatchCandidate:
    """One oriented CAD candidate: model, rotation into the map and its Matching Error terms.

    ``rotation`` maps the model's canonical frame into the map (``Rz(frame yaw) @ box_rotation``);
    ``box_rotation`` is the discrete orientation relative to ``frame``, the observed box (or, for
    ours, a box aligned with a large vertical plane, see ``candidate_frames``).
    """

    entry: CadEntry
    features: ModelFeatures
    frame: GravityBox
    box_rotation: NDArray[np.float64]
    rotation: NDArray[np.float64]
    d_size: float
    d_plane: float
    d_bias: float
    d_front: float
    d_class: float
    error: float
    assignment: tuple[tuple[int, int], ...] = ()

    @property
    def upright(self) -> bool:
        return bool(self.box_rotation[2, 2] > 0.5)

    @property
    def model_key(self) -> str:
        return self.entry.key


@dataclass
class MatchResult:
    """Ranked candidates (best first) plus bookkeeping of the search."""

    candidates: list[MatchCandidate]
    hypotheses: int
    scored: int
    observed_planes: int
    time_s: float
    timings: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class ObservedPlanes:
    """Observation planes (map frame: ``normals``, ``offsets``, ``areas`` = inlier fractions)."""

    normals: NDArray[np.float64]
    offsets: NDArray[np.float64]
    areas: NDArray[np.float64]

    def in_frame(self, box: GravityBox) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        """Normals, offsets and support flags in a box frame (Eq. 9's T_x^T pi)."""
        rz = _rot_z(box.yaw)
        # Plane n.x + d = 0 with x = c + Rz u  ->  (Rz^T n).u + (d + n.c) = 0.
        n_box = self.normals @ rz
        d_box = self.offsets + self.normals @ box.center
        return n_box, d_box, n_box[:, 2] > SUPPORT_NORMAL_COS


def observed_planes(obs: ObjectObservation, config: CadReplacementConfig) -> ObservedPlanes:
    """RANSAC planes of the observation (Sec. 4.1 settings), map frame."""
    box = obs.gravity_box
    thr = config.plane_distance
    if thr is None:
        thr = min(0.03, 0.02 * float(np.linalg.norm(box.size)))
    thr = max(thr, 1e-3)
    planes = extract_planes(
        obs.points,
        normals=obs.normals,
        distance_threshold=thr,
        iterations=config.plane_iterations,
        min_inlier_fraction=config.plane_min_fraction,
        sample_count=config.plane_samples,
        seed=config.seed,
    )
    if not planes:
        return ObservedPlanes(np.zeros((0, 3)), np.zeros(0), np.zeros(0))
    return ObservedPlanes(
        np.array([p.normal for p in planes]), np.array([p.d for p in planes]), np.array([p.area for p in planes])
    )


def box_in_frame(points: NDArray[np.float64], yaw: float) -> GravityBox:
    """Tight gravity-aligned box of ``points`` whose axes are rotated by ``yaw``."""
    c, s = np.cos(yaw), np.sin(yaw)
    u = points[:, 0] * c + points[:, 1] * s
    v = -points[:, 0] * s + points[:, 1] * c
    lo = np.array([u.min(), v.min(), points[:, 2].min()])
    hi = np.array([u.max(), v.max(), points[:, 2].max()])
    mid = 0.5 * (lo + hi)
    center = np.array([mid[0] * c - mid[1] * s, mid[0] * s + mid[1] * c, mid[2]])
    return GravityBox(center, hi - lo, yaw)


def _plane_yaw_clusters(planes: ObservedPlanes, tol: float) -> list[tuple[float, float]]:
    """(yaw modulo a quarter turn, summed area) of the vertical planes, grouped within ``tol`` (rad).

    Largest area first; a cluster's yaw is the area-weighted mean of its planes' yaws. The front and
    the sides of a body fall into one cluster (perpendicular planes share a yaw modulo a quarter
    turn), so together they outweigh a single open door.
    """
    quarter = 0.5 * np.pi
    vertical = np.flatnonzero(np.abs(planes.normals[:, 2]) < 0.2)
    clusters: list[list[float]] = []  # [reference yaw, sum(area * offset from reference), sum(area)]
    for i in vertical[np.argsort(-planes.areas[vertical])]:
        yaw = float(np.arctan2(planes.normals[i, 1], planes.normals[i, 0]))
        yaw = yaw - quarter * np.round(yaw / quarter)
        area = float(planes.areas[i])
        for c in clusters:
            off = ((yaw - c[0] + 0.5 * quarter) % quarter) - 0.5 * quarter
            if abs(off) <= tol:
                c[1] += area * off
                c[2] += area
                break
        else:
            clusters.append([yaw, 0.0, area])
    out = [(c[0] + c[1] / c[2], c[2]) for c in clusters]
    return sorted(out, key=lambda it: -it[1])


#: A round body's handle (``handle_yaw``): the outline must reach this much beyond the body's radius
#: (m, and as a share of the radius) over at most ``HANDLE_MAX_SPAN`` of the circle.
HANDLE_MIN_REACH = 0.008
HANDLE_MIN_REACH_REL = 0.12
HANDLE_MAX_SPAN = np.radians(100.0)
_HANDLE_BINS = 36


def _circle_fit(xy: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
    """Least-squares circle (Kasa) through 2-D points: centre and radius."""
    a = np.c_[2.0 * xy, np.ones(len(xy))]
    b = (xy ** 2).sum(axis=1)
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    centre = sol[:2]
    return centre, float(np.sqrt(max(sol[2] + centre @ centre, 0.0)))


def handle_yaw(points: NDArray[np.float64]) -> float | None:
    """Direction (yaw, rad) of a handle on a round body (a cup's), or ``None`` when the outline is round.

    The body's axis is a circle fitted to the outline (per angular bin the outermost points, the bins
    that reach farthest left out, refitted once); the handle is the bins whose outermost points reach
    at least ``HANDLE_MIN_REACH`` beyond the body's radius, one contiguous span of at most
    ``HANDLE_MAX_SPAN``; its direction is the mean direction of the points that stick out. The paper's
    box frames align a model with the body's extremes, which a handle does not set (a cup's handle came
    out 34 degrees off, issue 23).
    """
    xy = np.asarray(points, dtype=np.float64)[:, :2]
    if len(xy) < 30:
        return None
    centre, _ = _circle_fit(xy)
    keep = np.ones(len(xy), dtype=bool)
    for _ in range(2):
        d = xy - centre
        ang = np.arctan2(d[:, 1], d[:, 0])
        rad = np.linalg.norm(d, axis=1)
        bins = ((ang + np.pi) / (2.0 * np.pi) * _HANDLE_BINS).astype(int) % _HANDLE_BINS
        outer = np.zeros(_HANDLE_BINS)
        for b in range(_HANDLE_BINS):
            sel = rad[bins == b]
            outer[b] = np.percentile(sel, 95) if len(sel) else np.nan
        filled = outer[np.isfinite(outer)]
        if len(filled) < 0.75 * _HANDLE_BINS:
            return None  # too little of the outline to tell a handle from a missing side
        body = float(np.median(filled))
        reach = max(HANDLE_MIN_REACH, HANDLE_MIN_REACH_REL * body)
        out_bins = np.flatnonzero(np.nan_to_num(outer, nan=0.0) > body + reach)
        keep = ~np.isin(bins, out_bins) & (rad <= body + 0.5 * reach)
        if keep.sum() < 20:
            return None
        rim = keep & (rad >= np.percentile(rad[keep], 60))  # the outer wall, not the inside
        centre, _ = _circle_fit(xy[rim]) if rim.sum() >= 10 else (centre, body)
    if len(out_bins) == 0:
        return None
    span = len(out_bins) * 2.0 * np.pi / _HANDLE_BINS
    mask = np.zeros(_HANDLE_BINS, dtype=bool)
    mask[out_bins] = True
    runs = int(np.sum(mask & ~np.roll(mask, 1)))  # contiguous spans on the circle
    if span > HANDLE_MAX_SPAN or runs != 1:
        return None
    d = xy - centre
    rad = np.linalg.norm(d, axis=1)
    out = rad > body + 0.5 * reach
    if out.sum() < 3:
        return None
    mean = (d[out] / rad[out, None]).mean(axis=0)
    return float(np.arctan2(mean[1], mean[0]))


def _round_class(class_name: str) -> bool:
    try:
        return default_class_table().by_name(class_name).round
    except UnknownClassError:
        return False


def candidate_frames(obs: ObjectObservation, planes: ObservedPlanes, extra: int = 2) -> list[GravityBox]:
    """Box frames whose axes the model axes are aligned to: the observed box, plus (ours) the frames
    of the largest vertical planes.

    The minimal-footprint box is tilted when a door stands open or a drawer is out; the large
    vertical planes (sides, front, back) still show the body's axes. Vertical planes are grouped
    by yaw modulo a quarter turn (within 5 degrees, ``_plane_yaw_clusters``); a group within
    5 degrees of the observed box replaces the box's yaw (fitted planes pin the yaw better than
    the extreme points of a box), the other groups add frames, largest area first. A round class's
    body with a handle (``handle_yaw``) has the handle's frame alone.
    """
    box = obs.gravity_box
    frames = [box]
    if extra <= 0:
        return frames
    tol = np.radians(5.0)
    quarter = 0.5 * np.pi

    def gap(a: float, b: float) -> float:
        return abs(((a - b + 0.5 * quarter) % quarter) - 0.5 * quarter)

    if _round_class(obs.class_name):
        # A round body's box has no meaningful axes; a handle has (model +x is the handle's side): the
        # handle's frame is then the only one (the box's, up to 45 degrees off, had filled the fits).
        handle = handle_yaw(obs.points)
        if handle is not None:
            return [box_in_frame(obs.points, handle)]
    clusters = _plane_yaw_clusters(planes, tol)
    near_box = [yaw for yaw, _ in clusters if gap(yaw, box.yaw) <= tol]
    if near_box:
        frames[0] = box_in_frame(obs.points, near_box[0])
    for yaw, _area in clusters:
        if len(frames) > extra:
            break
        if all(gap(yaw, f.yaw) > tol for f in frames):
            frames.append(box_in_frame(obs.points, yaw))
    return frames


@functools.lru_cache(maxsize=1)
def default_class_table() -> ClassTable:
    """The repository class table, parsed once (YAML parsing costs ~0.1 s)."""
    return load_class_table()


def candidate_classes(class_name: str, table: ClassTable | None = None) -> list[str]:
    """The observed class first, then the classes the table marks as interchangeable with it."""
    table = table if table is not None else default_class_table()
    try:
        info = table.by_name(class_name)
    except UnknownClassError:
        return [class_name]
    return [class_name, *[c for c in info.confusable_with if c != class_name]]


def _model_planes(features: ModelFeatures) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """CAD planes with offsets relative to the model's box centre (so both sides share an origin)."""
    arr = features.plane_array()
    if len(arr) == 0:
        return np.zeros((0, 3)), np.zeros(0)
    n = arr[:, :3]
    return n, arr[:, 3] + n @ features.box_center


def _articulated_class(class_name: str) -> bool:
    try:
        return default_class_table().by_name(class_name).category == "articulated"
    except UnknownClassError:
        return False


def _has_front(class_name: str) -> bool:
    """Whether a class's models have a front that orientation must get right: articulated ones (doors,
    drawers) and front-facing ones (a chair's backrest, a sofa's, a monitor's screen)."""
    return _articulated_class(class_name) or class_policy(class_name).front_facing


def _open_parts_capped(s_x: NDArray[np.float64], s_y: NDArray[np.float64], rots: NDArray[np.float64],
                       classes: Sequence[str]) -> NDArray[np.float64]:
    """Observed box extents with an open door or drawer discounted, per hypothesis (ours).

    Doors open and drawers slide towards an articulated model's front (+x), so the observed box is
    deeper along the box axis that carries the model's front than the closed model can be: a
    cabinet 45 cm deep with its door open 40 degrees spans 82 cm. Compared as is, the hypothesis
    with the front on that axis loses to one turned by 90 degrees, whose proportions happen to fit
    the inflated box (a front flip the alignment can no longer undo). Along the front axis the
    observation is capped at the model's extent times the larger of the other two axes' ratios
    (the model's own proportions; ``box_start`` does the same for the start scale).
    """
    arts = np.array([_articulated_class(c) for c in classes], dtype=bool)
    if not np.any(arts):
        return s_x
    out = s_x.copy()
    h = np.flatnonzero(arts)
    front = np.argmax(np.abs(rots[h, :, 0]), axis=1)  # box axis of the model's +x
    ratio = s_x[h] / np.maximum(s_y[h], EPS)
    others = ratio.copy()
    others[np.arange(len(h)), front] = -np.inf
    cap = s_y[h, front] * others.max(axis=1)
    out[h, front] = np.minimum(s_x[h, front], cap)
    return out


def _open_sides_relaxed(s_x: NDArray[np.float64], s_y: NDArray[np.float64],
                        room: NDArray[np.float64]) -> NDArray[np.float64]:
    """Observed box extents along axes with unknown space beyond a face raised towards the model's,
    per hypothesis (ours; ``room``: (H, 2) metres of unknown space along box x and y, both faces).

    Seen in part, a 1.1 m table measured 0.7 m where its far half was outside every frame, and the
    size term preferred a model with the proportions of the seen half. Along such an axis the seen
    extent is only a lower bound: it is compared as the model's extent at the scale of the vertical
    axis when that is larger and fits in the room, so a model longer than the seen part costs nothing
    there and a shorter one still does."""
    if not np.any(room > 0.0):
        return s_x
    out = s_x.copy()
    ratio = s_x[:, 2] / np.maximum(s_y[:, 2], EPS)
    reach = np.minimum(s_y[:, :2] * ratio[:, None], s_x[:, :2] + room)
    out[:, :2] = np.maximum(s_x[:, :2], reach)
    return out


def match_candidates(
    obs: ObjectObservation,
    candidates: Sequence[tuple[CadEntry, ModelFeatures]],
    config: CadReplacementConfig | None = None,
    *,
    planes: ObservedPlanes | None = None,
) -> MatchResult:
    """Rank oriented candidates by the Matching Error (Eq. 7) and keep the ``top_k`` best.

    ``candidates`` are (entry, features) pairs, e.g. from ``CadLibrary.candidates`` over
    ``candidate_classes(obs.class_name)``; entries of another class than ``obs.class_name``
    pay the class term (ours).
    """
    cfg = config or CadReplacementConfig()
    t0 = time.perf_counter()
    paper = cfg.method == "paper"
    if planes is None:
        planes = observed_planes(obs, cfg)
    t_planes = time.perf_counter() - t0
    frames = candidate_frames(obs, planes, extra=0 if paper else cfg.extra_frames)
    framed = [planes.in_frame(f) for f in frames]
    s_x_all = np.stack([np.asarray(f.size, dtype=np.float64) for f in frames])
    s_x_norms = np.maximum(np.linalg.norm(s_x_all, axis=1), EPS)
    hint = obs.front_hint
    front_ok = hint is not None and class_policy(obs.class_name).front_facing and not paper

    # ---- all hypotheses (frame, model, discrete rotation), vectorised
    rows: list[tuple[int, int, NDArray[np.float64]]] = []
    for fi in range(len(frames)):
        for mi, (entry, _feats) in enumerate(candidates):
            for rot in orientation_set(entry.class_name, cfg.method):
                rows.append((fi, mi, rot))
    if not rows:
        return MatchResult([], 0, 0, len(planes.normals), time.perf_counter() - t0, {"planes": t_planes})
    frame_idx = np.array([r[0] for r in rows])
    model_idx = np.array([r[1] for r in rows])
    rots = np.stack([r[2] for r in rows])  # (H, 3, 3) model -> box frame
    sizes_m = np.stack([np.asarray(candidates[i][1].box_size, dtype=np.float64) for i in range(len(candidates))])
    s_y = np.einsum("hij,hj->hi", np.abs(rots), sizes_m[model_idx])  # model box size along the box axes
    s_y_norm = np.maximum(np.linalg.norm(s_y, axis=1), EPS)
    s_x = s_x_all[frame_idx]
    s_x_norm = s_x_norms[frame_idx]
    if not paper:
        s_x = _open_parts_capped(s_x, s_y, rots, [candidates[i][0].class_name for i in model_idx])
        s_x = _open_sides_relaxed(s_x, s_y, np.stack([obs.room(f).sum(axis=1) for f in frames])[frame_idx])
        s_x_norm = np.maximum(np.linalg.norm(s_x, axis=1), EPS)
    diff = s_x / s_x_norm[:, None] - s_y / s_y_norm[:, None]
    # Eq. (8): ours takes the Euclidean norm; the paper's implementation an L1 difference.
    d_size = np.abs(diff).sum(axis=1) if paper else np.linalg.norm(diff, axis=1)
    # Eq. (10): d_b = 1 + g . z(y), g = -z; z(y) = where the model's up axis points.
    d_bias = 1.0 - rots[:, 2, 2]
    frame_rots = np.stack([_rot_z(f.yaw) for f in frames])
    map_rots = np.einsum("hij,hjk->hik", frame_rots[frame_idx], rots)
    if front_ok:
        assert hint is not None
        front = map_rots[:, :2, 0]  # model +x in the map, xy part
        flen = np.linalg.norm(front, axis=1)
        cos = np.where(flen > 0.5, (front @ hint) / np.maximum(flen, EPS), 0.0)
        d_front = 0.5 * (1.0 - cos)
    else:
        d_front = np.zeros(len(rows))
    other_class = np.array([candidates[i][0].class_name != obs.class_name for i in model_idx], dtype=np.float64)
    d_class = np.zeros(len(rows)) if paper else other_class
    w_front = 0.0 if paper else cfg.w_front
    w_class = 0.0 if paper else cfg.w_class
    lower = cfg.w_size * d_size + cfg.w_bias * d_bias + w_front * d_front + w_class * d_class

    # ---- plane term with pruning by the lower bound
    model_planes = [_model_planes(f) for _, f in candidates]
    n_obs = len(planes.normals)
    order = np.argsort(lower, kind="stable")
    k = max(1, int(cfg.top_k))
    heap: list[tuple[float, int, float, tuple[tuple[int, int], ...]]] = []  # (-error, row, d_plane, assignment)
    scored = 0
    for h in order:
        if len(heap) >= k and lower[h] >= -heap[0][0]:
            break
        scored += 1
        fi = int(frame_idx[h])
        d_plane, assignment = _plane_term(
            framed[fi], model_planes[model_idx[h]], rots[h], float(s_x_norms[fi]), float(s_y_norm[h]), cfg,
            normalise=not paper,
        )
        err = float(lower[h] + cfg.w_plane * d_plane)
        item = (-err, int(h), d_plane, assignment)
        if len(heap) < k:
            heapq.heappush(heap, item)
        elif err < -heap[0][0]:
            heapq.heapreplace(heap, item)
    best = sorted(heap, key=lambda it: (-it[0], it[1]))
    if not paper:
        best += _orientation_siblings(best, frame_idx, model_idx, candidates, lower, framed, model_planes, rots,
                                      s_x_norms, s_y_norm, cfg, obs.class_name, lower - w_front * d_front)
    out = []
    for neg_err, h, d_plane, assignment in best:
        entry, feats = candidates[model_idx[h]]
        out.append(
            MatchCandidate(
                entry=entry,
                features=feats,
                frame=frames[int(frame_idx[h])],
                box_rotation=rots[h],
                rotation=map_rots[h],
                d_size=float(d_size[h]),
                d_plane=float(d_plane),
                d_bias=float(d_bias[h]),
                d_front=float(d_front[h]),
                d_class=float(d_class[h]),
                error=float(-neg_err),
                assignment=assignment,
            )
        )
    return MatchResult(out, len(rows), scored, n_obs, time.perf_counter() - t0, {"planes": t_planes})


#: Ours: the best models with a front (articulated or front-facing classes) of the ranking (distinct
#: models, each in the box frame it ranks best in) keep all their upright orientations.
SIBLING_MODELS = 6


def _orientation_siblings(
    best: list[tuple[float, int, float, tuple[tuple[int, int], ...]]],
    frame_idx: NDArray[np.int64],
    model_idx: NDArray[np.int64],
    candidates: Sequence[tuple[CadEntry, ModelFeatures]],
    lower: NDArray[np.float64],
    framed: list[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]],
    model_planes: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
    rots: NDArray[np.float64],
    s_x_norms: NDArray[np.float64],
    s_y_norm: NDArray[np.float64],
    cfg: CadReplacementConfig,
    class_name: str,
    unhinted: NDArray[np.float64] | None = None,
) -> list[tuple[float, int, float, tuple[tuple[int, int], ...]]]:
    """The other upright orientations of the best few models with a front (same frame), scored.

    Box proportions and the context's front hint cannot tell which side of a cabinet (or a chair) is
    its front when a door stands open (the box is inflated along the front, the hint comes from free
    space around an inflated box, or from a corner's other free side); the screening fits can (with
    the articulation envelope; a chair's backrest). So those
    orientations reach it even when the Matching Error ranks them below the top-k. Half of the
    models are the best of the ranking, half the best by the lower bound without the front term
    (``unhinted``): a hint from a corner's free side (issue 23) had pushed every orientation of the
    model that was the object out of the top-k, and a model of another front turned sideways won.
    """
    have = {int(h) for _e, h, _d, _a in best}
    seen: list[tuple[int, int]] = []  # (frame, model) of each model's best-ranked hypothesis
    # distinct models (one model ranked best in each box frame must not use up the slots), those of
    # the observed class first (the detector's label is trusted; a flood of confusable models of a
    # larger library must not crowd out the observed class's own)
    ranked = [h for _e, h, _d, _a in sorted(
        best, key=lambda it: candidates[int(model_idx[it[1]])][0].class_name != class_name)]
    if unhinted is not None:
        own = np.array([candidates[int(i)][0].class_name == class_name for i in model_idx])
        order = np.lexsort((unhinted, ~own))  # the observed class first, then by the bound
        by_bound: list[int] = []
        models: set[int] = set()
        for h in order:
            if len(by_bound) >= SIBLING_MODELS // 2:
                break
            mi = int(model_idx[h])
            if mi not in models and _has_front(candidates[mi][0].class_name):
                models.add(mi)
                by_bound.append(int(h))
        ranked = ranked[:SIBLING_MODELS - len(by_bound)] + by_bound + ranked[SIBLING_MODELS - len(by_bound):]
    for h in ranked:
        key = (int(frame_idx[h]), int(model_idx[h]))
        if all(m != key[1] for _f, m in seen) and _has_front(candidates[key[1]][0].class_name):
            seen.append(key)
        if len(seen) >= SIBLING_MODELS:
            break
    extra = []
    for fi, mi in seen:
        for hh in np.flatnonzero((frame_idx == fi) & (model_idx == mi) & (np.abs(rots[:, 2, 2]) > 0.5)):
            h = int(hh)
            if h in have:
                continue
            d_plane, assignment = _plane_term(framed[fi], model_planes[mi], rots[h], float(s_x_norms[fi]),
                                              float(s_y_norm[h]), cfg, normalise=True)
            extra.append((-float(lower[h] + cfg.w_plane * d_plane), h, d_plane, assignment))
    return sorted(extra, key=lambda it: (-it[0], it[1]))


def _plane_term(
    obs: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]],
    model: tuple[NDArray[np.float64], NDArray[np.float64]],
    rot: NDArray[np.float64],
    s_x_norm: float,
    s_y_norm: float,
    cfg: CadReplacementConfig,
    *,
    normalise: bool,
) -> tuple[float, tuple[tuple[int, int], ...]]:
    """Eq. (9): optimal support-preserving plane assignment (Hungarian) and its cost.

    Model planes are rotated into the box frame (offsets are rotation invariant about the box
    centre). Pairs that would map a supporting plane onto a non-supporting one are forbidden.
    Observed planes without a partner pay ``plane_unmatched_cost``. Ours averages over the
    observed planes (keeps the weights' meaning independent of how many planes RANSAC found);
    the paper sums.
    """
    obs_n, obs_d, obs_support = obs
    n_obs = len(obs_n)
    if n_obs == 0:
        return 0.0, ()
    n_m, d_m = model
    n_rot = n_m @ rot.T
    support_m = n_rot[:, 2] > SUPPORT_NORMAL_COS
    cost = np.abs(obs_d[:, None] / s_x_norm - d_m[None, :] / s_y_norm) + 1.0 - obs_n @ n_rot.T
    forbidden = obs_support[:, None] != support_m[None, :]
    big = 1e6
    cost = np.where(forbidden, big, cost)
    # One "unmatched" column per observed plane keeps every row assignable.
    unmatched = cfg.plane_unmatched_cost if normalise else 0.0
    full = np.concatenate([cost, np.full((n_obs, n_obs), unmatched)], axis=1)
    r, c = linear_sum_assignment(full)
    total = float(full[r, c].sum())
    pairs = tuple((int(i), int(j)) for i, j in zip(r, c, strict=True) if j < len(n_m))
    return (total / n_obs if normalise else total), pairs


__all__ = [
    "ALL_ROTATIONS",
    "CLASS_POLICIES",
    "DEFAULT_POLICY",
    "UPRIGHT_ROTATIONS",
    "ClassPolicy",
    "MatchCandidate",
    "MatchResult",
    "ObservedPlanes",
    "box_in_frame",
    "candidate_classes",
    "candidate_frames",
    "class_policy",
    "match_candidates",
    "observed_planes",
    "orientation_set",
]
