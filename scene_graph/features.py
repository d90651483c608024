"""Per-node initialisation (paper Sec. 2.2): class, category, minimal gravity-aligned box, planes.

This is the per-entity work of the builder and does not depend on other entities, so an
incremental consumer (the ROS node) caches it per (entity id, revision).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import trimesh

from recon_core.entity import Entity, EntityError
from recon_core.geometry.box import GravityBox
from recon_core.geometry.box_fit import fit_gravity_box
from scene_graph.classify import NodeClass, classify
from scene_graph.config import SceneGraphConfig
from scene_graph.planes import SurfacePlane, detect_planes


@dataclass(eq=False)
class NodeFeatures:
    """An initialised node: the entity, its class, its unrefined box and its surface planes."""

    entity: Entity
    node_class: NodeClass
    box: GravityBox
    planes: list[SurfacePlane] = field(default_factory=list)

    @property
    def id(self) -> int:
        return self.entity.id

    @property
    def name(self) -> str:
        return self.entity.name

    @property
    def category(self) -> str:
        return self.node_class.category


def _box_points(entity: Entity, samples: int, seed: int) -> np.ndarray:
    if samples <= 0 or not entity.has_faces:
        return entity.vertices
    mesh = trimesh.Trimesh(entity.vertices, entity.faces, process=False)
    if mesh.area <= 0.0:
        return entity.vertices
    pts, _ = trimesh.sample.sample_surface(mesh, samples, seed=seed)
    return np.r_[entity.vertices, np.asarray(pts, np.float64)]


def compute_features(entity: Entity, cfg: SceneGraphConfig) -> NodeFeatures:
    """Box and planes of one entity; raises ``EntityError`` for an entity without geometry."""
    if entity.is_empty:
        raise EntityError(f"entity {entity.name!r} ({entity.id}) has no geometry")
    node_class = classify(entity.class_name, entity.category, cfg.class_table)
    # Box and planes from the voted core (``Entity.core_mesh``): the mapper's fringe fill joins
    # background along depth edges, which would inflate a small object's box and add its planes.
    core = entity
    if entity.core_vertices >= 0:
        v, f = entity.core_mesh()
        if len(f) < len(entity.faces):
            core = dataclasses.replace(entity, vertices=v, faces=f, core_vertices=-1)
    points = _box_points(core, cfg.box.surface_samples, cfg.planes.seed)
    box = fit_gravity_box(points, cfg.box.trim_percent)
    diag = float(np.linalg.norm(box.size))
    planes = detect_planes(core, cfg.planes, cfg.support.a_th, box_diagonal=diag)
    return NodeFeatures(entity, node_class, box, planes)
