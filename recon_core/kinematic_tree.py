"""A scene or an object as a kinematic tree (paper Sec. 4.5) and the project's one URDF writer.

Links are rigid bodies (a layout element, a rigid object, or one part of an articulated object);
joints connect them: a CAD model's own revolute/prismatic joints, and the contact graph's support
edges turned into fixed joints (a table on the floor) or floating joints (a cup on a table).
Everything that writes URDF (a single CAD model, the reconstructed scene, the synthetic world's
ground truth) builds a ``KinematicTree`` and calls ``to_urdf``/``urdf_text``, so names, number
formats, inertials and mesh references follow one convention.

Every name written into XML is sanitised (``recon_core.names``) and made unique; attribute values
go through ``quoteattr``; numbers are printed with 17 significant digits and must be finite.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal
from xml.sax.saxutils import quoteattr

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from recon_core.geometry.transforms import EPS_NORM, is_rigid, rotation_about, translation, unit
from recon_core.io import write_bytes_atomic, write_text_atomic
from recon_core.names import unique_names, urdf_name

JOINT_TYPES = ("fixed", "floating", "revolute", "prismatic", "continuous")
MeshFormat = Literal["stl", "obj"]
RGBA = tuple[float, float, float, float]
#: Joint effort (N or N m) and velocity (m/s or rad/s) limits written when a joint has none.
DEFAULT_EFFORT = 100.0
DEFAULT_VELOCITY = 1.0
#: Smallest box extent (m) used for a link's inertia, so flat parts keep a positive-definite tensor.
MIN_INERTIA_EXTENT = 1e-3


def format_number(value: float) -> str:
    """A finite float with 17 significant digits (exact round trip); non-finite values are refused."""
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"non-finite value in URDF output: {v}")
    return format(v, ".17g")


def format_vector(values: ArrayLike) -> str:
    return " ".join(format_number(v) for v in np.asarray(values, dtype=np.float64).reshape(-1))


def rpy_of(rotation: NDArray[np.float64]) -> NDArray[np.float64]:
    """URDF roll-pitch-yaw (fixed axes x, y, z: R = Rz(y) Ry(p) Rx(r)) of a 3x3 rotation."""
    m = np.eye(4)
    m[:3, :3] = rotation
    return np.asarray(trimesh.transformations.euler_from_matrix(m, "sxyz"), dtype=np.float64)


def origin_element(transform: NDArray[np.float64]) -> str:
    t = np.asarray(transform, dtype=np.float64)
    return f"<origin xyz={quoteattr(format_vector(t[:3, 3]))} rpy={quoteattr(format_vector(rpy_of(t[:3, :3])))}/>"


COLLISION_KINDS = ("box", "cylinder", "sphere", "mesh")


@dataclass(frozen=True, eq=False)
class CollisionShape:
    """One collision element of a link (URDF ``<collision>``): a primitive or a convex mesh piece.

    Simulators collide a mesh as its convex hull, so a concave part must arrive as several convex
    pieces or primitives, never as one visual mesh. ``origin`` places the shape in the link frame;
    a box has ``size`` (x, y, z), a cylinder ``radius`` and ``length`` along its z axis, a sphere
    ``radius``; a mesh piece carries ``mesh`` (convex, in the shape frame).
    """

    kind: str
    origin: NDArray[np.float64] = field(default_factory=lambda: np.eye(4))
    size: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    radius: float = 0.0
    length: float = 0.0
    mesh: trimesh.Trimesh | None = None

    def __post_init__(self) -> None:
        if self.kind not in COLLISION_KINDS:
            raise ValueError(f"collision kind must be one of {COLLISION_KINDS}, got {self.kind!r}")
        origin = np.array(self.origin, dtype=np.float64)
        if not is_rigid(origin):
            raise ValueError("collision origin must be a rigid 4x4 transform")
        size = np.array(self.size, dtype=np.float64).reshape(3)
        values = [*size, float(self.radius), float(self.length)]
        if not all(math.isfinite(v) and v >= 0.0 for v in values):
            raise ValueError(f"collision {self.kind}: sizes must be finite and non-negative, got {values}")
        if self.kind == "box" and np.any(size <= 0.0):
            raise ValueError(f"collision box needs a positive size, got {size.tolist()}")
        if self.kind in ("cylinder", "sphere") and self.radius <= 0.0:
            raise ValueError(f"collision {self.kind} needs a positive radius")
        if self.kind == "cylinder" and self.length <= 0.0:
            raise ValueError("collision cylinder needs a positive length")
        if self.kind == "mesh" and (self.mesh is None or len(self.mesh.faces) == 0):
            raise ValueError("collision mesh piece needs a non-empty mesh")
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "size", size)


@dataclass(frozen=True, eq=False)
class Inertial:
    """Mass (kg), centre of mass (link frame) and inertia tensor about the centre of mass (link axes)."""

    mass: float
    center_of_mass: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    inertia: NDArray[np.float64] = field(default_factory=lambda: np.eye(3) * 1e-6)

    def __post_init__(self) -> None:
        com = np.array(self.center_of_mass, dtype=np.float64).reshape(3)
        inertia = np.array(self.inertia, dtype=np.float64).reshape(3, 3)
        if not (math.isfinite(self.mass) and self.mass > 0.0):
            raise ValueError(f"mass must be positive and finite, got {self.mass}")
        if not (np.all(np.isfinite(com)) and np.all(np.isfinite(inertia))):
            raise ValueError("centre of mass and inertia must be finite")
        if not np.allclose(inertia, inertia.T, atol=1e-12) or np.linalg.eigvalsh(inertia).min() < 0.0:
            raise ValueError("inertia must be symmetric positive semi-definite")
        object.__setattr__(self, "center_of_mass", com)
        object.__setattr__(self, "inertia", inertia)


@dataclass
class TreeLink:
    """A rigid body; ``mesh`` (the visual) is expressed in the link frame.

    ``collisions``: the collision elements; ``None`` uses the visual mesh (acceptable only for
    convex parts). ``mass`` 0 means massless (layout, fixed world parts: no inertial is written);
    ``inertial`` gives the full inertial, otherwise the inertia is that of the mesh's bounding box
    about its centre.
    """

    name: str
    mesh: trimesh.Trimesh | None = None
    mass: float = 0.0
    rgba: RGBA | None = (0.7, 0.7, 0.7, 1.0)
    collisions: tuple[CollisionShape, ...] | None = None
    inertial: Inertial | None = None


JointType = Literal["fixed", "floating", "revolute", "prismatic", "continuous"]


@dataclass(frozen=True, eq=False)
class Joint:
    """One joint (URDF semantics), the only joint type of the project (CAD models and scenes).

    ``origin`` maps the joint frame into the parent link frame; the child link frame is the joint
    frame moved by the joint motion (rotation about / translation along ``axis``, in the joint
    frame). Limits in rad (revolute) or m (prismatic) with ``lower < upper``; fixed and floating
    joints have none (a floating joint keeps its child's pose in ``origin``), continuous joints
    are unlimited.
    """

    name: str
    type: str  # one of JOINT_TYPES (checked at construction; data from files and graphs is plain text)
    parent: str
    child: str
    origin: NDArray[np.float64] = field(default_factory=lambda: np.eye(4))
    axis: NDArray[np.float64] = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    lower: float = 0.0
    upper: float = 0.0
    effort: float = DEFAULT_EFFORT
    velocity: float = DEFAULT_VELOCITY

    def __post_init__(self) -> None:
        if self.type not in JOINT_TYPES:
            raise ValueError(f"joint {self.name!r}: type must be one of {JOINT_TYPES}, got {self.type!r}")
        if not self.name or not self.parent or not self.child:
            raise ValueError(f"joint {self.name!r}: name, parent and child must be non-empty")
        if self.parent == self.child:
            raise ValueError(f"joint {self.name!r}: parent and child are both {self.parent!r}")
        origin = np.array(self.origin, dtype=np.float64)
        if not is_rigid(origin):
            raise ValueError(f"joint {self.name!r}: origin must be a rigid 4x4 transform")
        origin.setflags(write=False)
        axis = unit(self.axis, f"joint {self.name!r} axis")
        axis.setflags(write=False)
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "axis", axis)
        lower, upper = float(self.lower), float(self.upper)
        if self.type in ("fixed", "floating", "continuous"):
            lower = upper = 0.0
        elif not (np.isfinite(lower) and np.isfinite(upper) and lower < upper):
            raise ValueError(f"joint {self.name!r}: need finite limits lower < upper, got [{lower}, {upper}]")
        object.__setattr__(self, "lower", lower)
        object.__setattr__(self, "upper", upper)

    @property
    def movable(self) -> bool:
        """A joint with one degree of freedom driven by a joint value (floating joints are poses)."""
        return self.type in ("revolute", "prismatic", "continuous")

    @property
    def zero_value(self) -> float:
        """The closed/rest value: 0 clipped into the limits."""
        return float(np.clip(0.0, self.lower, self.upper))

    def clip(self, value: float) -> float:
        if self.type == "continuous":
            return float(value)
        return float(np.clip(value, self.lower, self.upper))

    def motion(self, value: float) -> NDArray[np.float64]:
        """Transform of the child frame relative to the joint frame at joint value ``value``."""
        if self.type in ("revolute", "continuous"):
            return rotation_about(self.axis, value)
        if self.type == "prismatic":
            return translation(self.axis * value)
        return np.eye(4)

    def transform(self, value: float) -> NDArray[np.float64]:
        """Child link pose in the parent link frame at ``value`` (clipped to the limits)."""
        return self.origin @ self.motion(self.clip(value))


def box_inertia(mass: float, extents: ArrayLike) -> NDArray[np.float64]:
    """Inertia tensor of a solid box of ``extents`` about its centre."""
    a, b, c = np.maximum(np.asarray(extents, dtype=np.float64).reshape(3), MIN_INERTIA_EXTENT) ** 2
    return np.diag([mass / 12.0 * (b + c), mass / 12.0 * (a + c), mass / 12.0 * (a + b)])


@dataclass
class KinematicTree:
    name: str
    root: str
    links: list[TreeLink] = field(default_factory=list)
    joints: list[Joint] = field(default_factory=list)
    #: Current values of the movable joints (by joint name); missing ones are at their zero value.
    joint_values: dict[str, float] = field(default_factory=dict)

    def link_poses(self, values: Mapping[str, float] | None = None) -> dict[str, NDArray[np.float64]]:
        """Forward kinematics: pose of every link in the root frame (values by joint name)."""
        values = values or {}
        children: dict[str, list[Joint]] = {}
        for j in self.joints:
            children.setdefault(j.parent, []).append(j)
        poses = {self.root: np.eye(4)}
        stack = [self.root]
        while stack:
            parent = stack.pop()
            for j in children.get(parent, []):
                q = values.get(j.name, self.joint_values.get(j.name, j.zero_value))
                poses[j.child] = poses[parent] @ j.transform(q)
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

    # ------------------------------------------------------------------ URDF
    def safe_names(self) -> tuple[dict[str, str], list[str]]:
        """URDF names: link name -> safe unique name, and the joints' safe unique names (in order)."""
        links = dict(zip([lk.name for lk in self.links], unique_names(urdf_name(lk.name) for lk in self.links),
                         strict=True))
        joints = unique_names(urdf_name(j.name) for j in self.joints)
        return links, joints

    def urdf_text(self, mesh_dir: str | Path, mesh_uri_prefix: str = "", mesh_format: MeshFormat = "stl",
                  write_meshes: bool = True) -> str:
        """Write the link meshes into ``mesh_dir`` and return the URDF document.

        Mesh references are ``mesh_uri_prefix + <file name>`` (relative paths keep a scene folder
        movable); file names are ``<link>.<fmt>`` (visual) and ``<link>_collision_<k>.<fmt>``
        (convex pieces). ``write_meshes=False`` only references them: several documents over one
        mesh folder (a scene and its per-object parts) write each file once.
        """
        if mesh_format not in ("stl", "obj"):
            raise ValueError(f"mesh_format must be 'stl' or 'obj', got {mesh_format!r}")
        self.validate()
        out = Path(mesh_dir) if write_meshes else None
        if out is not None:
            out.mkdir(parents=True, exist_ok=True)
        link_names, joint_names = self.safe_names()
        lines = ['<?xml version="1.0"?>', f"<robot name={quoteattr(urdf_name(self.name))}>"]
        for link in self.links:
            lines.extend(_link_lines(link, link_names[link.name], out, mesh_uri_prefix, mesh_format))
        for j, jname in zip(self.joints, joint_names, strict=True):
            lines.extend(_joint_lines(j, jname, link_names))
        lines.append("  <!-- generated by scene_recon -->")
        lines.append("</robot>")
        return "\n".join(lines) + "\n"

    def to_urdf(self, folder: str | Path, mesh_dir: str = "meshes", filename: str | None = None,
                mesh_format: MeshFormat = "stl", write_meshes: bool = True) -> Path:
        """Write ``<folder>/<name>.urdf`` (atomically) and the link meshes under ``<folder>/<mesh_dir>/``."""
        folder = Path(folder)
        text = self.urdf_text(folder / mesh_dir, f"{mesh_dir}/" if mesh_dir else "", mesh_format, write_meshes)
        return write_text_atomic(folder / (filename or f"{urdf_name(self.name)}.urdf"), text)


def export_mesh_file(mesh: trimesh.Trimesh, path: Path, mesh_format: str) -> Path:
    """Write one mesh file atomically (a reader never sees half a mesh)."""
    data = mesh.export(file_type=mesh_format)
    return write_bytes_atomic(path, data.encode("utf-8") if isinstance(data, str) else bytes(data))


def _link_lines(link: TreeLink, name: str, out: Path | None, uri_prefix: str, mesh_format: str) -> list[str]:
    lines = [f"  <link name={quoteattr(name)}>"]
    mesh = link.mesh
    if mesh is not None and len(mesh.faces):
        fname = f"{name}.{mesh_format}"
        if out is not None:
            export_mesh_file(mesh, out / fname, mesh_format)
        geometry = f"<geometry><mesh filename={quoteattr(uri_prefix + fname)}/></geometry>"
        material = ""
        if link.rgba is not None:
            material = (f"<material name={quoteattr(name + '_material')}>"
                        f"<color rgba={quoteattr(format_vector(link.rgba))}/></material>")
        lines.append(f'    <visual><origin xyz="0 0 0" rpy="0 0 0"/>{geometry}{material}</visual>')
        if link.collisions is None:
            lines.append(f'    <collision><origin xyz="0 0 0" rpy="0 0 0"/>{geometry}</collision>')
    for k, shape in enumerate(link.collisions or ()):
        lines.append(_collision_line(shape, f"{name}_collision_{k}", out, uri_prefix, mesh_format))
    if link.inertial is not None or link.mass > 0.0:
        lines.extend(_inertial_lines(link))
    lines.append("  </link>")
    return lines


def _collision_line(shape: CollisionShape, file_stem: str, out: Path | None, uri_prefix: str,
                    mesh_format: str) -> str:
    n = format_number
    if shape.kind == "box":
        geometry = f"<box size={quoteattr(format_vector(shape.size))}/>"
    elif shape.kind == "cylinder":
        geometry = f"<cylinder radius={quoteattr(n(shape.radius))} length={quoteattr(n(shape.length))}/>"
    elif shape.kind == "sphere":
        geometry = f"<sphere radius={quoteattr(n(shape.radius))}/>"
    else:
        assert shape.mesh is not None  # checked by CollisionShape
        fname = f"{file_stem}.{mesh_format}"
        if out is not None:
            export_mesh_file(shape.mesh, out / fname, mesh_format)
        geometry = f"<mesh filename={quoteattr(uri_prefix + fname)}/>"
    return f"    <collision>{origin_element(shape.origin)}<geometry>{geometry}</geometry></collision>"


def _inertial_lines(link: TreeLink) -> list[str]:
    mesh = link.mesh
    if link.inertial is not None:
        mass, center, inertia = link.inertial.mass, link.inertial.center_of_mass, link.inertial.inertia
    else:
        mass = link.mass
        has_mesh = mesh is not None and len(mesh.vertices) > 0
        lo, hi = (mesh.bounds if mesh is not None and has_mesh else (np.zeros(3), np.zeros(3)))
        center = 0.5 * (lo + hi)
        inertia = box_inertia(mass, hi - lo)
    n = format_number
    return [
        "    <inertial>",
        f'      <origin xyz={quoteattr(format_vector(center))} rpy="0 0 0"/>',
        f"      <mass value={quoteattr(n(mass))}/>",
        f"      <inertia ixx={quoteattr(n(inertia[0, 0]))} ixy={quoteattr(n(inertia[0, 1]))}"
        f" ixz={quoteattr(n(inertia[0, 2]))} iyy={quoteattr(n(inertia[1, 1]))} iyz={quoteattr(n(inertia[1, 2]))}"
        f" izz={quoteattr(n(inertia[2, 2]))}/>",
        "    </inertial>",
    ]


def _joint_lines(j: Joint, name: str, link_names: Mapping[str, str]) -> list[str]:
    lines = [f"  <joint name={quoteattr(name)} type={quoteattr(j.type)}>",
             f"    {origin_element(j.origin)}",
             f"    <parent link={quoteattr(link_names[j.parent])}/>",
             f"    <child link={quoteattr(link_names[j.child])}/>"]
    if j.type in ("revolute", "prismatic", "continuous"):
        axis = np.asarray(j.axis, dtype=np.float64)
        lines.append(f"    <axis xyz={quoteattr(format_vector(axis / max(float(np.linalg.norm(axis)), EPS_NORM)))}/>")
    if j.type in ("revolute", "prismatic"):
        lines.append(f"    <limit lower={quoteattr(format_number(j.lower))} upper={quoteattr(format_number(j.upper))}"
                     f" effort={quoteattr(format_number(j.effort))} velocity={quoteattr(format_number(j.velocity))}/>")
    lines.append("  </joint>")
    return lines


__all__ = [
    "COLLISION_KINDS",
    "DEFAULT_EFFORT",
    "DEFAULT_VELOCITY",
    "JOINT_TYPES",
    "CollisionShape",
    "Inertial",
    "Joint",
    "JointType",
    "KinematicTree",
    "TreeLink",
    "box_inertia",
    "export_mesh_file",
    "format_number",
    "format_vector",
    "origin_element",
    "rpy_of",
]
