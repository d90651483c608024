"""The annotated contact graph cg_gt of a generated scene (what Sec. 5.3 compares against).

Supports, proximal pairs and boxes come straight from the generator's ground truth; the joints
follow the ground-truth URDF's rule (movable classes float, the rest is fixed).
"""

from __future__ import annotations

from pathlib import Path

from scene_recon.synthetic.scene import ROOT, GroundTruthScene

from .box import GravityBox
from .graph import ROOT_ID, ContactGraph, GraphNode, SupportEdge, root_node


def ground_truth_graph(scene: GroundTruthScene) -> ContactGraph:
    """cg_gt of a ground-truth scene (node ids = entity ids)."""
    ids = {e.name: e.id for e in scene.entities}
    ids[ROOT] = ROOT_ID
    graph = ContactGraph(name=scene.name, nodes={ROOT_ID: root_node()})
    for e in scene.entities:
        box = GravityBox.from_any(e.box) if e.box is not None else None
        graph.nodes[e.id] = GraphNode(e.id, e.name, e.class_name, e.category, e.class_id, box, box,
                                      movable=e.movable)
        graph.supports[e.id] = SupportEdge(ids[e.parent], e.id, "ground_truth", 1.0, 1.0, 0.0, None,
                                           "floating" if e.movable else "fixed")
    graph.proximal = sorted((min(ids[a], ids[b]), max(ids[a], ids[b])) for a, b in scene.proximal)
    graph.validate()
    return graph


def load_ground_truth_graph(folder: str | Path) -> ContactGraph:
    return ground_truth_graph(GroundTruthScene.load(folder))


def restrict_graph(graph: ContactGraph, keep: set[int]) -> ContactGraph:
    """The graph over the ``keep`` nodes only; a kept node whose parent is dropped hangs off its
    nearest kept ancestor (what the tree looks like to someone who never saw the dropped ones)."""
    out = ContactGraph(name=graph.name, frame_id=graph.frame_id, nodes={graph.root_id: graph.nodes[graph.root_id]},
                       root_id=graph.root_id)
    for nid, node in graph.nodes.items():
        if nid == graph.root_id or nid not in keep:
            continue
        out.nodes[nid] = node
        edge = graph.supports[nid]
        parent = edge.parent_id
        while parent != graph.root_id and parent not in keep:
            parent = graph.supports[parent].parent_id
        out.supports[nid] = SupportEdge(parent, nid, edge.kind, edge.score, edge.contact_ratio, edge.distance,
                                        edge.plane, edge.joint)
    out.proximal = [(a, b) for a, b in graph.proximal if a in out.nodes and b in out.nodes]
    out.validate()
    return out
