"""Export one ``CadModel`` as URDF through the project's one writer (``recon_core.kinematic_tree``).

The model becomes a ``KinematicTree`` (its links with their meshes, its joints with their limits)
and the core writer prints it, so a single object and a whole scene share names, number formats
and inertials. The output loads with ``yourdfpy.URDF.load`` and its forward kinematics equal the
model's (``CadModel.link_poses``).

Collisions and inertial: a link's own collision shapes (procedural links: exact primitives, see
``cad_replacement.collision``) with mass = their volume x density (the class table's density
unless given) and their full inertia tensor. A link without shapes (imported meshes) collides as
its visual mesh and weighs its mesh volume (closed) or hull volume x density with the inertia of
its bounding box; ``cad_replacement.export`` decomposes such meshes into convex pieces.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import trimesh

from cad_replacement.cad.model import CadModel, Link
from cad_replacement.collision import inertial_from_shapes
from recon_core.classes import ClassTable, UnknownClassError, load_class_table
from recon_core.io import write_text_atomic
from recon_core.kinematic_tree import Inertial, KinematicTree, MeshFormat, TreeLink
from recon_core.names import sanitize_name

#: Density (kg/m^3) for classes missing from the class table.
DEFAULT_DENSITY = 500.0
#: Smallest link mass (kg) written: physics engines reject massless links.
MIN_MASS = 1e-3


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
    rho = _density(model, density, class_table)
    prefix = sanitize_name(name_prefix, "") if name_prefix else ""
    return model_tree(model, rho, prefix, robot_name).urdf_text(mesh_dir, mesh_uri_prefix, mesh_format)


def model_tree(model: CadModel, density: float, name_prefix: str = "", robot_name: str | None = None) -> KinematicTree:
    """The model as a kinematic tree at its closed configuration (names prefixed for scene merging)."""
    links = [TreeLink(name_prefix + lk.name, lk.mesh, max(link_volume(lk.mesh) * density, MIN_MASS),
                      None if lk.color is None else tuple(float(c) for c in lk.color),  # type: ignore[arg-type]
                      collisions=lk.collisions, inertial=_inertial(lk, density))
             for lk in model.links]
    joints = [dataclasses.replace(j, name=name_prefix + j.name, parent=name_prefix + j.parent,
                                  child=name_prefix + j.child) for j in model.joints]
    return KinematicTree(sanitize_name(robot_name or model.model_id, "model"), name_prefix + model.root_link,
                         links, joints)


def _inertial(link: Link, density: float) -> Inertial | None:
    """The link's own inertial, else the one of its collision shapes (None: the writer's mesh box)."""
    if link.inertial is not None or not link.collisions:
        return link.inertial
    return inertial_from_shapes(link.collisions, density)


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
    return write_text_atomic(out / f"{name}.urdf", text)
