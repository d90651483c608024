"""Supporting relations S of the parse tree (paper Sec. 2.1-2.2, Eqs. (1)-(3), Sec. 6.5 fallbacks).

Bottom-up: for every node v_c, the candidates v_p are the nodes whose bottoms are below v_c's
box bottom and whose footprints meet v_c's; their supporting planes (Eq. (1): n . g <= a_th)
between ``max_gap`` below and ``above_tolerance`` above v_c's bottom are scored with Eq. (3),

    S = (1 - min(1, |D| / scale)) * A,     D = bottom of v_c - plane height   (Eq. (1), scale 1 m),

where A is the contact-area ratio of Eq. (2) (``contact.py``). Among the accepted scores
(> accept_score) a plane that also meets Eq. (2) (A >= b_th) is preferred. A candidate whose box
top is at v_c's bottom and covers at least b_th of its footprint but has no valid plane there
gets v_c's bottom registered as a new, *inferred* supporting plane (an occluded table top).
With no accepted score the fallbacks of Sec. 6.5 apply: the floor for things standing low, else
the nearest wall (an object hung on or leaning against it), else the floor / the root.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from recon_core.geometry.box import GravityBox
from recon_core.geometry.gravity import UP
from recon_core.geometry.plane import Plane
from recon_core.geometry.polygon import EPS, polygon_distance
from scene_graph.classify import LAYOUT
from scene_graph.config import SupportConfig
from scene_graph.contact import claimed_ratios, footprint_grid, points_cover, triangles_cover
from scene_graph.features import NodeFeatures
from scene_graph.planes import SurfacePlane

log = logging.getLogger(__name__)

#: Parent id of nodes hanging off the scene root.
ROOT_ID = 0
#: How a support was decided.
KINDS = ("root", "support", "inferred_plane", "fallback_floor", "fallback_wall", "fallback_root")


@dataclass
class SupportDecision:
    """The parent of one node and why: plane, score (Eq. (3)), contact ratio (Eq. (2)), D (Eq. (1))."""

    child_id: int
    parent_id: int
    kind: str
    score: float = 0.0
    contact_ratio: float = 0.0
    distance: float = 0.0
    plane: SurfacePlane | None = None


@dataclass
class SupportResult:
    decisions: dict[int, SupportDecision] = field(default_factory=dict)
    #: Invisible supporting planes registered per parent id (Sec. 2.2).
    inferred_planes: dict[int, list[SurfacePlane]] = field(default_factory=dict)
    #: Number of (child, plane) pairs whose contact area was measured.
    plane_tests: int = 0


def footprint_triangles(box: GravityBox) -> np.ndarray:
    """(2, 3, 2) triangles covering a box footprint (the region of an inferred plane)."""
    c = box.corners_xy()
    return np.stack([c[[0, 1, 2]], c[[0, 2, 3]]])


def _is(node: NodeFeatures, classes: Sequence[str]) -> bool:
    return node.node_class.class_name in classes


def _overlap_ratio(child: GravityBox, parent: GravityBox) -> float:
    """Share of the child's footprint over the parent's footprint (a point: inside or not)."""
    area = child.footprint_area
    if area <= EPS:
        local = parent.to_local_xy(child.center[:2])[0]
        return float(np.all(np.abs(local) <= 0.5 * parent.size[:2] + EPS))
    return float(np.clip(child.footprint_intersection(parent) / area, 0.0, 1.0))


class SupportInference:
    """Runs the bottom-up support estimation over initialised nodes."""

    def __init__(self, nodes: Mapping[int, NodeFeatures], neighbours: Mapping[int, set[int]],
                 cfg: SupportConfig) -> None:
        self.nodes = nodes
        self.neighbours = neighbours
        self.cfg = cfg
        self.result = SupportResult()
        self.floors = [i for i, n in nodes.items() if _is(n, cfg.floor_classes)]
        self.walls = [i for i, n in nodes.items() if _is(n, cfg.wall_classes)]

    # ------------------------------------------------------------------ helpers
    def _planes_of(self, node_id: int) -> list[SurfacePlane]:
        return self.nodes[node_id].planes + self.result.inferred_planes.get(node_id, [])

    def _is_ancestor(self, maybe_ancestor: int, node_id: int) -> bool:
        seen = set()
        cur = node_id
        while cur in self.result.decisions and cur not in seen:
            seen.add(cur)
            cur = self.result.decisions[cur].parent_id
            if cur == maybe_ancestor:
                return True
        return False

    def _candidates(self, child: NodeFeatures) -> list[int]:
        """Nodes whose bottoms are below the child's box bottom and whose footprints meet it.

        A layout child (a wall) only considers layout parents: a wall whose lower part hides
        behind a desk stands on the floor, not on the desk.
        """
        bottom = child.box.z_min
        out = []
        for j in sorted(self.neighbours.get(child.id, ())):
            cand = self.nodes[j]
            if cand.box.z_min > bottom + self.cfg.above_tolerance or self._is_ancestor(child.id, j):
                continue
            if child.category == LAYOUT and cand.category != LAYOUT:
                continue
            out.append(j)
        return out

    def _floor_under(self, child: NodeFeatures, candidates: list[int], grid) -> np.ndarray:
        """Cells of the child's footprint where the floor plane continues unseen under the child:
        no other candidate's footprint covers them (nothing can stand between the floor and the child)."""
        free = np.ones(len(grid.world), dtype=bool)
        for j in candidates:
            cand = self.nodes[j]
            if j in self.floors or cand.category == LAYOUT:
                continue
            local = cand.box.to_local_xy(grid.world)
            free &= ~np.all(np.abs(local) <= 0.5 * cand.box.size[:2] + EPS, axis=1)
        return free

    # ------------------------------------------------------------------ Eqs. (1)-(3)
    def _score_planes(self, child: NodeFeatures, candidates: list[int]) -> list[SupportDecision]:
        cfg = self.cfg
        box = child.box
        bottom = box.z_min
        grid = footprint_grid(box, cfg.grid_cell_size, cfg.grid_max_cells)
        entries: list[tuple[int, SurfacePlane, float]] = []
        covers = []
        floor_free = None
        for pid in candidates:
            main = None
            if cfg.floor_under_objects and pid in self.floors:  # the floor's dominant supporting plane
                sup = [sp for sp in self.nodes[pid].planes if sp.is_support(cfg.a_th)]
                main = max(sup, key=lambda sp: sp.plane.area) if sup else None
            for sp in self._planes_of(pid):
                if not sp.is_support(cfg.a_th):  # Eq. (1): n . g <= a_th
                    continue
                h = sp.height_at(box.center[:2])
                if not np.isfinite(h) or not bottom - cfg.max_gap <= h <= bottom + cfg.above_tolerance:
                    continue
                self.result.plane_tests += 1
                cov = triangles_cover(grid.world, sp.region_triangles,
                                      sp.region_bounds() if len(sp.region_triangles) else None)
                if len(sp.region_points):
                    cov |= points_cover(grid, sp.region_points)
                if sp is main:
                    if floor_free is None:
                        floor_free = self._floor_under(child, candidates, grid)
                    cov |= floor_free
                if cov.any():
                    entries.append((pid, sp, h))
                    covers.append(cov)
        if not entries:
            return []
        heights = np.array([h for _, _, h in entries])
        ratios = claimed_ratios(grid, np.stack(covers), heights)  # Eq. (2), higher surfaces first
        out = []
        for k, (pid, sp, h) in enumerate(entries):
            ratio = float(ratios[k])
            dist = bottom - h  # Eq. (1): D(v_c, pi) = p_c - (-d + s_c / 2)
            score = (1.0 - min(1.0, abs(dist) / cfg.distance_scale)) * ratio  # Eq. (3)
            out.append(SupportDecision(child.id, pid, "support", score, ratio, dist, sp))
        return out

    def _inferred(self, child: NodeFeatures, candidates: list[int],
                  scored: list[SupportDecision]) -> list[SupportDecision]:
        """Invisible supporting planes (Sec. 2.2): a candidate that the child is well overlapped with
        but that has no valid plane in contact with the child's bottom.

        "Well overlapped": the child's footprint lies at least b_th over the candidate's and its
        bottom is within the candidate's height range (above the candidate's bottom by at least
        ``inferred_min_height``, below its top plus ``invisible_max_gap``): an occluded table top,
        an unseen shelf level. The child's bottom becomes the candidate's new plane (D = 0).
        """
        cfg = self.cfg
        bottom = child.box.z_min
        in_contact = {d.parent_id for d in scored
                      if d.score > cfg.accept_score and abs(d.distance) <= cfg.contact_tolerance}
        out = []
        for pid in candidates:
            parent = self.nodes[pid]
            if pid in in_contact or parent.category == LAYOUT:
                continue
            if not parent.box.z_min + cfg.inferred_min_height <= bottom <= parent.box.z_max + cfg.invisible_max_gap:
                continue
            ratio = _overlap_ratio(child.box, parent.box)
            if ratio < cfg.b_th:
                continue
            score = ratio  # Eq. (3) with D = 0: the plane is registered at the child's bottom
            plane = SurfacePlane(Plane(normal=UP, d=-bottom, area=child.box.footprint_area),
                                 "inferred", footprint_triangles(parent.box))
            out.append(SupportDecision(child.id, pid, "inferred_plane", score, ratio, 0.0, plane))
        return out

    # ------------------------------------------------------------------ fallbacks (Sec. 6.5)
    def _floor_plane(self, floor_id: int, below: float) -> SurfacePlane | None:
        planes = [p for p in self._planes_of(floor_id) if p.is_support(self.cfg.a_th)]
        heights = [p.height_at(self.nodes[floor_id].box.center[:2]) for p in planes]
        ok = [(h, p) for h, p in zip(heights, planes, strict=True) if np.isfinite(h) and h <= below]
        return max(ok, key=lambda t: t[0])[1] if ok else None

    def _fallback(self, child: NodeFeatures) -> SupportDecision:
        cfg = self.cfg
        bottom = child.box.z_min
        floors = [f for f in self.floors if f != child.id and not self._is_ancestor(child.id, f)]
        floor = None
        if floors:  # the floor right below the child (largest footprint overlap, then the highest)
            floor = max(floors, key=lambda f: (_overlap_ratio(child.box, self.nodes[f].box), self.nodes[f].box.z_max))
            top = self.nodes[floor].box.z_max
            if bottom - top <= cfg.floor_height:
                plane = self._floor_plane(floor, bottom + cfg.above_tolerance)
                return SupportDecision(child.id, floor, "fallback_floor", 0.0, 0.0, bottom - top, plane)
        walls = [w for w in self.walls if w != child.id and not self._is_ancestor(child.id, w)]
        hangs = child.category != LAYOUT or _is(child, cfg.ceiling_classes)  # walls stand, ceilings hang
        if walls and hangs:
            dists = [polygon_distance(child.box.corners_xy(), self.nodes[w].box.corners_xy()) for w in walls]
            k = int(np.argmin(dists))
            if dists[k] <= cfg.wall_distance:
                return SupportDecision(child.id, walls[k], "fallback_wall", 0.0, 0.0, float(dists[k]), None)
        if floor is not None:
            # the last resort: a parent for the tree, but no contact: no plane, so box refinement does
            # not stretch an object floating over an unmapped support (a microwave on a kitchen
            # counter left unlabelled) down to the floor
            return SupportDecision(child.id, floor, "fallback_floor", 0.0, 0.0, bottom - self.nodes[floor].box.z_max,
                                   None)
        return SupportDecision(child.id, ROOT_ID, "fallback_root")

    # ------------------------------------------------------------------ main loop
    def decide(self, child: NodeFeatures) -> SupportDecision:
        cfg = self.cfg
        if _is(child, cfg.floor_classes):
            return SupportDecision(child.id, ROOT_ID, "root", 1.0, 1.0, 0.0, None)
        candidates = self._candidates(child)
        scored = self._score_planes(child, candidates)
        accepted = [d for d in scored if d.score > cfg.accept_score]
        touching = [d for d in accepted if abs(d.distance) <= cfg.contact_tolerance]
        if cfg.invisible_planes and not touching:  # nothing visible under the child's bottom
            accepted += [d for d in self._inferred(child, candidates, scored) if d.score > cfg.accept_score]
        if accepted:
            # Prefer planes that also meet Eq. (2) (A >= b_th), then the best Eq. (3) score.
            best = max(accepted, key=lambda d: (d.contact_ratio >= cfg.b_th, d.score, -abs(d.distance)))
            if best.kind == "inferred_plane" and best.plane is not None:
                self.result.inferred_planes.setdefault(best.parent_id, []).append(best.plane)
            return best
        return self._fallback(child)

    def run(self) -> SupportResult:
        order = sorted(self.nodes, key=lambda i: (self.nodes[i].box.z_min, i))
        for i in order:
            self.result.decisions[i] = self.decide(self.nodes[i])
        return self.result
