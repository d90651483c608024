"""Export one ``CadModel`` as URDF: link meshes as files, inertials from volume x density, joints.

The output loads with ``yourdfpy.URDF.load`` and its forward kinematics equal the model's
(``CadModel.link_poses``). Every name is sanitised to ``[A-Za-z0-9_]`` and every attribute value is
written through ``xml.sax.saxutils.quoteattr``; numbers are printed with 17 significant digits.

Inertial: mass = volume x density (the class table's density unless given), where the volume is the
link mesh's own volume when it is a closed solid and its convex hull's otherwise; the inertia is
that of the link's bounding box (paper-level fidelity; enough for a physics sanity check).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal
from xml.sax.saxutils import quoteattr

import numpy as np
import trimesh
from numpy.typing import ArrayLike

from .classes import ClassTable, UnknownClassError, load_class_table
from .model import CadModel, Link
from .names import sanitize_name, unique_names

#: Density (kg/m^3) for classes missing from the class table.
DEFAULT_DENSITY = 500.0
#: Smallest link mass (kg) written: physics engines reject massless links.
MIN_MASS = 1e-3
#: Joint effort (N or N m) and velocity (m/s or rad/s) limits written for movable joints.
DEFAULT_EFFORT = 100.0
DEFAULT_VELOCITY = 1.0

MeshFormat = Literal["stl", "obj"]


def _num(v: float) -> str:
    return format(float(v), ".17g")


def _vec(values: ArrayLike) -> str:
    return " ".join(_num(v) for v in np.asarray(values, dtype=np.float64).reshape(-1))


def _rpy(rotation: np.ndarray) -> np.ndarray:
    """URDF roll-pitch-yaw (fixed axes x, y, z: R = Rz(y) Ry(p) Rx(r))."""
    m = np.eye(4)
    m[:3, :3] = rotation
    return np.asarray(trimesh.transformations.euler_from_matrix(m, "sxyz"), dtype=np.float64)


def _origin(transform: np.ndarray) -> str:
    return f"<origin xyz={quoteattr(_vec(transform[:3, 3]))} rpy={quoteattr(_vec(_rpy(transform[:3, :3])))}/>"


def link_volume(mesh: trimesh.Trimesh) -> float:
    """Solid volume for mass: the mesh's own if closed, else its convex hull's (0 when degenerate)."""
    if len(mesh.faces) == 0:
        return 0.0
    if mesh.is_watertight and mesh.volume > 0.0:
        return float(mesh.volume)
    try:
        return float(max(mesh.convex_hull.volume, 0.0))
    except Exception:  # qhull fails on flat/degenerate geometry: treat as massless
        return 0.0


def _density(model: CadModel, density: float | None, class_table: ClassTable | None) -> float:
    if density is not None:
        if not (np.isfinite(density) and density > 0):
            raise ValueError(f"density must be positive, got {density}")
        return float(density)
    table = class_table if class_table is not None else load_class_table()
    try:
        value = table.by_name(model.class_name).density
    except UnknownClassError:
        return DEFAULT_DENSITY
    return DEFAULT_DENSITY if value is None else float(value)


def _inertial(link: Link, density: float) -> list[str]:
    mesh = link.mesh
    mass = max(link_volume(mesh) * density, MIN_MASS)
    if len(mesh.vertices):
        lo, hi = mesh.bounds
        center, ext = 0.5 * (lo + hi), np.maximum(hi - lo, 1e-3)
    else:
        center, ext = np.zeros(3), np.full(3, 1e-3)
    a, b, c = ext**2
    ixx, iyy, izz = mass / 12.0 * (b + c), mass / 12.0 * (a + c), mass / 12.0 * (a + b)
    return [
        "    <inertial>",
        f'      <origin xyz={quoteattr(_vec(center))} rpy="0 0 0"/>',
        f"      <mass value={quoteattr(_num(mass))}/>",
        f'      <inertia ixx={quoteattr(_num(ixx))} ixy="0" ixz="0" iyy={quoteattr(_num(iyy))} iyz="0"'
        f" izz={quoteattr(_num(izz))}/>",
        "    </inertial>",
    ]


def export_urdf(
    model: CadModel,
    mesh_dir: Path | str,
    *,
    robot_name: str | None = None,
    density: float | None = None,
    class_table: ClassTable | None = None,
    mesh_format: MeshFormat = "stl",
    mesh_uri_prefix: str = "",
    name_prefix: str = "",
) -> str:
    """Write the link meshes into ``mesh_dir`` and return the URDF document as a string.

    Mesh references are ``mesh_uri_prefix + <file name>``: with the default empty prefix the URDF
    must be saved inside ``mesh_dir`` (``write_urdf`` does that). ``name_prefix`` is prepended to
    every link/joint name (to merge several models into one scene).
    """
    if mesh_format not in ("stl", "obj"):
        raise ValueError(f"mesh_format must be 'stl' or 'obj', got {mesh_format!r}")
    out = Path(mesh_dir)
    out.mkdir(parents=True, exist_ok=True)
    rho = _density(model, density, class_table)
    prefix = sanitize_name(name_prefix, "") if name_prefix else ""
    link_names = dict(
        zip(
            [lk.name for lk in model.links],
            unique_names([prefix + lk.name for lk in model.links], "link"),
            strict=True,
        )
    )
    joint_names = unique_names([prefix + j.name for j in model.joints], "joint")
    robot = sanitize_name(robot_name or model.model_id, "model")
    lines = ['<?xml version="1.0"?>', f"<robot name={quoteattr(robot)}>"]
    for lk in model.links:
        name = link_names[lk.name]
        lines.append(f"  <link name={quoteattr(name)}>")
        if len(lk.mesh.faces):
            fname = f"{name}.{mesh_format}"
            lk.mesh.export(out / fname, file_type=mesh_format)
            uri = quoteattr(mesh_uri_prefix + fname)
            material = ""
            if lk.color is not None:
                material = (
                    f"      <material name={quoteattr(name + '_material')}>"
                    f"<color rgba={quoteattr(_vec(lk.color))}/></material>\n"
                )
            for tag in ("visual", "collision"):
                lines.append(f"    <{tag}>")
                lines.append('      <origin xyz="0 0 0" rpy="0 0 0"/>')
                lines.append(f"      <geometry><mesh filename={uri}/></geometry>")
                if tag == "visual" and material:
                    lines.append(material.rstrip("\n"))
                lines.append(f"    </{tag}>")
        lines.extend(_inertial(lk, rho))
        lines.append("  </link>")
    for j, jname in zip(model.joints, joint_names, strict=True):
        lines.append(f"  <joint name={quoteattr(jname)} type={quoteattr(j.type)}>")
        lines.append(f"    {_origin(j.origin)}")
        lines.append(f"    <parent link={quoteattr(link_names[j.parent])}/>")
        lines.append(f"    <child link={quoteattr(link_names[j.child])}/>")
        if j.movable:
            lines.append(f"    <axis xyz={quoteattr(_vec(j.axis))}/>")
            lines.append(
                f"    <limit lower={quoteattr(_num(j.lower))} upper={quoteattr(_num(j.upper))}"
                f" effort={quoteattr(_num(DEFAULT_EFFORT))} velocity={quoteattr(_num(DEFAULT_VELOCITY))}/>"
            )
        lines.append("  </joint>")
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def write_urdf(
    model: CadModel,
    out_dir: Path | str,
    *,
    robot_name: str | None = None,
    density: float | None = None,
    class_table: ClassTable | None = None,
    mesh_format: MeshFormat = "stl",
    name_prefix: str = "",
) -> Path:
    """Write ``<out_dir>/<robot>.urdf`` with meshes in ``<out_dir>/meshes/``; returns the URDF path."""
    out = Path(out_dir)
    text = export_urdf(
        model,
        out / "meshes",
        robot_name=robot_name,
        density=density,
        class_table=class_table,
        mesh_format=mesh_format,
        mesh_uri_prefix="meshes/",
        name_prefix=name_prefix,
    )
    name = sanitize_name(robot_name or model.model_id, "model")
    path = out / f"{name}.urdf"
    path.write_text(text, encoding="utf-8")
    return path
