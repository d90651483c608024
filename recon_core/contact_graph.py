"""The contact graph cg = (pt, E) (paper Sec. 2.1): parse tree of supports plus proximal edges.

Plain data with a JSON round trip (``contact_graph.json``) and a readable tree print-out. The
root is the scene node (id 0, ``ROOT_NAME``); every other node has exactly one support edge
(its parent), so the parse tree is a tree by construction (``validate`` checks it).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from recon_core.errors import GraphError
from recon_core.geometry.box import GravityBox
from recon_core.geometry.plane import Plane, SurfacePlane

ROOT_ID = 0
ROOT_NAME = "scene"
#: Category of the root node (not a class-table category).
SCENE = "scene"
GRAPH_FORMAT = "scene_recon.contact_graph"
GRAPH_VERSION = 1


@dataclass(eq=False)
class GraphNode:
    """A node v_i = <o_i, c_i, M_i, B_i, Pi_i>: id, class, category, boxes and surface planes.

    ``box`` is the refined box (Sec. 2.2), ``box_unrefined`` the minimal box of the mesh alone.
    The mesh M_i stays with the entity (the builder's input), not in the graph.
    """

    id: int
    name: str
    class_name: str
    category: str
    class_id: int = -1
    box: GravityBox | None = None
    box_unrefined: GravityBox | None = None
    planes: list[SurfacePlane] = field(default_factory=list)
    confidence: float = 1.0
    movable: bool = False
    cad_id: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id, "name": self.name, "class_name": self.class_name, "class_id": self.class_id,
            "category": self.category, "confidence": self.confidence, "movable": self.movable,
            "cad_id": self.cad_id,
            "box": self.box.to_dict() if self.box else None,
            "box_unrefined": self.box_unrefined.to_dict() if self.box_unrefined else None,
            "planes": [p.to_dict() for p in self.planes],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> GraphNode:
        box = GravityBox.from_dict(d["box"]) if d.get("box") else None
        unrefined = GravityBox.from_dict(d["box_unrefined"]) if d.get("box_unrefined") else None
        return cls(int(d["id"]), d["name"], d["class_name"], d["category"], int(d.get("class_id", -1)), box,
                   unrefined, [SurfacePlane.from_dict(p) for p in d.get("planes", [])],
                   float(d.get("confidence", 1.0)), bool(d.get("movable", False)), d.get("cad_id", ""))


@dataclass(eq=False)
class SupportEdge:
    """s_{p,c}: parent supports child on ``plane``, with its Eq. (3) score and the joint it becomes."""

    parent_id: int
    child_id: int
    kind: str = "support"
    score: float = 0.0
    contact_ratio: float = 0.0
    distance: float = 0.0
    plane: Plane | None = None
    joint: str = "fixed"

    def to_dict(self) -> dict[str, Any]:
        return {"parent": self.parent_id, "child": self.child_id, "kind": self.kind, "score": self.score,
                "contact_ratio": self.contact_ratio, "distance": self.distance, "joint": self.joint,
                "plane": self.plane.to_dict() if self.plane is not None else None}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SupportEdge:
        plane = Plane.from_dict(d["plane"]) if d.get("plane") else None
        return cls(int(d["parent"]), int(d["child"]), d.get("kind", "support"), float(d.get("score", 0.0)),
                   float(d.get("contact_ratio", 0.0)), float(d.get("distance", 0.0)), plane, d.get("joint", "fixed"))


def root_node() -> GraphNode:
    return GraphNode(ROOT_ID, ROOT_NAME, ROOT_NAME, SCENE)


@dataclass(eq=False)
class ContactGraph:
    """Nodes by id (the root included), support edges by child id, proximal pairs (a < b)."""

    nodes: dict[int, GraphNode] = field(default_factory=lambda: {ROOT_ID: root_node()})
    supports: dict[int, SupportEdge] = field(default_factory=dict)
    proximal: list[tuple[int, int]] = field(default_factory=list)
    name: str = ""
    frame_id: str = "map"
    #: Entities that could not become nodes, with the reason (empty mesh, ...).
    skipped: dict[int, str] = field(default_factory=dict)
    #: Build figures (timings, pair counts); informative only.
    stats: dict[str, Any] = field(default_factory=dict)

    root_id: int = ROOT_ID

    # ------------------------------------------------------------------ structure
    def parent(self, node_id: int) -> int | None:
        edge = self.supports.get(node_id)
        return None if edge is None else edge.parent_id

    def parents(self) -> dict[int, int]:
        return {c: e.parent_id for c, e in self.supports.items()}

    def children(self, node_id: int) -> list[int]:
        return sorted((c for c, e in self.supports.items() if e.parent_id == node_id),
                      key=lambda c: (self.nodes[c].name, c))

    def walk(self) -> Iterator[tuple[int, int]]:
        """(node id, depth) in depth-first order from the root."""
        kids: dict[int, list[int]] = {}
        for c, e in self.supports.items():
            kids.setdefault(e.parent_id, []).append(c)
        stack = [(self.root_id, 0)]
        while stack:
            nid, depth = stack.pop()
            yield nid, depth
            for c in sorted(kids.get(nid, []), key=lambda c: (self.nodes[c].name, c), reverse=True):
                stack.append((c, depth + 1))

    def by_name(self, name: str) -> GraphNode:
        for n in self.nodes.values():
            if n.name == name:
                return n
        raise KeyError(f"no node named {name!r}")

    def ancestors(self, node_id: int) -> list[int]:
        out, cur = [], self.parent(node_id)
        while cur is not None:
            out.append(cur)
            if len(out) > len(self.nodes):
                raise GraphError(f"cycle above node {node_id}")
            cur = self.parent(cur)
        return out

    def validate(self) -> None:
        """Raise ``GraphError`` unless the support edges form one tree rooted at the root node."""
        if self.root_id not in self.nodes:
            raise GraphError("the root node is missing")
        if self.root_id in self.supports:
            raise GraphError("the root node cannot have a parent")
        for nid in self.nodes:
            if nid == self.root_id:
                continue
            edge = self.supports.get(nid)
            if edge is None:
                raise GraphError(f"node {nid} ({self.nodes[nid].name}) has no support edge")
            if edge.parent_id not in self.nodes:
                raise GraphError(f"node {nid} has an unknown parent {edge.parent_id}")
            if self.ancestors(nid)[-1] != self.root_id:
                raise GraphError(f"node {nid} is not connected to the root")
        unknown = [c for c in self.supports if c not in self.nodes]
        if unknown:
            raise GraphError(f"support edges for unknown nodes {unknown}")
        for a, b in self.proximal:
            if a not in self.nodes or b not in self.nodes:
                raise GraphError(f"proximal edge ({a}, {b}) names an unknown node")

    def restricted(self, keep: set[int]) -> ContactGraph:
        """The graph over the ``keep`` nodes only; a kept node whose parent is dropped hangs off its
        nearest kept ancestor (what the tree looks like to someone who never saw the dropped ones)."""
        out = ContactGraph(name=self.name, frame_id=self.frame_id, nodes={self.root_id: self.nodes[self.root_id]},
                           root_id=self.root_id)
        for nid, node in self.nodes.items():
            if nid == self.root_id or nid not in keep:
                continue
            out.nodes[nid] = node
            edge = self.supports[nid]
            parent = edge.parent_id
            while parent != self.root_id and parent not in keep:
                parent = self.supports[parent].parent_id
            out.supports[nid] = SupportEdge(parent, nid, edge.kind, edge.score, edge.contact_ratio, edge.distance,
                                            edge.plane, edge.joint)
        out.proximal = [(a, b) for a, b in self.proximal if a in out.nodes and b in out.nodes]
        out.validate()
        return out

    # ------------------------------------------------------------------ presentation
    def format_tree(self, scores: bool = True) -> str:
        """Indented parse tree: name [class, category] and, per edge, score, joint and kind."""
        lines = []
        for nid, depth in self.walk():
            n = self.nodes[nid]
            if nid == self.root_id:
                lines.append(n.name)
                continue
            e = self.supports[nid]
            text = f"{'  ' * depth}{n.name} [{n.class_name}, {n.category}]"
            if scores:
                text += f"  score {e.score:.2f}  {e.joint}"
                if e.kind not in ("support", "root"):
                    text += f"  ({e.kind})"
            lines.append(text)
        if self.proximal:
            lines.append(f"proximal relations: {len(self.proximal)}")
        if self.skipped:
            lines.append("skipped: " + ", ".join(f"{i} ({r})" for i, r in sorted(self.skipped.items())))
        return "\n".join(lines)

    # ------------------------------------------------------------------ persistence
    def to_dict(self) -> dict[str, Any]:
        return {
            "format": GRAPH_FORMAT, "version": GRAPH_VERSION, "name": self.name, "frame_id": self.frame_id,
            "root_id": self.root_id,
            "nodes": [self.nodes[i].to_dict() for i in sorted(self.nodes)],
            "support_edges": [self.supports[c].to_dict() for c in sorted(self.supports)],
            "proximal_edges": [list(p) for p in self.proximal],
            "skipped": {str(k): v for k, v in sorted(self.skipped.items())},
            "stats": self.stats,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ContactGraph:
        if d.get("format") != GRAPH_FORMAT or d.get("version") != GRAPH_VERSION:
            raise GraphError(f"not a contact graph v{GRAPH_VERSION} document "
                             f"(format={d.get('format')!r}, version={d.get('version')!r})")
        nodes = {n.id: n for n in (GraphNode.from_dict(x) for x in d["nodes"])}
        supports = {e.child_id: e for e in (SupportEdge.from_dict(x) for x in d.get("support_edges", []))}
        graph = cls(nodes, supports, [(int(a), int(b)) for a, b in d.get("proximal_edges", [])],
                    d.get("name", ""), d.get("frame_id", "map"),
                    {int(k): v for k, v in d.get("skipped", {}).items()}, d.get("stats", {}),
                    int(d.get("root_id", ROOT_ID)))
        graph.validate()
        return graph

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.to_dict(), indent=1), encoding="utf-8")
        return path

    @classmethod
    def load(cls, path: str | Path) -> ContactGraph:
        path = Path(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise GraphError(f"{path}: invalid JSON: {exc}") from exc
        return cls.from_dict(data)
