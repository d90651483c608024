"""A replaced scene as one kinematic tree (root ``map``): what URDF, TF and joint states publish.

Every object contributes its CAD model's links (named ``<object>__<link>``; the root link takes the
object's own name, so TF frames read ``map -> table_1 -> cup_2``) and its revolute/prismatic joints;
it hangs off the link that carries it by a fixed joint (layout, furniture) or a floating joint
(movable things), whose origin is the object's pose relative to that link at the current joint
values. Masses come from volume x class density (``cad.urdf_export.model_tree``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from cad_replacement.cad.urdf_export import DEFAULT_DENSITY, model_tree
from cad_replacement.scene_model import MAP_ROOT, PlacedObject, ReplacedScene
from recon_core.classes import ClassTable, load_class_table
from recon_core.errors import UnknownClassError
from recon_core.geometry.transforms import invert_rigid
from recon_core.kinematic_tree import Joint, KinematicTree, TreeLink


def link_name(obj: PlacedObject, link: str) -> str:
    """Tree name of one of ``obj``'s links: the root link carries the object's name."""
    return obj.name if link == obj.model.root_link else f"{obj.name}__{link}"


def _density(class_name: str, table: ClassTable) -> float:
    try:
        value = table.by_name(class_name).density
    except UnknownClassError:
        return DEFAULT_DENSITY
    return DEFAULT_DENSITY if value is None else float(value)


def scene_to_tree(scene: ReplacedScene, class_table: ClassTable | None = None) -> KinematicTree:
    """The whole scene as one kinematic tree rooted at ``map`` with the objects' joint values."""
    scene.validate()
    table = class_table or load_class_table()
    links = [TreeLink(MAP_ROOT)]
    joints: list[Joint] = []
    values: dict[str, float] = {}
    for obj in scene.objects:
        part = model_tree(obj.model, _density(obj.class_name, table))
        rename = {lk.name: link_name(obj, lk.name) for lk in obj.model.links}
        for lk in part.links:
            links.append(dataclasses.replace(lk, name=rename[lk.name]))
        for j in part.joints:
            joints.append(dataclasses.replace(j, name=f"{obj.name}__{j.name}", parent=rename[j.parent],
                                              child=rename[j.child]))
            if j.movable:
                values[f"{obj.name}__{j.name}"] = float(obj.joint_values.get(j.name, j.zero_value))
        if obj.parent == MAP_ROOT:
            parent_link, origin = MAP_ROOT, obj.pose
        else:
            parent = scene.object(obj.parent)
            carrier = obj.parent_link or parent.model.root_link
            parent_link = link_name(parent, carrier)
            origin = invert_rigid(scene.parent_link_pose(obj)) @ obj.pose
        joints.append(Joint(f"{parent_link}__to__{obj.name}", obj.support, parent_link, obj.name,
                            np.asarray(origin, dtype=np.float64)))
    tree = KinematicTree(scene.name, MAP_ROOT, links, joints, values)
    tree.validate()
    return tree


__all__ = ["link_name", "scene_to_tree"]
