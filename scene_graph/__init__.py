"""Contact graphs (paper Sec. 2): boxes, planes, support and proximal relations. ROS-free.

Public API
----------
Input: ``recon_core.entity.Entity`` (map frame, z up; id 0 is reserved for the root), read from a
    mapped-scene folder with ``recon_core.entity.load_entities``.

Building (``builder``; config ``config/scene_graph.yaml`` -> ``SceneGraphConfig``):
    build_contact_graph(entities, cfg=None, joints=None, name="", frame_id="map") -> ContactGraph
    ContactGraphBuilder(cfg, joints): .update(entities) (recomputes only new (id, revision)),
        .remove(ids), .build() -> ContactGraph
    Steps: split_layout (layout: the map's one "wall" entity -> one node per wall, new ids; stray
    layout faces dropped), drop_fragments (fragments: small far pieces of object meshes),
    fit_gravity_box (box_fit), detect_planes (planes: RANSAC reused from cad_replacement + height
    groups), fragment_hosts (merge: same-class over-segmented nodes joined), SupportInference
    (support: Eqs. (1)-(3), invisible planes, the floor continuing under the objects it hides,
    floor/wall fallbacks), refine_box (refine), proximal_relations (proximal: sweep + exact test).
    The mapped-input steps are deviations from the paper (config/scene_graph.yaml says which);
    ground-truth meshes pass them unchanged.

Graph (``recon_core.contact_graph``): ContactGraph(nodes, supports, proximal) with GraphNode (box refined and
    unrefined, planes) and SupportEdge (plane, score, joint); .validate(), .format_tree(),
    .save(path) / ContactGraph.load(path) (JSON), .parents(), .children(id), .walk().
Kinematic tree (``kinematic``, ``joints``): to_kinematic_tree(graph, entities_by_id) -> KinematicTree
    (URDF via .to_urdf); SupportJointTable from ``config/support_joints.yaml`` decides fixed/floating.
Picture: draw.draw_graph (PNG). Evaluation against ground truth lives in the tool layer
    (``scene_recon.evaluation``: graph metrics, GED, box mAP, observed entities).
"""

from recon_core.contact_graph import ROOT_ID, ContactGraph, GraphError, GraphNode, SupportEdge
from recon_core.entity import Entity
from recon_core.errors import EntityError
from recon_core.geometry.box import GravityBox
from scene_graph.builder import ContactGraphBuilder, build_contact_graph
from scene_graph.config import SceneGraphConfig, load_scene_graph_config
from scene_graph.kinematic import to_kinematic_tree

__all__ = [
    "ROOT_ID",
    "ContactGraph",
    "ContactGraphBuilder",
    "Entity",
    "EntityError",
    "GraphError",
    "GraphNode",
    "GravityBox",
    "SceneGraphConfig",
    "SupportEdge",
    "build_contact_graph",
    "load_scene_graph_config",
    "to_kinematic_tree",
]
