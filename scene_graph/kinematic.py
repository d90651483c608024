"""Contact graph -> kinematic tree (paper Sec. 2.3 / 4.5), before any CAD replacement.

Every node becomes a link carrying the node's own mesh; every support edge becomes the joint
from the parent's link to the child's, fixed or floating as the edge says (``joints.py``). A
link's frame sits at the bottom centre of the node's refined box, turned by the box's yaw, so a
floating joint's origin is the object's resting pose on its parent. CAD replacement later swaps
the meshes for CAD models and adds their own revolute/prismatic joints.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import trimesh

from recon_core.contact_graph import ContactGraph
from recon_core.entity import Entity
from recon_core.kinematic_tree import Joint, KinematicTree, TreeLink
from scene_graph.classify import LAYOUT


def link_pose(graph: ContactGraph, node_id: int) -> np.ndarray:
    """4x4 pose of a node's link in the map frame (identity for the root and for box-less nodes)."""
    node = graph.nodes[node_id]
    if node_id == graph.root_id or node.box is None:
        return np.eye(4)
    return node.box.bottom_pose()


def to_kinematic_tree(graph: ContactGraph, entities: Mapping[int, Entity] | None = None,
                      object_mass: float = 5.0) -> KinematicTree:
    """The graph as a kinematic tree; ``entities`` (by id) give the link meshes (none: no geometry)."""
    graph.validate()
    entities = entities or {}
    poses = {nid: link_pose(graph, nid) for nid in graph.nodes}
    names = {nid: n.name for nid, n in graph.nodes.items()}
    links = [TreeLink(names[graph.root_id])]
    joints = []
    for nid, _depth in graph.walk():  # parents before children
        if nid == graph.root_id:
            continue
        node = graph.nodes[nid]
        mesh = None
        ent = entities.get(nid)
        if ent is not None and ent.has_faces:
            mesh = trimesh.Trimesh(ent.vertices, ent.faces, process=False)
            mesh.apply_transform(np.linalg.inv(poses[nid]))
        mass = 0.0 if node.category == LAYOUT else float(object_mass)
        links.append(TreeLink(node.name, mesh, mass))
        edge = graph.supports[nid]
        origin = np.linalg.inv(poses[edge.parent_id]) @ poses[nid]
        joints.append(Joint(f"{names[edge.parent_id]}__to__{node.name}", edge.joint, names[edge.parent_id],
                                node.name, origin))
    tree = KinematicTree(graph.name or "scene", names[graph.root_id], links, joints)
    tree.validate()
    return tree
