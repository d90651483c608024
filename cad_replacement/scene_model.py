"""The replaced scene (stage 4's result): CAD models placed in the gravity-aligned map frame.

Every object of the scene, layout included, is a ``PlacedObject``: a (scaled) ``CadModel`` in its
canonical frame (z up, front +x, origin bottom centre), its pose in the map, its joint values and
the support it rests on (another object's link, or the map root). The scene is a kinematic tree by
construction: every object hangs off exactly one parent, fixed (layout, furniture) or floating
(things a robot may move). Matching and alignment produce it, the global physical check and the
scene actions edit it, the exporters turn it into URDF/MJCF/GLB, and ``revision`` counts changes so
ROS consumers know when to reload.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cad_replacement.cad.model import CadModel
from recon_core.errors import InputError
from recon_core.geometry.transforms import is_rigid

#: Name of the scene's root frame (REP-105 ``map``, gravity aligned, z up).
MAP_ROOT = "map"
SUPPORT_JOINTS = ("fixed", "floating")


@dataclass(eq=False)
class PlacedObject:
    """One object (or layout element) of the replaced scene.

    ``pose`` maps the model frame into the map (float64, rigid). ``parent`` names the supporting
    object (``MAP_ROOT`` for the layout and for objects standing on nothing known) and
    ``parent_link`` the parent's link that carries it ("" = the parent's root link: a drawer
    carries what lies in it). ``support`` is the joint to the parent. ``scale`` is the factor applied
    to the library model (``model`` is already scaled); ``cad_id`` names the library model.
    """

    name: str
    class_name: str
    model: CadModel
    pose: NDArray[np.float64]
    parent: str = MAP_ROOT
    parent_link: str = ""
    support: str = "fixed"
    movable: bool = False
    entity_id: int = -1
    joint_values: dict[str, float] = field(default_factory=dict)
    scale: NDArray[np.float64] = field(default_factory=lambda: np.ones(3))
    cad_id: str = ""

    def __post_init__(self) -> None:
        pose = np.array(self.pose, dtype=np.float64)
        if not is_rigid(pose):
            raise InputError(f"object {self.name!r}: pose must be a finite rigid 4x4 transform")
        if self.support not in SUPPORT_JOINTS:
            raise InputError(f"object {self.name!r}: support must be one of {SUPPORT_JOINTS}, got {self.support!r}")
        if self.parent == self.name:
            raise InputError(f"object {self.name!r} cannot rest on itself")
        self.pose = pose
        self.scale = np.array(self.scale, dtype=np.float64).reshape(3)
        self.joint_values = {k: float(v) for k, v in self.joint_values.items()}

    def link_poses(self) -> dict[str, NDArray[np.float64]]:
        """Pose of every link of the object in the map frame at its joint values."""
        return {name: self.pose @ t for name, t in self.model.link_poses(self.joint_values).items()}

    def resting_height(self) -> float:
        """Height (map) of the bottom the object rests with: its lowest point at its joint values.

        An object kept as its scan (``model.source == "observed"``, origin at the bottom of its mapped
        box) rests with its box's bottom when the scan does not reach down to it: the box was grown to
        the support below (scene_graph), and what the camera did not see of the object's foot (a cabinet's
        lower front behind a chair) is unseen, not absent. Resting the lowest *seen* point on the support
        instead sank such a scan by the hidden height (24 cm), and dropped what stands on it with it."""
        lows = [float((np.asarray(m.vertices) @ self.pose[:3, :3].T + self.pose[:3, 3])[:, 2].min())
                for m in self.model.posed_link_meshes(self.joint_values).values() if len(m.vertices)]
        lowest = min(lows) if lows else float(self.pose[2, 3])
        if self.model.source == "observed":
            return min(lowest, float(self.pose[2, 3]))
        return lowest


@dataclass(eq=False)
class ReplacedScene:
    """The objects of a scene, parents before children, with a revision number."""

    name: str
    objects: list[PlacedObject] = field(default_factory=list)
    frame_id: str = MAP_ROOT
    revision: int = 0

    def __iter__(self) -> Iterator[PlacedObject]:
        return iter(self.objects)

    def __len__(self) -> int:
        return len(self.objects)

    def object(self, name: str) -> PlacedObject:
        for o in self.objects:
            if o.name == name:
                return o
        raise InputError(f"scene {self.name!r} has no object {name!r} (objects: {[o.name for o in self.objects]})")

    def children(self, name: str) -> list[PlacedObject]:
        return [o for o in self.objects if o.parent == name]

    def validate(self) -> None:
        """Unique names, known parents and links, parents listed before their children (a tree)."""
        seen: dict[str, PlacedObject] = {}
        for o in self.objects:
            if o.name in seen or o.name == MAP_ROOT:
                raise InputError(f"scene {self.name!r}: duplicate or reserved object name {o.name!r}")
            if o.parent != MAP_ROOT:
                parent = seen.get(o.parent)
                if parent is None:
                    raise InputError(f"object {o.name!r}: parent {o.parent!r} is unknown or listed after it")
                if o.parent_link and o.parent_link not in {lk.name for lk in parent.model.links}:
                    raise InputError(f"object {o.name!r}: parent {o.parent!r} has no link {o.parent_link!r}")
            seen[o.name] = o

    def parent_link_pose(self, obj: PlacedObject) -> NDArray[np.float64]:
        """Pose in the map of the link that carries ``obj`` (identity for the map root)."""
        if obj.parent == MAP_ROOT:
            return np.eye(4)
        parent = self.object(obj.parent)
        poses = parent.link_poses()
        return poses[obj.parent_link or parent.model.root_link]


def scene_record(scene: ReplacedScene) -> dict[str, Any]:
    """Plain-data description of the final scene (for replacement.json): the model of each object is
    named by ``cad_id`` + ``scale`` (layout boxes by their size), never pickled."""
    return {"name": scene.name, "frame_id": scene.frame_id, "revision": scene.revision, "objects": [
        {"name": o.name, "class_name": o.class_name, "cad_id": o.cad_id, "scale": o.scale.tolist(),
         "model_size": o.model.size.tolist(), "pose": o.pose.tolist(), "joint_values": dict(o.joint_values),
         "parent": o.parent, "parent_link": o.parent_link, "support": o.support, "movable": o.movable,
         "entity_id": o.entity_id} for o in scene.objects]}


__all__ = ["MAP_ROOT", "SUPPORT_JOINTS", "PlacedObject", "ReplacedScene", "scene_record"]
