"""3D panoptic quality (PQ/SQ/RQ, paper Eq. 15) and instance mAP@0.5 of a mapped scene (paper Sec. 5.2).

The map and the ground truth are both sets of triangle meshes, so the comparison needs a common
support on which "masks" can be intersected: predicted labels are transferred onto points of the
*observed* ground-truth surface:

1. Every ground-truth mesh is sampled uniformly (``MetricsConfig.sample_spacing``: one point per
   ``spacing**2`` of area, deterministic seed).
2. Points whose outside is blocked by another ground-truth entity within ``contact_distance`` (the
   bottom of a cup on a table, the table under it, the back of a cabinet 1 cm in front of a wall) are
   dropped: no camera can see them, and a reconstruction would otherwise be blamed for labelling them
   as the neighbour.
3. Points farther than ``observed_distance`` from the reconstruction (the union of all predicted
   meshes) are dropped: the robot never observed them (outer faces of walls, unvisited corners).
4. Each remaining point takes the predicted entity of the nearest predicted surface within
   ``transfer_distance`` (else no prediction).
5. Ground-truth entities with fewer than ``min_gt_points`` remaining points were never seen: they are
   not counted as misses; their points become *void* (as are points of classes left out of the
   evaluation). Stuff classes (``is_thing`` false: floor, wall, ceiling) form one segment per class
   on both sides, as in 2D panoptic segmentation.

On this support, IoU(pred, gt) = |points with both| / |points with either|, where void points are
removed from the prediction (Kirillov et al. 2019). A prediction matches a ground-truth segment of the
same class when IoU > ``iou_threshold`` (strictly; at 0.5 matches are unique). Unmatched predictions
are false positives unless more than ``void_overlap`` of their points are void, or they are negligible
(fewer than ``min_pred_points`` points *and* mesh area below ``min_fp_area``; a prediction with no
transferred point at all, e.g. a hallucinated object floating in free space, is thus an FP only if its
mesh is at least ``min_fp_area`` large). PQ/SQ/RQ are computed per class and averaged over the classes
that occur (TP + FP + FN > 0) -- "class-averaged" as in the paper's Tables 1 and 2 -- and over stuff
and thing classes separately. Instance AP@0.5 per thing class ranks predictions by ``confidence``
(ties: more points, then larger mesh first), matches greedily (each ground-truth instance once) and
integrates the monotone precision envelope over all recall points (VOC 2010+ / COCO style); mAP is the
mean over thing classes present in the evaluated ground truth.

All reported qualities (PQ, SQ, RQ, AP, mAP) are percentages in [0, 100], like the paper's tables.

Consequences worth knowing: completeness is not scored (what the map never reconstructed is not a
miss), and the map should export *all* its geometry, unknown-class entities included -- ground-truth
surface left without its own reconstruction but within ``observed_distance`` of a neighbour's mesh is
transferred to that neighbour and lowers its IoU.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Protocol

import numpy as np
import trimesh

from recon_core.entity import Entity

#: The 10 classes of the paper's evaluation (Sec. 5.2): 2 stuff + 8 thing classes.
PAPER_CLASSES: tuple[str, ...] = ("wall", "floor", "bed", "table", "chair", "monitor", "sofa", "bag", "cabinet",
                                  "fridge")
#: Segment label of a point with no (evaluated) ground truth / no prediction.
VOID = -1
#: Reported qualities are percentages.
PERCENT = 100.0
#: Contact rays start this far (m) behind the surface, so that exactly touching faces are hit.
CONTACT_RAY_BACKOFF = 1e-3


@dataclass(frozen=True)
class MetricsConfig:
    """Distances (metres), densities and thresholds of the evaluation protocol (see module doc)."""

    sample_spacing: float = 0.02  # ground-truth surface sampling: one point per spacing**2 of area
    seed: int = 0  # sampling seed: the same inputs always give the same numbers
    contact_distance: float = 0.02  # drop GT points whose outside is blocked this close by another GT entity
    observed_distance: float = 0.05  # GT points farther than this from the reconstruction were never observed
    transfer_distance: float = 0.05  # a GT point takes the label of the nearest predicted surface within this
    min_gt_points: int = 25  # GT entities with fewer observed points were not seen: void, not misses
    min_pred_points: int = 1  # with min_fp_area: below both, an unmatched prediction is not an FP
    min_fp_area: float = 0.01  # m^2; a prediction without transferred points counts as FP from this area on
    iou_threshold: float = 0.5  # match when IoU is strictly greater
    void_overlap: float = 0.5  # unmatched predictions with more than this share of void points are not FPs
    prefilter_spacing: float = 0.05  # speed only: grid of the KD-tree that skips far-away exact queries
    prefilter_min_triangles: int = 100_000  # speed only: coarser maps are queried exactly right away

    def __post_init__(self) -> None:
        for name in ("sample_spacing", "prefilter_spacing"):
            if not getattr(self, name) > 0:
                raise ValueError(f"MetricsConfig.{name} must be positive, got {getattr(self, name)!r}")
        for name in ("contact_distance", "observed_distance", "transfer_distance", "min_fp_area"):
            if getattr(self, name) < 0:
                raise ValueError(f"MetricsConfig.{name} must not be negative, got {getattr(self, name)!r}")
        if not 0 <= self.iou_threshold < 1 or not 0 <= self.void_overlap <= 1:
            raise ValueError("MetricsConfig.iou_threshold must be in [0, 1) and void_overlap in [0, 1]")


class GroundTruthEntityLike(Protocol):
    """What the evaluation needs of a ground-truth entity (``scene_recon.synthetic.scene.SceneEntity``)."""

    id: int
    class_id: int
    class_name: str
    is_thing: bool
    mesh: trimesh.Trimesh | None


@dataclass(frozen=True)
class Segment:
    """One evaluated segment: a thing instance, or all entities of one stuff class merged."""

    class_id: int
    class_name: str
    is_thing: bool
    confidence: float = 1.0  # ranking score for AP (predictions only)
    area: float = 0.0  # mesh surface area in m^2 (decides whether a point-less prediction is an FP)
    members: tuple[int, ...] = ()  # entity ids merged into this segment


@dataclass
class ClassResult:
    """Per-class panoptic quality and instance AP; qualities in percent."""

    class_id: int
    class_name: str
    is_thing: bool
    pq: float
    sq: float
    rq: float
    tp: int
    fp: int
    fn: int
    ap: float | None  # None for stuff classes and thing classes without evaluated ground truth
    num_gt: int  # evaluated ground-truth segments
    num_pred: int  # predicted segments that take part (TP or FP)


@dataclass
class PanopticMetrics:
    """Result of one evaluation. Qualities are percentages (0-100); averages are over classes."""

    per_class: dict[str, ClassResult]
    pq: float
    sq: float
    rq: float
    pq_stuff: float
    sq_stuff: float
    rq_stuff: float
    pq_things: float
    sq_things: float
    rq_things: float
    map: float  # mean AP@iou_threshold over thing classes present in the ground truth
    counts: dict[str, int] = field(default_factory=dict)
    matches: list[dict[str, Any]] = field(default_factory=list)  # {class, gt, pred (entity ids), iou (%)}
    config: MetricsConfig = field(default_factory=MetricsConfig)
    elapsed_s: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (the `eval-map --json` output)."""
        return {
            "units": "percent",
            "averages": {
                "all": {"pq": self.pq, "sq": self.sq, "rq": self.rq},
                "stuff": {"pq": self.pq_stuff, "sq": self.sq_stuff, "rq": self.rq_stuff},
                "things": {"pq": self.pq_things, "sq": self.sq_things, "rq": self.rq_things},
                "map": self.map,
            },
            "per_class": {name: asdict(r) for name, r in self.per_class.items()},
            "counts": dict(self.counts),
            "matches": list(self.matches),
            "config": asdict(self.config),
            "elapsed_s": self.elapsed_s,
        }


# ---------------------------------------------------------------------------------------------- geometry


def _mesh_arrays(mesh: trimesh.Trimesh | None) -> tuple[np.ndarray, np.ndarray]:
    if mesh is None or len(mesh.faces) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)


def _entity_arrays(e: Entity) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(e.vertices, np.float64).reshape(-1, 3)
    f = np.asarray(e.faces, np.int64).reshape(-1, 3)
    return (v, f) if len(f) and len(v) else (np.zeros((0, 3)), np.zeros((0, 3), np.int64))


def _triangle_areas(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    tri = v[f]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def sample_surface_points(meshes: Sequence[tuple[np.ndarray, np.ndarray]], spacing: float,
                          seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Uniform area-weighted samples of all meshes at once: points (N, 3), owner mesh index (N,), and the
    unit normal of the sampled triangle (N, 3).

    Each triangle gets ``floor(area / spacing**2 + u)`` points (u uniform in [0, 1)): unbiased, and
    far less clumpy than drawing triangles at random. Points come out grouped by owner, in order.
    """
    rng = np.random.default_rng(seed)
    tris, owners = [], []
    for i, (v, f) in enumerate(meshes):
        if len(f):
            tris.append(v[f])
            owners.append(np.full(len(f), i, np.int64))
    if not tris:
        return np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros((0, 3))
    tri, tri_owner = np.concatenate(tris), np.concatenate(owners)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    double_area = np.linalg.norm(cross, axis=1)
    normal = np.divide(cross, double_area[:, None], out=np.zeros_like(cross), where=double_area[:, None] > 0)
    count = np.floor(0.5 * double_area / spacing**2 + rng.random(len(tri))).astype(np.int64)
    which = np.repeat(np.arange(len(tri)), count)
    r1, r2 = np.sqrt(rng.random(len(which))), rng.random(len(which))
    a, b, c = tri[which, 0], tri[which, 1], tri[which, 2]
    points = (1 - r1)[:, None] * a + (r1 * (1 - r2))[:, None] * b + (r1 * r2)[:, None] * c
    return points, tri_owner[which], normal[which]


def _barycentric_grid(n: int) -> np.ndarray:
    """Barycentric coordinates of the vertices of a triangle split into n x n similar sub-triangles."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    i, j = i[keep], j[keep]
    return np.stack([n - i - j, i, j], axis=1) / n


def _covering_points(v: np.ndarray, f: np.ndarray, radius: float) -> np.ndarray:
    """Points such that every surface point of the mesh lies within `radius` of one of them.

    Triangles longer than `radius` are subdivided until every sub-triangle edge is at most `radius`
    (a point of a triangle is never farther from its nearest corner than its longest edge).
    """
    tri = v[f]
    longest = np.max(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2), axis=1)
    splits = np.maximum(np.ceil(longest / radius).astype(np.int64), 1)
    out = [v[np.unique(f)]]
    for n in np.unique(splits[splits > 1]):
        out.append(np.einsum("qj,sjd->sqd", _barycentric_grid(int(n)), tri[splits == n]).reshape(-1, 3))
    return np.concatenate(out)


def _voxel_downsample(points: np.ndarray, cell: float) -> np.ndarray:
    """One point per occupied grid cell (moves coverage by at most one cell diagonal)."""
    if not len(points):
        return points
    keys = np.floor(points / cell).astype(np.int64)
    keys -= keys.min(0)
    span = keys.max(0) + 1
    flat = (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2]  # one int64 per cell: fast unique
    _, first = np.unique(flat, return_index=True)
    return points[first]


class SurfaceIndex:
    """Exact nearest-surface queries against a set of meshes, each tagged with an owner index.

    Open3D's closest-point query is exact but slow for points far from a dense mesh (it starts with an
    unbounded search radius). With `prefilter_spacing`, a KD-tree over points covering the meshes first
    discards points that cannot be within the query distance; only the rest get the exact query.
    """

    def __init__(self, meshes: Sequence[tuple[np.ndarray, np.ndarray]], owners: Sequence[int],
                 prefilter_spacing: float | None = None) -> None:
        import open3d as o3d

        self._o3d = o3d
        self._scene = o3d.t.geometry.RaycastingScene()
        geometry_owner: dict[int, int] = {}
        cover = []
        for (v, f), owner in zip(meshes, owners, strict=True):
            if not len(f):
                continue
            gid = self._scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(v, np.float32)),
                                            o3d.core.Tensor(np.ascontiguousarray(f, np.uint32)))
            geometry_owner[int(gid)] = int(owner)
            if prefilter_spacing:
                cover.append(_covering_points(v, f, prefilter_spacing))
        self.empty = not geometry_owner
        self._owner_of = np.full(max(geometry_owner, default=-1) + 1, VOID, np.int64)  # Open3D geometry id -> owner
        for gid, owner in geometry_owner.items():
            self._owner_of[gid] = owner
        self._kdtree = None
        self._slack = 0.0
        if cover and prefilter_spacing:
            from scipy.spatial import cKDTree

            # covering radius `prefilter_spacing`, plus what thinning to one point per cell moves
            self._kdtree = cKDTree(_voxel_downsample(np.concatenate(cover), prefilter_spacing))
            self._slack = prefilter_spacing * (1 + math.sqrt(3))

    def nearest(self, points: np.ndarray, max_distance: float) -> tuple[np.ndarray, np.ndarray]:
        """(distance, owner) of the nearest surface per point; (inf, VOID) beyond `max_distance`."""
        dist = np.full(len(points), np.inf)
        owner = np.full(len(points), VOID, np.int64)
        if self.empty or not len(points):
            return dist, owner
        idx = np.arange(len(points))
        if self._kdtree is not None:
            d, _ = self._kdtree.query(points, distance_upper_bound=max_distance + self._slack, workers=-1)
            idx = idx[np.isfinite(d)]
        if not len(idx):
            return dist, owner
        query = np.ascontiguousarray(points[idx], np.float32)
        res = self._scene.compute_closest_points(self._o3d.core.Tensor(query))
        d = np.linalg.norm(res["points"].numpy() - query, axis=1).astype(np.float64)
        gid = res["geometry_ids"].numpy().astype(np.int64)
        ok = (d <= max_distance) & (gid < len(self._owner_of))  # also drops Open3D's INVALID_ID
        dist[idx[ok]] = d[ok]
        owner[idx[ok]] = self._owner_of[gid[ok]]
        return dist, owner


def _aabbs(meshes: Sequence[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    lo = np.array([v[np.unique(f)].min(0) if len(f) else np.full(3, np.inf) for v, f in meshes]).reshape(-1, 3)
    hi = np.array([v[np.unique(f)].max(0) if len(f) else np.full(3, -np.inf) for v, f in meshes]).reshape(-1, 3)
    return lo, hi


def contact_mask(points: np.ndarray, normals: np.ndarray, owner: np.ndarray,
                 meshes: Sequence[tuple[np.ndarray, np.ndarray]], distance: float) -> np.ndarray:
    """True for points whose outside is blocked by another mesh within `distance` (hidden contacts).

    A ray leaves each point along its outward normal, starting `CONTACT_RAY_BACKOFF` behind the surface
    so that a coplanar touching face (cup bottom on a table top) is hit too. Unlike a plain distance
    test this keeps the visible top of a thin book lying on a table while dropping its bottom, the
    table under it, and the back of a cabinet standing 1 cm in front of a wall (and that wall patch).
    Only meshes whose bounding boxes come within `distance` are cast against, and only with the points
    inside those boxes. Assumes outward-facing triangle winding (as trimesh primitives have).
    """
    import open3d as o3d

    hidden = np.zeros(len(points), bool)
    if distance <= 0 or not len(points):
        return hidden
    lo, hi = _aabbs(meshes)
    lo_x, hi_x = lo - distance, hi + distance
    starts = np.searchsorted(owner, np.arange(len(meshes) + 1))  # points are grouped by owner
    for i in range(len(meshes)):
        s, e = starts[i], starts[i + 1]
        if s == e:
            continue
        near = np.all((lo_x <= hi[i]) & (hi_x >= lo[i]), axis=1)
        near[i] = False
        others = np.flatnonzero(near)
        if not len(others):
            continue
        p = points[s:e]
        inside = np.zeros(len(p), bool)
        for j in others:
            inside |= np.all((p >= lo_x[j]) & (p <= hi_x[j]), axis=1)
        if not inside.any():
            continue
        scene = o3d.t.geometry.RaycastingScene()
        for j in others:
            v, f = meshes[j]
            scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(v, np.float32)),
                                o3d.core.Tensor(np.ascontiguousarray(f, np.uint32)))
        n = normals[s:e][inside]
        rays = np.hstack([p[inside] - CONTACT_RAY_BACKOFF * n, n]).astype(np.float32)
        t_hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        hidden[s + np.flatnonzero(inside)[t_hit <= distance + CONTACT_RAY_BACKOFF]] = True
    return hidden


# ---------------------------------------------------------------------------------------------- segments


def build_segments(class_ids: Sequence[int], class_names: Sequence[str], is_thing: Sequence[bool],
                   include: np.ndarray, entity_ids: Sequence[int], confidences: Sequence[float] | None = None,
                   areas: Sequence[float] | None = None) -> tuple[np.ndarray, list[Segment]]:
    """Segment index per entity (VOID where not included) and the segments.

    Things are one segment each; all included entities of one stuff class share one segment (its
    confidence is the highest of its members, its area their sum).
    """
    n = len(class_ids)
    confidences = confidences if confidences is not None else [1.0] * n
    areas = areas if areas is not None else [0.0] * n
    seg_of = np.full(n, VOID, np.int64)
    segments: list[Segment] = []
    stuff_seg: dict[int, int] = {}
    for i in range(n):
        if not include[i]:
            continue
        cid = int(class_ids[i])
        if not is_thing[i] and cid in stuff_seg:
            k = stuff_seg[cid]
            old = segments[k]
            segments[k] = Segment(cid, old.class_name, False, max(old.confidence, float(confidences[i])),
                                  old.area + float(areas[i]), (*old.members, int(entity_ids[i])))
            seg_of[i] = k
            continue
        seg_of[i] = len(segments)
        if not is_thing[i]:
            stuff_seg[cid] = len(segments)
        segments.append(Segment(cid, str(class_names[i]), bool(is_thing[i]), float(confidences[i]),
                                float(areas[i]), (int(entity_ids[i]),)))
    return seg_of, segments


# ---------------------------------------------------------------------------------------------- scoring


def average_precision(is_tp: np.ndarray, num_gt: int) -> float:
    """Area under the monotone precision envelope over all recall points (VOC 2010+ / COCO), in [0, 1].

    `is_tp` flags the ranked predictions (best first) as true or false positives.
    """
    if num_gt <= 0:
        return float("nan")
    is_tp = np.asarray(is_tp, bool)
    if not len(is_tp):
        return 0.0
    tp = np.cumsum(is_tp)
    fp = np.cumsum(~is_tp)
    recall = np.concatenate([[0.0], tp / num_gt, [1.0]])
    precision = np.concatenate([[0.0], tp / (tp + fp), [0.0]])
    precision = np.maximum.accumulate(precision[::-1])[::-1]
    step = np.flatnonzero(recall[1:] != recall[:-1])
    return float(np.sum((recall[step + 1] - recall[step]) * precision[step + 1]))


def _confusion(gt_labels: np.ndarray, pred_labels: np.ndarray, n_gt: int, n_pred: int) -> np.ndarray:
    """(n_gt + 1) x (n_pred + 1) point counts; row/column 0 are VOID."""
    flat = (np.asarray(gt_labels, np.int64) + 1) * (n_pred + 1) + (np.asarray(pred_labels, np.int64) + 1)
    return np.bincount(flat, minlength=(n_gt + 1) * (n_pred + 1)).reshape(n_gt + 1, n_pred + 1)


def _iou_matrix(conf: np.ndarray) -> np.ndarray:
    """IoU of every GT x predicted segment; void points are removed from the predictions."""
    inter = conf[1:, 1:].astype(np.float64)
    gt_size = conf[1:, :].sum(1)
    pred_size = conf[1:, 1:].sum(0)
    union = gt_size[:, None] + pred_size[None, :] - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def _greedy_by_iou(iou: np.ndarray, threshold: float) -> list[tuple[int, int]]:
    """Unique (gt, pred) pairs with IoU > threshold, best first (unique anyway when threshold >= 0.5)."""
    g, p = np.nonzero(iou > threshold)
    pairs, used_g, used_p = [], set(), set()
    for k in np.argsort(-iou[g, p], kind="stable"):
        if g[k] not in used_g and p[k] not in used_p:
            pairs.append((int(g[k]), int(p[k])))
            used_g.add(g[k])
            used_p.add(p[k])
    return pairs


def _class_ap(iou: np.ndarray, gts: np.ndarray, preds: np.ndarray, pred_segments: Sequence[Segment],
              pred_points: np.ndarray, threshold: float) -> float:
    """AP of one class: predictions by score (ties: more points, larger mesh), greedy, each GT once."""
    order = sorted(preds, key=lambda p: (-pred_segments[p].confidence, -pred_points[p], -pred_segments[p].area, p))
    free = np.ones(len(gts), bool)
    is_tp = np.zeros(len(order), bool)
    for rank, p in enumerate(order):
        cand = np.where(free, iou[gts, p], -1.0)
        best = int(np.argmax(cand)) if len(cand) else -1
        if best >= 0 and cand[best] > threshold:
            free[best] = False
            is_tp[rank] = True
    return average_precision(is_tp, len(gts))


def _mean(values: Iterable[float]) -> float:
    values = list(values)
    return float(np.mean(values)) if values else 0.0


def evaluate_point_labels(gt_labels: np.ndarray, pred_labels: np.ndarray, gt_segments: Sequence[Segment],
                          pred_segments: Sequence[Segment], config: MetricsConfig | None = None) -> PanopticMetrics:
    """PQ/SQ/RQ and AP from per-point segment labels (the protocol's core, independent of meshes).

    `gt_labels[k]` / `pred_labels[k]` index `gt_segments` / `pred_segments` for point k, or VOID.
    """
    cfg = config or MetricsConfig()
    n_g, n_p = len(gt_segments), len(pred_segments)
    conf = _confusion(gt_labels, pred_labels, n_g, n_p)
    iou = _iou_matrix(conf)
    gt_cls = np.array([s.class_id for s in gt_segments], np.int64)
    pred_cls = np.array([s.class_id for s in pred_segments], np.int64)
    same = gt_cls[:, None] == pred_cls[None, :]
    iou_same = np.where(same, iou, 0.0)
    pairs = _greedy_by_iou(iou_same, cfg.iou_threshold)

    pred_points = conf[:, 1:].sum(0)
    pred_area = np.array([s.area for s in pred_segments], np.float64)
    mostly_void = conf[0, 1:] > cfg.void_overlap * pred_points
    negligible = (pred_points < cfg.min_pred_points) & (pred_area < cfg.min_fp_area)
    matchable = (iou_same > cfg.iou_threshold).any(0) if n_g else np.zeros(n_p, bool)
    counted = matchable | ~(mostly_void | negligible)  # predictions that are TP or FP

    matched_g = {g for g, _ in pairs}
    matched_p = {p for _, p in pairs}
    names = {s.class_id: s.class_name for s in (*pred_segments, *gt_segments)}
    thing = {s.class_id: s.is_thing for s in (*pred_segments, *gt_segments)}
    per_class: dict[str, ClassResult] = {}
    for cid in sorted(names):
        gts = np.flatnonzero(gt_cls == cid)
        preds = np.flatnonzero((pred_cls == cid) & counted)
        tp_pairs = [(g, p) for g, p in pairs if gt_cls[g] == cid]
        tp = len(tp_pairs)
        fp = sum(1 for p in preds if p not in matched_p)
        fn = sum(1 for g in gts if g not in matched_g)
        if tp + fp + fn == 0:
            continue
        iou_sum = float(sum(iou[g, p] for g, p in tp_pairs))
        denom = tp + 0.5 * fp + 0.5 * fn
        ap = None
        if thing[cid] and len(gts):
            ap = PERCENT * _class_ap(iou_same, gts, preds, pred_segments, pred_points, cfg.iou_threshold)
        per_class[names[cid]] = ClassResult(
            cid, names[cid], thing[cid], PERCENT * iou_sum / denom, PERCENT * iou_sum / tp if tp else 0.0,
            PERCENT * tp / denom, tp, fp, fn, ap, len(gts), len(preds))

    stuff = [r for r in per_class.values() if not r.is_thing]
    things = [r for r in per_class.values() if r.is_thing]
    allc = list(per_class.values())
    matches = [{"class": gt_segments[g].class_name, "gt": list(gt_segments[g].members),
                "pred": list(pred_segments[p].members), "iou": PERCENT * float(iou[g, p])} for g, p in pairs]
    counts = {"points": len(gt_labels), "void_points": int(conf[0].sum()),
              "unlabelled_points": int(conf[:, 0].sum()), "gt_segments": n_g, "pred_segments": n_p,
              "pred_segments_counted": int(counted.sum()), "pred_segments_void": int((~counted & mostly_void).sum())}
    return PanopticMetrics(
        per_class,
        _mean(r.pq for r in allc), _mean(r.sq for r in allc), _mean(r.rq for r in allc),
        _mean(r.pq for r in stuff), _mean(r.sq for r in stuff), _mean(r.rq for r in stuff),
        _mean(r.pq for r in things), _mean(r.sq for r in things), _mean(r.rq for r in things),
        _mean(r.ap for r in things if r.ap is not None),
        counts, matches, cfg)


# ---------------------------------------------------------------------------------------------- meshes


def _included(class_ids: Sequence[int], names: Sequence[str], classes: Iterable[str] | None) -> np.ndarray:
    """Entities taking part: a known class (id >= 0; -1 is "unknown") that is among `classes`."""
    wanted = None if classes is None else set(classes)
    return np.array([cid >= 0 and (wanted is None or n in wanted) for cid, n in zip(class_ids, names, strict=True)],
                    bool).reshape(-1)


def evaluate_panoptic_map(predictions: Sequence[Entity], ground_truth: Iterable[GroundTruthEntityLike],
                          config: MetricsConfig | None = None,
                          classes: Iterable[str] | None = None) -> PanopticMetrics:
    """3D panoptic quality and instance mAP of mapped entities against ground-truth entities.

    `ground_truth` is a sequence of entities with id, class_id, class_name, is_thing and a map-frame
    mesh (e.g. ``GroundTruthScene.entities``; a ``GroundTruthScene`` itself works too). `classes`
    restricts the evaluation to these class names (e.g. ``PAPER_CLASSES``). Entities of other classes,
    and predictions of the "unknown" class (id -1), still count as reconstructed geometry: ground-truth
    points of left-out classes are void, points transferred from left-out predictions are unlabelled.
    """
    t0 = time.perf_counter()
    cfg = config or MetricsConfig()
    classes = None if classes is None else tuple(classes)
    gt = list(getattr(ground_truth, "entities", ground_truth))
    gt_meshes = [_mesh_arrays(e.mesh) for e in gt]
    points, owner, normals = sample_surface_points(gt_meshes, cfg.sample_spacing, cfg.seed)
    n_sampled = len(points)
    visible = ~contact_mask(points, normals, owner, gt_meshes, cfg.contact_distance)
    points, owner = points[visible], owner[visible]

    pred_meshes = [_entity_arrays(e) for e in predictions]
    dense = sum(len(f) for _, f in pred_meshes) >= cfg.prefilter_min_triangles
    index = SurfaceIndex(pred_meshes, range(len(predictions)), cfg.prefilter_spacing if dense else None)
    dist, nearest = index.nearest(points, max(cfg.observed_distance, cfg.transfer_distance))
    observed = dist <= cfg.observed_distance
    owner = owner[observed]
    nearest = np.where(dist <= cfg.transfer_distance, nearest, VOID)[observed]

    gt_point_count = np.bincount(owner, minlength=len(gt))
    seen = gt_point_count >= cfg.min_gt_points
    gt_ids, gt_names = [int(e.class_id) for e in gt], [e.class_name for e in gt]
    gt_seg_of, gt_segments = build_segments(
        gt_ids, gt_names, [e.is_thing for e in gt], seen & _included(gt_ids, gt_names, classes), [e.id for e in gt])
    pred_ids, pred_names = [int(e.class_id) for e in predictions], [e.class_name for e in predictions]
    pred_areas = [float(_triangle_areas(*m).sum()) if len(m[1]) else 0.0 for m in pred_meshes]
    pred_seg_of, pred_segments = build_segments(
        pred_ids, pred_names, [e.is_thing for e in predictions], _included(pred_ids, pred_names, classes),
        [e.id for e in predictions], [e.confidence for e in predictions], pred_areas)

    gt_labels = gt_seg_of[owner]
    pred_labels = np.append(pred_seg_of, VOID)[nearest]  # nearest == VOID picks the appended VOID
    result = evaluate_point_labels(gt_labels, pred_labels, gt_segments, pred_segments, cfg)
    has_geometry = np.array([len(f) > 0 for _, f in gt_meshes], bool)
    result.counts.update({
        "gt_entities": len(gt), "gt_entities_seen": int(seen.sum()),
        "gt_entities_unobserved": int((has_geometry & ~seen).sum()),
        "pred_entities": len(predictions), "sampled_points": n_sampled,
        "contact_points": int(n_sampled - visible.sum()), "observed_points": int(observed.sum()),
    })
    result.elapsed_s = time.perf_counter() - t0
    return result


def ground_truth_as_predictions(ground_truth: Iterable[GroundTruthEntityLike]) -> list[Entity]:
    """The ground truth as a perfect map (upper bound / sanity check of the protocol: PQ = 100)."""
    out = []
    for e in getattr(ground_truth, "entities", ground_truth):
        v, f = _mesh_arrays(e.mesh)
        out.append(Entity(int(e.id), e.class_name, v, f, class_id=int(e.class_id), instance_id=int(e.id),
                          is_thing=bool(e.is_thing), category=getattr(e, "category", "rigid")))
    return out
