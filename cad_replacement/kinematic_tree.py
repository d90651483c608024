"""A scene as a kinematic tree (paper Sec. 4.5) and its URDF export.

Links are rigid bodies (a layout element, a rigid object, or one part of an articulated object);
joints connect them: the CAD model's own revolute/prismatic joints, and the contact graph's
support edges turned into fixed joints (a table on the floor) or floating joints (a cup on a
table). `to_urdf` writes a URDF that yourdfpy, RViz and simulators load, with every link mesh as
an STL file beside it. Every name written into XML is sanitised and escaped.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import escape, quoteattr

import numpy as np
import trimesh

JOINT_TYPES = ("fixed", "floating", "revolute", "prismatic", "continuous")
_NAME_RE = re.compile(r"[^A-Za-z0-9_]")


def urdf_name(name: str) -> str:
    """A URDF/TF-safe name: letters, digits and underscores, not starting with a digit."""
    safe = _NAME_RE.sub("_", str(name)) or "unnamed"
    return f"_{safe}" if safe[0].isdigit() else safe


def _rpy(r: np.ndarray) -> tuple[float, float, float]:
    """URDF roll-pitch-yaw (fixed axes X, Y, Z) of a rotation matrix."""
    sy = -float(np.clip(r[2, 0], -1.0, 1.0))
    pitch = math.asin(sy)
    if abs(sy) < 1 - 1e-9:
        roll = math.atan2(r[2, 1], r[2, 2])
        yaw = math.atan2(r[1, 0], r[0, 0])
    else:  # gimbal lock: yaw and roll share one degree of freedom
        roll = 0.0
        yaw = math.atan2(-r[0, 1], r[1, 1])
    return roll, pitch, yaw


def _fmt(values) -> str:
    vals = [float(v) for v in values]
    if not all(math.isfinite(v) for v in vals):
        raise ValueError(f"non-finite value in URDF output: {vals}")
    return " ".join(f"{v:.9g}" for v in vals)


@dataclass
class TreeLink:
    name: str
    mesh: trimesh.Trimesh | None = None  # in the link frame
    mass: float = 0.0  # kg; 0 = massless (layout, fixed world parts)
    rgba: tuple[float, float, float, float] = (0.7, 0.7, 0.7, 1.0)


@dataclass
class TreeJoint:
    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray = field(default_factory=lambda: np.eye(4))  # child joint frame in the parent link
    axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    lower: float = 0.0
    upper: float = 0.0
    value: float = 0.0  # current joint value (rad or m); floating joints keep their pose in `origin`

    def __post_init__(self) -> None:
        if self.type not in JOINT_TYPES:
            raise ValueError(f"joint {self.name!r}: type {self.type!r} not in {JOINT_TYPES}")


@dataclass
class KinematicTree:
    name: str
    root: str
    links: list[TreeLink] = field(default_factory=list)
    joints: list[TreeJoint] = field(default_factory=list)

    def motion(self, joint: TreeJoint, value: float) -> np.ndarray:
        m = np.eye(4)
        axis = np.asarray(joint.axis, dtype=np.float64)
        axis = axis / max(np.linalg.norm(axis), 1e-12)
        if joint.type in ("revolute", "continuous"):
            m[:3, :3] = trimesh.transformations.rotation_matrix(value, axis)[:3, :3]
        elif joint.type == "prismatic":
            m[:3, 3] = value * axis
        return m

    def link_poses(self, values: dict[str, float] | None = None) -> dict[str, np.ndarray]:
        """Forward kinematics: pose of every link in the root frame."""
        values = values or {}
        children: dict[str, list[TreeJoint]] = {}
        for j in self.joints:
            children.setdefault(j.parent, []).append(j)
        poses = {self.root: np.eye(4)}
        stack = [self.root]
        while stack:
            parent = stack.pop()
            for j in children.get(parent, []):
                q = values.get(j.name, j.value)
                poses[j.child] = poses[parent] @ j.origin @ self.motion(j, q)
                stack.append(j.child)
        return poses

    def validate(self) -> None:
        names = [link.name for link in self.links]
        if len(set(names)) != len(names):
            raise ValueError("duplicate link names in kinematic tree")
        known = set(names)
        seen_children = set()
        for j in self.joints:
            if j.parent not in known or j.child not in known:
                raise ValueError(f"joint {j.name!r} connects unknown links {j.parent!r} -> {j.child!r}")
            if j.child in seen_children:
                raise ValueError(f"link {j.child!r} has two parent joints")
            seen_children.add(j.child)
        if self.root in seen_children or known - seen_children != {self.root}:
            raise ValueError("kinematic tree must have exactly one root and connect every link")

    def to_urdf(self, folder: str | Path, mesh_dir: str = "meshes", filename: str | None = None) -> Path:
        """Write `<folder>/<name>.urdf` and the link meshes under `<folder>/<mesh_dir>/`."""
        self.validate()
        folder = Path(folder)
        (folder / mesh_dir).mkdir(parents=True, exist_ok=True)
        lines = ['<?xml version="1.0"?>', f"<robot name={quoteattr(urdf_name(self.name))}>"]
        for link in self.links:
            lname = urdf_name(link.name)
            lines.append(f"  <link name={quoteattr(lname)}>")
            if link.mesh is not None and len(link.mesh.faces):
                rel = f"{mesh_dir}/{lname}.stl"
                link.mesh.export(folder / rel)
                geom = f"<geometry><mesh filename={quoteattr(rel)}/></geometry>"
                lines.append(f"    <visual><origin xyz=\"0 0 0\" rpy=\"0 0 0\"/>{geom}"
                             f"<material name={quoteattr(lname + '_mat')}><color rgba=\"{_fmt(link.rgba)}\"/>"
                             "</material></visual>")
                lines.append(f"    <collision><origin xyz=\"0 0 0\" rpy=\"0 0 0\"/>{geom}</collision>")
                if link.mass > 0:
                    lines.append(self._inertial(link))
            lines.append("  </link>")
        for j in self.joints:
            xyz, rpy = j.origin[:3, 3], _rpy(j.origin[:3, :3])
            lines.append(f"  <joint name={quoteattr(urdf_name(j.name))} type={quoteattr(j.type)}>")
            lines.append(f"    <parent link={quoteattr(urdf_name(j.parent))}/>")
            lines.append(f"    <child link={quoteattr(urdf_name(j.child))}/>")
            lines.append(f"    <origin xyz=\"{_fmt(xyz)}\" rpy=\"{_fmt(rpy)}\"/>")
            if j.type in ("revolute", "prismatic", "continuous"):
                axis = np.asarray(j.axis, float) / max(np.linalg.norm(j.axis), 1e-12)
                lines.append(f"    <axis xyz=\"{_fmt(axis)}\"/>")
            if j.type in ("revolute", "prismatic"):
                lines.append(f"    <limit lower=\"{j.lower:.9g}\" upper=\"{j.upper:.9g}\" effort=\"50\" "
                             f"velocity=\"1\"/>")
            lines.append("  </joint>")
        lines.append(f"  <!-- {escape('generated by scene_recon')} -->")
        lines.append("</robot>")
        out = folder / (filename or f"{urdf_name(self.name)}.urdf")
        out.write_text("\n".join(lines) + "\n", encoding="utf-8")
        return out

    @staticmethod
    def _inertial(link: TreeLink) -> str:
        """Inertia of the link's bounding box with the link's mass (robust for non-watertight meshes)."""
        lo, hi = link.mesh.bounds
        size = np.maximum(hi - lo, 1e-4)
        center = (lo + hi) / 2
        m = link.mass
        ixx = m / 12 * (size[1] ** 2 + size[2] ** 2)
        iyy = m / 12 * (size[0] ** 2 + size[2] ** 2)
        izz = m / 12 * (size[0] ** 2 + size[1] ** 2)
        return (f"    <inertial><origin xyz=\"{_fmt(center)}\" rpy=\"0 0 0\"/><mass value=\"{m:.9g}\"/>"
                f"<inertia ixx=\"{ixx:.9g}\" ixy=\"0\" ixz=\"0\" iyy=\"{iyy:.9g}\" iyz=\"0\" izz=\"{izz:.9g}\"/>"
                "</inertial>")
