"""Global physical check (paper Sec. 4.4): one candidate per object, no interpenetration, resting on support.

Each object arrives with its ranked CAD candidates (best alignment first). The check:

1. broad phase: only pairs whose axis-aligned bounds overlap are tested (an object is never tested
   against its own support parent's carrying surface, which it must touch);
2. narrow phase: the penetration depth of one object's surface into the other's closed link solids
   (signed distance, Open3D ray-casting scenes; containment counts: a cup sunk into a shelf panel is
   inside the solid, a cup standing on a shelf level is not);
3. conflicts are resolved over the candidate lists by min-conflicts: the object in the worst conflict
   that still has untried candidates switches to the next one when that lowers its penetration
   (movable, smaller objects yield before furniture), at most ``max_rounds`` rounds (the paper: 10);
4. supports that hold their objects at the wrong height (a shelf model whose boards are not where
   the books were seen lying) switch to a ranked alternative that offers the observed heights
   (``fit_supports``: Eq. (1)'s support relation kept in height, not only in name);
5. a final snap rests every supported object on its support (``rest_on``).

The paper's variant (``method="paper"``) tests FCL-style visual-mesh hulls: we keep the same loop but
measure penetration against the links' convex hulls, which flags containment (a cup inside a cabinet)
as a collision; ours measures solids.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import trimesh
from numpy.typing import NDArray

from cad_replacement.scene_model import MAP_ROOT, PlacedObject, ReplacedScene
from cad_replacement.solids import ObjectSolids, penetration_between
from recon_core.geometry.polygon import point_segment_distances, points_in_polygon

if TYPE_CHECKING:  # actions imports this module
    from cad_replacement.actions import SupportSpot

#: Penetration (m) above which a pair is a conflict (the issue's 1 cm).
MAX_PENETRATION_M = 0.01
#: Rounds of min-conflicts (the paper: 10).
MAX_ROUNDS = 10
#: A support whose surfaces are farther than this (m) from where a child was seen resting makes the
#: snap move the child: the support's candidates are searched for one that holds it where it was.
SUPPORT_MISMATCH_M = 0.02
#: Alternatives of a support tried, and how much worse (score ratio) than the choice they may fit.
SUPPORT_ALTERNATIVES = 3
SUPPORT_SCORE_RATIO = 1.5
#: A support model that would move a child this far (m) from where it was seen, with no alternative
#: that holds it, gives way to the object's scan (``_scan_holds``): the pose tolerance of the paper's
#: evaluation (10 cm), beyond which the child is no longer where the camera saw it.
SCAN_FALLBACK_MISMATCH_M = 0.10
#: Clearance (m) kept between a footprint and the outline of an enclosed support surface ...
CONTAINED_MARGIN = 0.005
#: ... and the largest horizontal move (m) made to get it there: farther, the fit (or the graph) is
#: wrong about where the object is, and moving it would only hide that.
CONTAINED_MAX_SHIFT = 0.05
#: ... and at most this share of the footprint's narrow side (a book standing 2 cm thick is not
#: moved by its own thickness: that is a different place, not a correction).
CONTAINED_MAX_SHARE = 0.3


@dataclass
class CheckReport:
    """What the check did: pairs tested, conflicts before/after, switches, time."""

    pairs_total: int = 0
    pairs_tested: int = 0
    conflicts_before: list[tuple[str, str, float]] = field(default_factory=list)
    conflicts_after: list[tuple[str, str, float]] = field(default_factory=list)
    switches: dict[str, int] = field(default_factory=dict)
    #: |gap| (m) between each supported object and the support surface it was snapped onto, before the snap.
    support_gaps_before: dict[str, float] = field(default_factory=dict)
    #: horizontal distance (m) each object was moved out of a wall it was sunk into
    wall_pushes: dict[str, float] = field(default_factory=dict)
    #: horizontal distance (m) each movable object was slid away from a neighbour on its surface
    separations: dict[str, float] = field(default_factory=dict)
    #: supports switched to an alternative holding their objects at the observed heights:
    #: name -> (height mismatch before, after) in m
    support_switches: dict[str, tuple[float, float]] = field(default_factory=dict)
    rounds: int = 0
    seconds: float = 0.0

    @property
    def max_penetration_after(self) -> float:
        return max((d for _a, _b, d in self.conflicts_after), default=0.0)


def _yield_order(obj: PlacedObject) -> tuple[bool, float]:
    """Who switches first in a conflict: movable things, then smaller objects."""
    size = obj.model.size
    return (not obj.movable, float(np.prod(np.maximum(size, 1e-3))))


class PhysicalCheck:
    """The Sec. 4.4 check as a callable for ``CadReplacer(physical_check=...)``."""

    def __init__(self, method: str = "ours", max_rounds: int = MAX_ROUNDS,
                 max_penetration: float = MAX_PENETRATION_M) -> None:
        if method not in ("ours", "paper"):
            raise ValueError(f"method must be 'ours' or 'paper', got {method!r}")
        self.method = method
        self.max_rounds = max_rounds
        self.max_penetration = max_penetration
        self.last_report = CheckReport()

    def _conflicts(self, scene: ReplacedScene, solids: dict[str, ObjectSolids],
                   names: list[str] | None = None) -> list[tuple[str, str, float]]:
        report = self.last_report
        objs = {o.name: o for o in scene}
        out = []
        order = sorted(solids)
        focus = set(names) if names is not None else None
        for i, a in enumerate(order):
            for b in order[i + 1:]:
                if focus is not None and a not in focus and b not in focus:
                    continue
                report.pairs_total += 1
                oa, ob = objs[a], objs[b]
                related = oa.parent == b or ob.parent == a
                if not solids[a].overlaps(solids[b]):
                    continue
                report.pairs_tested += 1
                depth = penetration_between(solids[a], solids[b])
                # an object resting on its parent touches it; a few mm is the support contact itself
                limit = self.max_penetration * (1.5 if related else 1.0)
                if depth > limit:
                    out.append((a, b, depth))
        return out

    def __call__(self, scene: ReplacedScene, alternatives: Mapping[str, Sequence[PlacedObject]]) -> ReplacedScene:
        t0 = time.perf_counter()
        self.last_report = report = CheckReport()
        hulls = self.method == "paper"
        objects = {o.name: o for o in scene}
        solids = {n: ObjectSolids(o, hulls) for n, o in objects.items()}  # layout slabs are obstacles too
        tried = {n: 0 for n in objects}
        conflicts = self._conflicts(scene, solids)
        report.conflicts_before = list(conflicts)
        for _round in range(self.max_rounds):
            if not conflicts:
                break
            report.rounds += 1
            worst = max(conflicts, key=lambda c: c[2])
            a, b = objects[worst[0]], objects[worst[1]]
            candidates = [o for o in sorted((a, b), key=_yield_order)
                          if tried[o.name] < len(alternatives.get(o.name, []))]
            if not candidates:
                conflicts = [c for c in conflicts if c is not worst]
                continue
            mover = candidates[0]
            other = b if mover is a else a
            current = penetration_between(solids[mover.name], solids[other.name])
            alt = alternatives[mover.name][tried[mover.name]]
            tried[mover.name] += 1
            trial = PlacedObject(mover.name, alt.class_name, alt.model, alt.pose.copy(), parent=mover.parent,
                                 parent_link=mover.parent_link, support=mover.support, movable=mover.movable,
                                 entity_id=mover.entity_id, joint_values=dict(alt.joint_values), scale=alt.scale,
                                 cad_id=alt.cad_id)
            _rest_like(trial, mover)
            trial_solids = ObjectSolids(trial, hulls)
            if penetration_between(trial_solids, solids[other.name]) < current:
                objects[mover.name] = trial
                solids[mover.name] = trial_solids
                report.switches[mover.name] = report.switches.get(mover.name, 0) + 1
            scene = ReplacedScene(scene.name, [objects[o.name] for o in scene], scene.frame_id, scene.revision)
            conflicts = self._conflicts(scene, solids, [mover.name, other.name]) + [
                c for c in conflicts if mover.name not in c[:2] and other.name not in c[:2]]
        result = ReplacedScene(scene.name, [objects[o.name] for o in scene], scene.frame_id, scene.revision)
        if self.method == "ours":
            report.support_switches = self._fit_supports(result, objects, solids, alternatives, hulls)
            result = ReplacedScene(scene.name, [objects[o.name] for o in scene], scene.frame_id, scene.revision)
        report.wall_pushes = push_out_of_walls(result, solids, self.max_penetration, hulls)
        report.support_gaps_before = snap_to_supports(result)
        solids = {o.name: ObjectSolids(o, hulls) for o in result}
        report.separations = separate_neighbours(result, solids, self.max_penetration, hulls)
        report.conflicts_after = self._conflicts(result, solids)
        report.seconds = time.perf_counter() - t0
        return result


    def _fit_supports(self, scene: ReplacedScene, objects: dict[str, PlacedObject], solids: dict[str, ObjectSolids],
                      alternatives: Mapping[str, Sequence[PlacedObject]], hulls: bool
                      ) -> dict[str, tuple[float, float]]:
        """Switch supports whose surfaces miss their children's observed heights (``support_mismatch``)
        to the first of their ``SUPPORT_ALTERNATIVES`` alternatives (scored within
        ``SUPPORT_SCORE_RATIO`` of the choice, when the alternatives carry scores) that holds every
        child within ``SUPPORT_MISMATCH_M`` and collides with nothing but its children.

        When none does, the model would move a child more than ``SCAN_FALLBACK_MISMATCH_M`` and the
        alternatives offer the object's scan (``alternatives[name].scan()``, the replacer's observed mesh
        of it), the scan takes its place if it holds every child within ``SUPPORT_MISMATCH_M``: a
        cabinet model whose shelves are 9 cm apart does not explain a 20 cm bottle seen standing inside
        it (gen-4242), and the snap lifted the bottle 47 cm onto its top. The scan's levels
        (``scan_features``) are where the children were seen. ``objects`` and ``solids`` are updated;
        returns name -> (mismatch before, after)."""
        switched: dict[str, tuple[float, float]] = {}
        children: dict[str, list[PlacedObject]] = {}
        for o in scene:
            if o.parent in objects:
                children.setdefault(o.parent, []).append(o)
        for name, kids in sorted(children.items()):
            parent = objects[name]
            alts = alternatives.get(name, [])
            if parent.model.source == "box" or not alts:
                continue
            before = support_mismatch(parent, kids)
            if before <= SUPPORT_MISMATCH_M:
                continue
            scores, best = getattr(alts, "scores", None), getattr(alts, "chosen_score", None)
            for i in range(min(len(alts), SUPPORT_ALTERNATIVES)):
                if scores is not None and best is not None and scores[i] > SUPPORT_SCORE_RATIO * best:
                    break
                alt = alts[i]
                trial = PlacedObject(name, alt.class_name, alt.model, alt.pose.copy(), parent=parent.parent,
                                     parent_link=parent.parent_link, support=parent.support, movable=parent.movable,
                                     entity_id=parent.entity_id, joint_values=dict(alt.joint_values), scale=alt.scale,
                                     cad_id=alt.cad_id)
                held = self._holds(trial, parent, kids, solids, hulls)
                if held is not None:
                    objects[name], solids[name] = trial, held[1]
                    switched[name] = (before, held[0])
                    break
            if name in switched or before <= SCAN_FALLBACK_MISMATCH_M:
                continue
            scan_of = getattr(alts, "scan", None)  # the object's scan, built only now
            scan = scan_of() if callable(scan_of) else None
            held = None if scan is None else self._holds(scan, parent, kids, solids, hulls)
            if scan is not None and held is not None:
                objects[name], solids[name] = scan, held[1]
                switched[name] = (before, held[0])
        return switched

    def _holds(self, trial: PlacedObject, parent: PlacedObject, kids: Sequence[PlacedObject],
               solids: dict[str, ObjectSolids], hulls: bool) -> tuple[float, ObjectSolids] | None:
        """``trial`` (another candidate, or the scan) rested like ``parent``: its mismatch and solids when it
        holds every child within ``SUPPORT_MISMATCH_M`` and collides with nothing but them (its own
        support a little more), else None."""
        _rest_like(trial, parent)
        after = support_mismatch(trial, kids)
        if after > SUPPORT_MISMATCH_M:
            return None
        trial_solids = ObjectSolids(trial, hulls)
        kid_names = {k.name for k in kids}
        if any(trial_solids.overlaps(solids[n]) and penetration_between(trial_solids, solids[n])
               > self.max_penetration * (1.5 if n == parent.parent else 1.0)
               for n in solids if n != trial.name and n not in kid_names):
            return None
        return after, trial_solids


def support_mismatch(parent: PlacedObject, kids: Sequence[PlacedObject]) -> float:
    """Largest vertical distance (m) between a child's bottom and the parent surface the snap would
    rest it on (the same choice as ``snap_to_supports``)."""
    from cad_replacement.actions import support_spots

    spots = support_spots(parent)
    worst = 0.0
    for kid in kids:
        worst = max(worst, abs(support_for(parent, kid, spots).height - kid.resting_height()))
    return worst


#: A child of an object kept as its scan rests on one of the scan's inner levels only when its bottom is
#: this close (m) to it: it was seen there. Farther, it goes onto the scan's top as on any unknown solid
#: (a real kitchen's cup, placed by the graph 26 cm under the table scan's top, belongs on that top).
SCAN_LEVEL_TOLERANCE_M = 0.03


def support_for(parent: PlacedObject, obj: PlacedObject, spots: Sequence[SupportSpot]) -> SupportSpot:
    """The surface of ``parent`` that ``obj`` rests on (``spots``: ``support_spots(parent)``).

    One it fits on (its height under the surface's clearance: a bottle on a cabinet never goes into a
    closed drawer), preferring those under the object's centre, nearest to its bottom. A scan's inner
    levels (``scan_features``: every surface but its top) count only within ``SCAN_LEVEL_TOLERANCE_M``.
    """
    centre, _radius, height = _footprint(obj)
    bottom = obj.resting_height()
    if parent.model.source == "observed" and len(spots) > 1:
        top = max(spots, key=lambda sp: sp.height)
        spots = [sp for sp in spots if sp is top or abs(sp.height - bottom) <= SCAN_LEVEL_TOLERANCE_M]
    fitting = [sp for sp in spots if sp.clearance is None or sp.clearance >= 0.9 * height] or list(spots)
    under = [sp for sp in fitting if points_in_polygon(centre[None], sp.polygon)[0]] or fitting
    return min(under, key=lambda sp: abs(sp.height - bottom))


#: Largest horizontal move (m) that takes an object out of a wall: farther, the wall or the pose is
#: wrong and moving the object would only hide it.
MAX_WALL_PUSH_M = 0.10


def _wall_axis(wall: PlacedObject) -> NDArray[np.float64]:
    """Unit horizontal direction across a wall slab (its thinnest horizontal box axis)."""
    size = wall.model.features.box_size
    axis = wall.pose[:3, :3][:, int(np.argmin(size[:2]))].copy()
    axis[2] = 0.0
    return axis / max(float(np.linalg.norm(axis)), 1e-12)


def push_out_of_walls(scene: ReplacedScene, solids: dict[str, ObjectSolids], max_penetration: float,
                      hulls: bool = False) -> dict[str, float]:
    """Move furniture and objects sunk into a wall slab straight out of it, towards the room.

    Walls are slabs behind the observed room-side face; a cabinet whose fitted CAD model is a few
    centimetres deeper than the mapped one pokes into the wall, which no candidate switch cures
    (every candidate is fitted to the same points) and which a simulator resolves by throwing it.
    The object (with what rests on it) moves across the wall by the penetration depth plus 2 mm,
    at most ``MAX_WALL_PUSH_M`` in all, and only when that clears the wall without sinking it into
    another one. ``solids`` is updated; returns the distance moved by object.
    """
    from cad_replacement.actions import descendants

    walls = [o for o in scene if o.model.source == "box" and o.class_name == "wall"]
    moved: dict[str, float] = {}
    if not walls:
        return moved
    for obj in scene:
        if obj.model.source == "box" or obj.name not in solids:
            continue
        total = np.zeros(3)
        for _ in range(3):  # a corner: one wall, then the other
            hits = [(w, penetration_between(solids[obj.name], solids[w.name])) for w in walls
                    if solids[obj.name].overlaps(solids[w.name])]
            hits = [(w, d) for w, d in hits if d > 0.5 * max_penetration]
            if not hits:
                break
            wall, depth = max(hits, key=lambda h: h[1])
            axis = _wall_axis(wall)
            centre = 0.5 * (solids[obj.name].lo + solids[obj.name].hi)
            side = 1.0 if float(axis @ (centre - wall.pose[:3, 3])) >= 0.0 else -1.0
            step = side * (depth + 0.002) * axis
            if float(np.linalg.norm(total + step)) > MAX_WALL_PUSH_M:
                break
            _trial, trial_solids = _slide(obj, step, hulls)
            after = {w.name: penetration_between(trial_solids, solids[w.name]) for w in walls
                     if trial_solids.overlaps(solids[w.name])}
            before = dict((w.name, d) for w, d in hits)
            # the wall must be cleared (a slab's depth measure saturates at its thickness: an
            # object through a wall looks only "slab-deep" in), and no other wall entered deeper
            if after.get(wall.name, 0.0) > 0.5 * max_penetration or any(
                    d > max(before.get(n, 0.0), 0.5 * max_penetration) for n, d in after.items() if n != wall.name):
                break
            for o in [obj, *descendants(scene, obj.name)]:
                o.pose[:3, 3] += step
                solids[o.name] = ObjectSolids(o, hulls)
            total += step
        if np.any(total):
            moved[obj.name] = float(np.linalg.norm(total))
    return moved


def _slide(obj: PlacedObject, step: NDArray[np.float64], hulls: bool) -> tuple[PlacedObject, ObjectSolids]:
    trial_pose = obj.pose.copy()
    trial_pose[:3, 3] += step
    trial = PlacedObject(obj.name, obj.class_name, obj.model, trial_pose, parent=obj.parent,
                         parent_link=obj.parent_link, support=obj.support, movable=obj.movable,
                         entity_id=obj.entity_id, joint_values=dict(obj.joint_values), scale=obj.scale,
                         cad_id=obj.cad_id)
    return trial, ObjectSolids(trial, hulls)


def separate_neighbours(scene: ReplacedScene, solids: dict[str, ObjectSolids], max_penetration: float,
                        hulls: bool = False, rounds: int = 3) -> dict[str, float]:
    """Slide movable objects on one surface apart where their CAD models overlap after the snap.

    Two books standing side by side are each fitted to their own points, but a library model
    slightly thicker than the book (or a snap that brought both onto the same shelf) makes them
    overlap by a centimetre or two; a simulator then throws them apart. The smaller object slides
    horizontally away from the other by the overlap plus 2 mm when it stays on its support surface
    (centre inside the surface outline) and the slide creates no deeper overlap with anything else.
    ``solids`` is updated; returns the distance moved by object.
    """
    from cad_replacement.actions import descendants, support_spots

    moved: dict[str, float] = {}
    objects = {o.name: o for o in scene}
    for _ in range(rounds):
        changed = False
        movable = sorted((o for o in scene if o.movable and o.parent in objects), key=lambda o: o.name)
        for i, a in enumerate(movable):
            for b in movable[i + 1:]:
                if a.parent != b.parent or not solids[a.name].overlaps(solids[b.name]):
                    continue
                depth = penetration_between(solids[a.name], solids[b.name])
                if depth <= 0.5 * max_penetration:
                    continue
                mover, other = sorted((a, b), key=_yield_order)
                ca = 0.5 * (solids[mover.name].lo + solids[mover.name].hi)
                cb = 0.5 * (solids[other.name].lo + solids[other.name].hi)
                away = (ca - cb)[:2]
                if float(np.linalg.norm(away)) < 1e-6:
                    away = mover.pose[:2, 0].copy()
                away /= float(np.linalg.norm(away))
                step = np.r_[away * (depth + 0.002), 0.0]
                trial, trial_solids = _slide(mover, step, hulls)
                centre, _r, _h = _footprint(trial)
                spots = [sp for sp in support_spots(objects[mover.parent])
                         if abs(sp.height - trial.resting_height()) < 0.01]
                if not any(points_in_polygon(centre[None], sp.polygon)[0] for sp in spots) and \
                        objects[mover.parent].model.source != "box":
                    continue
                worst_before = max((penetration_between(solids[mover.name], solids[n]) for n in solids
                                    if n not in (mover.name, other.name, mover.parent)), default=0.0)
                worst_after = max((penetration_between(trial_solids, solids[n]) for n in solids
                                   if n not in (mover.name, mover.parent)), default=0.0)
                if worst_after > max(worst_before, 0.5 * max_penetration):
                    continue
                for o in [mover, *descendants(scene, mover.name)]:
                    o.pose[:3, 3] += step
                    solids[o.name] = ObjectSolids(o, hulls)
                moved[mover.name] = moved.get(mover.name, 0.0) + float(np.linalg.norm(step))
                changed = True
        if not changed:
            break
    return moved


def _rest_like(trial: PlacedObject, reference: PlacedObject) -> None:
    """Put the alternative's bottom where the current choice's bottom is (on the same support)."""
    trial.pose[2, 3] += reference.resting_height() - trial.resting_height()


def _footprint(obj: PlacedObject) -> tuple[NDArray[np.float64], float, float]:
    """xy of the object's box centre, the radius of its footprint's inscribed circle, its height.

    In the map: a book may lie on its side (classes that may lie down), so the model axis that
    points up is found from the pose, not assumed to be the model's z (a lying 26 cm book is 4 cm
    tall: it fits a 9 cm shelf).
    """
    f = obj.model.features
    rot = obj.pose[:3, :3]
    centre = (rot @ f.box_center + obj.pose[:3, 3])[:2]
    up = int(np.argmax(np.abs(rot[2])))
    across = [float(f.box_size[k]) for k in range(3) if k != up]
    return centre, 0.5 * min(across), float(f.box_size[up])


def _inside_margin(points: NDArray[np.float64], polygon: NDArray[np.float64]) -> NDArray[np.float64]:
    """Signed distance of xy points to a polygon's outline: positive inside, negative outside."""
    edge = point_segment_distances(points, polygon, np.roll(polygon, -1, axis=0)).min(axis=1)
    return np.where(points_in_polygon(points, polygon), edge, -edge)


def _onto_surface(centre: NDArray[np.float64], polygon: NDArray[np.float64], margin: float) -> NDArray[np.float64]:
    """Smallest horizontal move bringing ``centre`` at least ``margin`` inside ``polygon``.

    Candidates lie on the segment from the centre to the polygon's centroid (support polygons are
    convex outlines), so the object moves straight towards the middle of the surface and no further
    than needed; a surface too small for the margin gets the object at its centroid.
    """
    target = polygon.mean(axis=0)
    steps = np.linspace(0.0, 1.0, 41)[:, None]
    trial = centre[None] + steps * (target - centre)[None]
    inside = np.flatnonzero(_inside_margin(trial, polygon) >= margin)
    return (trial[inside[0]] if len(inside) else target) - centre


def _footprint_corners(obj: PlacedObject) -> NDArray[np.float64]:
    """xy of the object's CAD box corners in the map (8, 2): its footprint on a surface."""
    f = obj.model.features
    signs = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    corners = f.box_center + signs * f.box_size
    return (corners @ obj.pose[:3, :3].T + obj.pose[:3, 3])[:, :2]


def _into_surface(corners: NDArray[np.float64], polygon: NDArray[np.float64],
                  margin: float) -> NDArray[np.float64] | None:
    """Smallest horizontal move that puts the whole footprint (``corners``) at least ``margin``
    inside the convex ``polygon``; None when the footprint does not fit in it.

    Each edge is a half-plane constraint on the move t: n.t >= b (n the inward normal); the
    minimum-norm feasible t is 0, the projection onto one constraint's line or the meeting point
    of two of them, so those few candidates are enumerated and the shortest feasible one is taken.
    """
    a, b = polygon, np.roll(polygon, -1, axis=0)
    edge = b - a
    length = np.linalg.norm(edge, axis=1)
    ok = length > 1e-9
    if int(ok.sum()) < 3:
        return None
    a, edge, length = a[ok], edge[ok], length[ok]
    area2 = float(np.sum(polygon[:, 0] * np.roll(polygon[:, 1], -1) - np.roll(polygon[:, 0], -1) * polygon[:, 1]))
    sign = 1.0 if area2 > 0 else -1.0  # counter-clockwise: the inward normal is the edge turned left
    n = sign * np.c_[-edge[:, 1], edge[:, 0]] / length[:, None]
    need = (margin + np.einsum("ej,ej->e", n, a)[None] - corners @ n.T).max(axis=0)  # b_e per edge
    cands = [np.zeros(2)] + [need[e] * n[e] for e in range(len(n)) if need[e] > 0]
    for i in range(len(n)):
        for j in range(i + 1, len(n)):
            m = np.array([n[i], n[j]])
            if abs(np.linalg.det(m)) > 1e-9:
                cands.append(np.linalg.solve(m, [need[i], need[j]]))
    pts = np.array(cands)
    feasible = np.all(pts @ n.T >= need[None] - 1e-9, axis=1)
    if not np.any(feasible):
        return None
    pts = pts[feasible]
    return pts[int(np.argmin(np.linalg.norm(pts, axis=1)))]


def snap_to_supports(scene: ReplacedScene) -> dict[str, float]:
    """Final snap (Sec. 4.4): rest every supported object on its parent's CAD support surface.

    The surface is ``support_for``'s choice. The object (and what rests on it) moves vertically onto
    it and, when its centre is closer than a quarter of its footprint to the surface's edge or off it
    (it would tip over in a simulator), horizontally onto it; ``parent_link`` becomes the link carrying that surface.
    Returns the gaps closed (m, by object).
    """
    from cad_replacement.actions import descendants, support_spots

    gaps: dict[str, float] = {}
    for obj in scene.objects:
        if obj.parent == MAP_ROOT:
            continue
        parent = scene.object(obj.parent)
        centre, radius, _height = _footprint(obj)
        spot = support_for(parent, obj, support_spots(parent))
        move = np.zeros(3)
        move[2] = spot.height - obj.resting_height()
        if parent.model.source != "box":  # layout slabs are the room: nothing falls off the floor
            move[:2] = _onto_surface(centre, spot.polygon, 0.5 * radius)
            if spot.clearance is not None:
                # An enclosed surface (a shelf, a drawer) has walls around it: the whole footprint
                # goes inside when it fits (a book overhanging a drawer's side sits on its wall, and
                # the simulator pushes it off), else the centre rule above stands.
                inside = _into_surface(_footprint_corners(obj) + move[:2], spot.polygon, CONTAINED_MARGIN)
                if inside is not None and float(np.linalg.norm(inside)) <= min(CONTAINED_MAX_SHIFT,
                                                                               CONTAINED_MAX_SHARE * 2.0 * radius):
                    move[:2] += inside
        gaps[obj.name] = abs(float(move[2]))
        for o in [obj, *descendants(scene, obj.name)]:
            o.pose[:3, 3] += move
        if spot.link != parent.model.root_link:
            obj.parent_link = spot.link
    return gaps


def pair_penetrations(scene: ReplacedScene, hulls: bool = False) -> list[tuple[str, str, float]]:
    """Every pair of objects whose bounds overlap with its penetration depth (m): for evaluation."""
    solids = [ObjectSolids(o, hulls) for o in scene]
    out = []
    for i, a in enumerate(solids):
        for b in solids[i + 1:]:
            if a.overlaps(b):
                out.append((a.name, b.name, penetration_between(a, b)))
    return out


def posed_mesh(obj: PlacedObject) -> trimesh.Trimesh:
    """The whole object in the map frame at its joint values (for pictures and evaluation)."""
    mesh = obj.model.mesh(obj.joint_values)
    mesh.apply_transform(obj.pose)
    return mesh


def support_gap(obj: PlacedObject, support_z: float) -> float:
    """Signed gap (m) between the object's bottom and its support height (negative: sunk in)."""
    return obj.resting_height() - support_z


__all__ = ["MAX_PENETRATION_M", "CheckReport", "PhysicalCheck", "pair_penetrations", "posed_mesh", "snap_to_supports",
           "support_for", "support_gap", "support_mismatch"]
