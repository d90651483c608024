"""The annotated contact graph cg_gt of a generated scene (what Sec. 5.3 compares against).

Supports, proximal pairs and boxes come straight from the generator's ground truth; the joints
follow the ground-truth URDF's rule (movable classes float, the rest is fixed).
"""

from __future__ import annotations

from pathlib import Path

from recon_core.contact_graph import ROOT_ID, ContactGraph, GraphNode, SupportEdge, root_node
from scene_recon.synthetic.scene import ROOT, GroundTruthScene


def ground_truth_graph(scene: GroundTruthScene) -> ContactGraph:
    """cg_gt of a ground-truth scene (node ids = entity ids)."""
    ids = {e.name: e.id for e in scene.entities}
    ids[ROOT] = ROOT_ID
    graph = ContactGraph(name=scene.name, nodes={ROOT_ID: root_node()})
    for e in scene.entities:
        box = e.box
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
    """The graph over the ``keep`` nodes only (``ContactGraph.restricted``)."""
    return graph.restricted(keep)


def seen_entity_ids(scene: GroundTruthScene, min_pixels: int) -> set[int] | None:
    """Ids of the entities the recording's camera saw at least ``min_pixels`` pixels of, over all frames
    (scene.json ``visible_pixels``); None when the ground truth does not record visibility."""
    if not any(e.visible_pixels > 0 for e in scene.entities):
        return None
    return {e.id for e in scene.entities if e.visible_pixels >= min_pixels}
