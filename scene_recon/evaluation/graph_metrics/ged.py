"""Graph edit distance between an inferred and an annotated contact graph (paper Sec. 5.3, Table 5).

Operations (unit cost): insert / remove a node, insert / remove an edge, substitute a node label.
After the geometric node matching (``matching.py``) the errors are counted as in Table 5:

* wrong support: a matched node whose parent is wrong - removing and adding an edge, 2 operations;
  the parent is compared through the nearest *matched* ancestors, so an unmatched node in between
  is charged once as a missing / extra node and not again to each of its children;
* missing detection: a ground-truth node with no match - 1 (insert it; it adopts its children);
* wrong detection: a predicted node with no match (1, remove it) or matched across classes
  (1, substitute the label);

    total = 2 * wrong_support + missing + wrong_detection        (Table 5: 12 = 2*1 + 5 + 5 for 225)

The parse tree is a tree, so the exact tree edit distance (unordered trees: a mapping must keep
ancestry, Zhang et al. 1992) under the matching is computed too: the matched pairs that can stay
mapped form the largest ancestry-consistent subset, found exactly as a minimum weighted vertex
cover of the pairwise conflicts by branch and bound (conflicts are few: one per wrong support).
Every dropped pair costs a removal plus an insertion. The two agree in the simple cases (a leaf
on the wrong parent, a missing leaf); they differ when one move fixes several ancestries.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from recon_core.contact_graph import ContactGraph
from scene_graph.config import MatchConfig
from scene_recon.evaluation.graph_metrics.matching import NodeMatching, match_nodes

#: Beyond this many conflicting pairs the vertex cover falls back to a greedy bound (flagged).
MAX_EXACT_CONFLICT_NODES = 60


@dataclass
class GedResult:
    """Edit counts; ``total`` is Table 5's distance, ``tree_edit_distance`` the exact TED."""

    gt_nodes: int
    pred_nodes: int
    total: int
    wrong_support: int
    missing: int
    wrong_detection: int
    substitutions: int
    tree_edit_distance: int
    ted_exact: bool = True
    wrong_support_nodes: list[str] = field(default_factory=list)
    missing_nodes: list[str] = field(default_factory=list)
    extra_nodes: list[str] = field(default_factory=list)

    @property
    def ratio(self) -> float:
        """Total distance per ground-truth node (0 when the ground truth is empty)."""
        return self.total / self.gt_nodes if self.gt_nodes else 0.0

    def to_dict(self) -> dict[str, Any]:
        return {"gt_nodes": self.gt_nodes, "pred_nodes": self.pred_nodes, "total": self.total,
                "ratio": self.ratio, "wrong_support": self.wrong_support, "missing": self.missing,
                "wrong_detection": self.wrong_detection, "substitutions": self.substitutions,
                "tree_edit_distance": self.tree_edit_distance, "ted_exact": self.ted_exact,
                "wrong_support_nodes": self.wrong_support_nodes, "missing_nodes": self.missing_nodes,
                "extra_nodes": self.extra_nodes}


def _nearest_matched_ancestor(graph: ContactGraph, node: int, matched: set[int]) -> int | None:
    cur = graph.parent(node)
    while cur is not None and cur not in matched:
        cur = graph.parent(cur)
    return cur


def _ancestor_sets(graph: ContactGraph) -> dict[int, set[int]]:
    return {n: set(graph.ancestors(n)) for n in graph.nodes}


def _min_weight_vertex_cover(nodes: list[int], edges: set[tuple[int, int]],
                             weight: dict[int, int]) -> tuple[int, bool]:
    """Exact minimum weighted vertex cover by branch and bound (greedy beyond the size cap)."""
    adj: dict[int, set[int]] = {n: set() for n in nodes}
    for a, b in edges:
        adj[a].add(b)
        adj[b].add(a)
    if len(nodes) > MAX_EXACT_CONFLICT_NODES:
        cost, live = 0, {n: set(s) for n, s in adj.items()}
        while any(live.values()):
            v = max(live, key=lambda n: len(live[n]) / weight[n])
            cost += weight[v]
            for u in live.pop(v):
                live[u].discard(v)
        return cost, False

    best = [sum(weight[n] for n in nodes if adj[n])]

    def solve(live: dict[int, set[int]], cost: int) -> None:
        live = {n: s for n, s in live.items() if s}
        if cost >= best[0]:
            return
        if not live:
            best[0] = cost
            return
        v = max(live, key=lambda n: len(live[n]))
        # Branch 1: v in the cover.
        rest = {n: s - {v} for n, s in live.items() if n != v}
        solve(rest, cost + weight[v])
        # Branch 2: v not in the cover -> all its neighbours are.
        nbrs = live[v]
        rest = {n: s - nbrs - {v} for n, s in live.items() if n != v and n not in nbrs}
        solve(rest, cost + sum(weight[u] for u in nbrs))

    solve(adj, 0)
    return best[0], True


def constrained_tree_edit_distance(pred: ContactGraph, gt: ContactGraph, matching: NodeMatching) -> tuple[int, bool]:
    """Exact unordered tree edit distance among mappings that use only the matched pairs."""
    pairs = {p: g for p, g in matching.pred_to_gt.items() if p != pred.root_id}
    anc_p, anc_g = _ancestor_sets(pred), _ancestor_sets(gt)
    ids = sorted(pairs)
    conflicts: set[tuple[int, int]] = set()
    for i, a in enumerate(ids):
        for b in ids[i + 1:]:
            ga, gb = pairs[a], pairs[b]
            if (a in anc_p[b]) != (ga in anc_g[gb]) or (b in anc_p[a]) != (gb in anc_g[ga]):
                conflicts.add((a, b))
    # Dropping a pair: remove + insert (2); a substituted pair already costs 1, so dropping adds 1.
    weight = {p: 2 - (p in matching.substituted) for p in ids}
    involved = sorted({n for e in conflicts for n in e})
    cover, exact = _min_weight_vertex_cover(involved, conflicts, weight) if conflicts else (0, True)
    unmatched_pred = len(pred.nodes) - len(matching.pred_to_gt)
    unmatched_gt = len(gt.nodes) - len(matching.pred_to_gt)
    return unmatched_pred + unmatched_gt + len(matching.substituted) + cover, exact


def graph_edit_distance(pred: ContactGraph, gt: ContactGraph, cfg: MatchConfig | None = None,
                        matching: NodeMatching | None = None) -> GedResult:
    """GED of Table 5 (and the exact constrained TED) between an inferred and an annotated graph."""
    matching = matching or match_nodes(pred, gt, cfg)
    p2g = matching.pred_to_gt
    matched_p, matched_g = set(p2g), set(p2g.values())
    wrong = []
    for p, g in p2g.items():
        if p == pred.root_id:
            continue
        pa = _nearest_matched_ancestor(pred, p, matched_p)
        ga = _nearest_matched_ancestor(gt, g, matched_g)
        if pa is None or p2g.get(pa) != ga:
            wrong.append(p)
    missing = sorted(g for g in gt.nodes if g not in matched_g)
    extra = sorted(p for p in pred.nodes if p not in matched_p)
    wrong_detection = len(extra) + len(matching.substituted)
    ted, exact = constrained_tree_edit_distance(pred, gt, matching)
    return GedResult(
        gt_nodes=len(gt.nodes) - 1, pred_nodes=len(pred.nodes) - 1,
        total=2 * len(wrong) + len(missing) + wrong_detection,
        wrong_support=len(wrong), missing=len(missing), wrong_detection=wrong_detection,
        substitutions=len(matching.substituted), tree_edit_distance=ted, ted_exact=exact,
        wrong_support_nodes=sorted(pred.nodes[p].name for p in wrong),
        missing_nodes=[gt.nodes[g].name for g in missing],
        # A substitution names the ground-truth node it was matched to (geometry, never the id).
        extra_nodes=[pred.nodes[p].name for p in extra] + sorted(
            f"{pred.nodes[p].name} (as {gt.nodes[p2g[p]].name})" for p in matching.substituted),
    )
