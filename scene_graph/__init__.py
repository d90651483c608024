"""Contact graphs (paper Sec. 2): boxes, planes, support and proximal relations. ROS-free.

Public API
----------
Input (``entity``, ``scene_io``):
    Entity(id, name, class_name, vertices, faces=(), class_id=-1, category="", is_thing=True,
           confidence=1.0, revision=0)            map frame, z up; id 0 is reserved for the root
    entities_from_ground_truth(GroundTruthScene) -> [Entity]      complete meshes (cg_map setting)
    load_source(path) -> EntitySource             ground-truth folder (scene.json) or mapped-scene
    write_entities(folder, entities) / read_entities(folder)      folder (entities.json + meshes/<id>.ply)

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

Graph (``graph``): ContactGraph(nodes, supports, proximal) with GraphNode (box refined and
    unrefined, planes) and SupportEdge (plane, score, joint); .validate(), .format_tree(),
    .save(path) / ContactGraph.load(path) (JSON), .parents(), .children(id), .walk().
Ground truth (``ground_truth``): ground_truth_graph(scene), restrict_graph(graph, keep_ids).
Kinematic tree (``kinematic``, ``joints``): to_kinematic_tree(graph, entities_by_id) -> KinematicTree
    (URDF via .to_urdf); SupportJointTable from ``config/support_joints.yaml`` decides fixed/floating.
Metrics (``metrics``): match_nodes (objects: IoU / containment; layout: class + containment of the
    observed part), graph_edit_distance (Table 5 + exact tree edit distance), box_map (Table 4,
    exact yaw-box IoU), evaluate_graph(pred, gt, seen=None) (with ``seen``: also the figures
    restricted to what the recording saw, ground_truth.seen_entity_ids / restrict_to_seen).
Evaluation helpers: observed.observed_entities (what a recording saw), evaluation (python -m
    scene_graph.evaluation), draw.draw_graph (PNG).
"""

from .box import GravityBox
from .builder import ContactGraphBuilder, build_contact_graph
from .config import SceneGraphConfig, load_scene_graph_config
from .entity import Entity, EntityError, entities_from_ground_truth
from .graph import ROOT_ID, ContactGraph, GraphError, GraphNode, SupportEdge
from .kinematic import to_kinematic_tree

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
    "entities_from_ground_truth",
    "load_scene_graph_config",
    "to_kinematic_tree",
]
