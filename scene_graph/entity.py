"""The builder's input: one scene entity (object or layout element) with its geometry in the map frame.

Kept deliberately small (id, name, class, vertices + optional faces) so that every producer can
make it: the ground truth of a generated scene (the paper's cg_map setting), the panoptic mapper's
meshes, a ``PanopticEntityArray`` message. The map frame is gravity aligned with z up.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:
    from scene_recon.synthetic.scene import GroundTruthScene, SceneEntity


class EntityError(ValueError):
    """An entity cannot be turned into a graph node (no geometry, non-finite values)."""


@dataclass(eq=False)
class Entity:
    """A segmented scene entity: vertices (N, 3) in the map frame and optional triangles (M, 3).

    ``category`` may be left empty: the builder then takes it from the class table.
    ``revision`` lets incremental consumers rebuild only entities whose geometry changed.
    """

    id: int
    name: str
    class_name: str
    vertices: NDArray[np.float64]
    faces: NDArray[np.int64] = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    class_id: int = -1
    category: str = ""
    is_thing: bool = True
    confidence: float = 1.0
    revision: int = 0

    def __post_init__(self) -> None:
        v = np.asarray(self.vertices, dtype=np.float64)
        v = v.reshape(-1, 3) if v.size else np.zeros((0, 3))
        f = np.asarray(self.faces, dtype=np.int64)
        f = f.reshape(-1, 3) if f.size else np.zeros((0, 3), np.int64)
        if not np.all(np.isfinite(v)):
            raise EntityError(f"entity {self.name!r} ({self.id}): non-finite vertex coordinates")
        if len(f) and (f.min() < 0 or f.max() >= len(v)):
            raise EntityError(f"entity {self.name!r} ({self.id}): face index out of range")
        self.vertices, self.faces = v, f
        self.id = int(self.id)

    @property
    def has_faces(self) -> bool:
        return len(self.faces) > 0

    @property
    def is_empty(self) -> bool:
        return len(self.vertices) == 0

    def mesh(self) -> trimesh.Trimesh:
        """The geometry as a trimesh (no processing: indices stay as given)."""
        return trimesh.Trimesh(self.vertices, self.faces, process=False)

    @classmethod
    def from_mesh(cls, id: int, name: str, class_name: str, mesh: trimesh.Trimesh, **kw) -> Entity:
        return cls(id, name, class_name, np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64), **kw)

    @classmethod
    def from_points(cls, id: int, name: str, class_name: str, points: ArrayLike, **kw) -> Entity:
        return cls(id, name, class_name, np.asarray(points, np.float64), **kw)

    @classmethod
    def from_scene_entity(cls, e: SceneEntity, mesh: trimesh.Trimesh | None = None) -> Entity:
        """A ground-truth entity (optionally with a replacement mesh, e.g. its observed part)."""
        m = e.mesh if mesh is None else mesh
        return cls(e.id, e.name, e.class_name, np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64),
                   class_id=e.class_id, category=e.category, is_thing=e.is_thing)


def entities_from_ground_truth(scene: GroundTruthScene) -> list[Entity]:
    """Every entity of a ground-truth scene with its complete mesh (the paper's cg_map setting)."""
    return [Entity.from_scene_entity(e) for e in scene.entities]
