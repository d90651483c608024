"""A picture of a contact graph: top-down boxes with support arrows, and the parse tree.

Left: every node's refined box footprint (layout grey, rigid blue, articulated orange), arrows
from each supporting object to what it carries (edges to the floor/root are left out: every
standing object has one), proximal pairs as dotted lines. Right: the parse tree, one row per
depth, leaves spread in depth-first order, fixed joints solid and floating joints dashed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from recon_core.contact_graph import ContactGraph
from scene_graph.classify import ARTICULATED, LAYOUT, RIGID

COLORS = {LAYOUT: "#9e9e9e", RIGID: "#1f77b4", ARTICULATED: "#ff7f0e"}


def _tree_layout(graph: ContactGraph) -> dict[int, tuple[float, float]]:
    """x by depth-first leaf order (parents centred over their children), y = -depth."""
    pos: dict[int, tuple[float, float]] = {}
    next_x = [0.0]

    def place(nid: int, depth: int) -> float:
        kids = graph.children(nid)
        if not kids:
            x = next_x[0]
            next_x[0] += 1.0
        else:
            xs = [place(k, depth + 1) for k in kids]
            x = 0.5 * (min(xs) + max(xs))
        pos[nid] = (x, -float(depth))
        return x

    place(graph.root_id, 0)
    return pos


def draw_graph(graph: ContactGraph, path: str | Path, title: str = "") -> Path:
    """Write the picture (PNG) and return its path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Polygon as MplPolygon

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig, (ax_map, ax_tree) = plt.subplots(1, 2, figsize=(16, 8), gridspec_kw={"width_ratios": [1, 1.3]})
    # -------- top-down view
    order = sorted((n for n in graph.nodes.values() if n.box is not None),
                   key=lambda n: (n.category != LAYOUT, n.box.z_max))  # type: ignore[union-attr]
    for n in order:
        corners = n.box.corners_xy()  # type: ignore[union-attr]
        color = COLORS.get(n.category, "#2ca02c")
        ax_map.add_patch(MplPolygon(corners, closed=True, facecolor=color, alpha=0.15 if n.category == LAYOUT else 0.35,
                                    edgecolor=color, linewidth=1.0))
        if n.category != LAYOUT:
            c = n.box.center  # type: ignore[union-attr]
            ax_map.text(c[0], c[1], n.name, fontsize=6, ha="center", va="center")
    for child, edge in graph.supports.items():
        parent = graph.nodes.get(edge.parent_id)
        if parent is None or parent.box is None or parent.category == LAYOUT:
            continue
        a, b = parent.box.center[:2], graph.nodes[child].box.center[:2]  # type: ignore[union-attr]
        ax_map.annotate("", xy=b, xytext=a, arrowprops={"arrowstyle": "->", "color": "#d62728", "lw": 1.0})
    for i, j in graph.proximal:
        ni, nj = graph.nodes[i], graph.nodes[j]
        if ni.box is None or nj.box is None or LAYOUT in (ni.category, nj.category):
            continue
        ax_map.plot([ni.box.center[0], nj.box.center[0]], [ni.box.center[1], nj.box.center[1]], ":", color="#555",
                    lw=0.8)
    ax_map.set_aspect("equal")
    ax_map.autoscale_view()
    ax_map.set_xlabel("x (m)")
    ax_map.set_ylabel("y (m)")
    ax_map.set_title("top-down: boxes, support arrows (red), proximal pairs (dotted)")
    # -------- parse tree
    pos = _tree_layout(graph)
    for child, edge in graph.supports.items():
        (x0, y0), (x1, y1) = pos[edge.parent_id], pos[child]
        ax_tree.plot([x0, x1], [y0, y1], "-" if edge.joint == "fixed" else "--", color="#444", lw=0.8)
    for nid, (x, y) in pos.items():
        n = graph.nodes[nid]
        color = COLORS.get(n.category, "#2ca02c")
        ax_tree.scatter([x], [y], s=40, color=color, zorder=3)
        ax_tree.text(x, y - 0.12, n.name, fontsize=6, ha="center", va="top", rotation=60 if y < -1 else 0)
    xs = np.array([p[0] for p in pos.values()])
    ax_tree.set_xlim(xs.min() - 1, xs.max() + 1)
    ax_tree.set_ylim(min(p[1] for p in pos.values()) - 1.2, 0.5)
    ax_tree.axis("off")
    ax_tree.set_title("parse tree (solid: fixed joint, dashed: floating)")
    fig.suptitle(title or graph.name or "contact graph")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
