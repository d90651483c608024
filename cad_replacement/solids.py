"""Posed solids of placed objects and the penetration depth between them (signed distance).

Shared by the global physical check and the scene actions: both must agree on what "inside another
object" means. Link meshes are posed at the object's joint values; a closed link mesh is a solid
queried through an Open3D ray-casting scene (negative signed distance inside). With ``hulls`` the
links are replaced by their convex hulls (what a collision checker on visual meshes sees).
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
import open3d.core as o3c

from cad_replacement.scene_model import PlacedObject


class ObjectSolids:
    """Posed link meshes of one object with their bounds and (lazily) a signed-distance scene."""

    def __init__(self, obj: PlacedObject, hulls: bool) -> None:
        self.name = obj.name
        meshes = []
        for m in obj.model.posed_link_meshes(obj.joint_values).values():
            if len(m.faces):
                posed = m.copy()
                posed.apply_transform(obj.pose)
                meshes.append(posed.convex_hull if hulls else posed)
        self.meshes = meshes
        verts = np.concatenate([m.vertices for m in meshes]) if meshes else np.zeros((0, 3))
        self.vertices = verts
        self.lo = verts.min(axis=0) if len(verts) else obj.pose[:3, 3].copy()
        self.hi = verts.max(axis=0) if len(verts) else obj.pose[:3, 3].copy()
        self._scenes: list[o3d.t.geometry.RaycastingScene] | None = None

    def scenes(self) -> list[o3d.t.geometry.RaycastingScene]:
        if self._scenes is None:
            self._scenes = []
            for m in self.meshes:
                if not m.is_watertight:
                    continue
                rs = o3d.t.geometry.RaycastingScene()
                rs.add_triangles(o3c.Tensor(np.asarray(m.vertices, np.float32)),
                                 o3c.Tensor(np.asarray(m.faces, np.uint32)))
                self._scenes.append(rs)
        return self._scenes

    def overlaps(self, other: ObjectSolids, margin: float = 0.0) -> bool:
        return bool(np.all(self.lo - margin <= other.hi) and np.all(other.lo - margin <= self.hi))

    def depth_into(self, other: ObjectSolids) -> float:
        """Deepest point of this object's surface inside ``other``'s solids (m, 0 when outside)."""
        if not len(self.vertices):
            return 0.0
        inside = np.all((self.vertices >= other.lo) & (self.vertices <= other.hi), axis=1)
        if not np.any(inside):
            return 0.0
        query = o3c.Tensor(self.vertices[inside].astype(np.float32))
        depth = 0.0
        for rs in other.scenes():
            depth = max(depth, float(-rs.compute_signed_distance(query).numpy().min()))
        return depth


def _penetration(a: ObjectSolids, b: ObjectSolids) -> float:
    return max(a.depth_into(b), b.depth_into(a))


def penetration_between(a: ObjectSolids, b: ObjectSolids) -> float:
    """Deepest point of either object inside the other (m); 0 when their bounds do not meet."""
    if not a.overlaps(b):
        return 0.0
    return max(a.depth_into(b), b.depth_into(a))


__all__ = ["ObjectSolids", "penetration_between"]
