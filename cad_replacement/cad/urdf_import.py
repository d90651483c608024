"""Import external articulated CAD models (URDF + meshes, PartNet-Mobility/SAPIEN style).

Folder layout (what ``CadLibrary`` scans)::

    <root>/<class_name>/<model_id>/mobility.urdf   # or exactly one other *.urdf
    <root>/<class_name>/<model_id>/<meshes...>      # .obj/.stl/.ply/.off/.glb, referenced relatively
    <root>/<class_name>/<model_id>/meta.yaml        # optional, see ImportMeta

``meta.yaml`` keys (all optional): ``class`` (overrides the folder name), ``model_id``,
``up_axis`` / ``front_axis`` (which source axis, e.g. ``+y``, points up / to the front; defaults
``+z`` / ``+x``) and ``scale`` (source units -> metres). The importer rotates and scales the model
into the canonical frame (z up, front +x), moves the origin to the bottom centre of its bounding box
in the closed configuration, sanitises every name to ``[A-Za-z0-9_]`` and computes the matching
features by RANSAC (``features.model_mesh_features``).

Safety/robustness: the URDF is parsed strictly (no entity expansion, no network), every mesh path
must resolve to an existing file *inside the model folder*, and any failure -- bad XML, missing
or unreadable mesh, unsupported joint, broken kinematic tree -- raises ``CadImportError`` naming
the file, never a low-level exception from deep inside a parser. Imported meshes are kept as they
are (PartNet meshes are often not watertight); ``Link.mesh.is_watertight`` tells.
"""

from __future__ import annotations

import io
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
import yaml
import yourdfpy
from lxml import etree

from cad_replacement.cad.feature_types import ModelFeatures
from cad_replacement.cad.features import model_mesh_features
from cad_replacement.cad.model import CadModel, Joint, Link, bounding_box_features
from recon_core.errors import CadImportError
from recon_core.geometry.transforms import as_mesh, is_rigid, rotation_from_axes, translation
from recon_core.names import sanitize_name, unique_names

#: Largest URDF file accepted (bytes); PartNet files are a few kB.
MAX_URDF_BYTES = 20 * 1024 * 1024
#: Mesh formats trimesh reads without optional dependencies.
MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".glb")
#: Preferred URDF file name inside a model folder (PartNet-Mobility).
PREFERRED_URDF = "mobility.urdf"
META_FILE = "meta.yaml"
_AXES = {
    "+x": (1.0, 0.0, 0.0),
    "-x": (-1.0, 0.0, 0.0),
    "+y": (0.0, 1.0, 0.0),
    "-y": (0.0, -1.0, 0.0),
    "+z": (0.0, 0.0, 1.0),
    "-z": (0.0, 0.0, -1.0),
}
_META_KEYS = {"class", "model_id", "up_axis", "front_axis", "scale"}


@dataclass(frozen=True)
class ImportMeta:
    """Optional per-model metadata (``meta.yaml``)."""

    class_name: str | None = None
    model_id: str | None = None
    up_axis: str = "+z"
    front_axis: str = "+x"
    scale: float = 1.0

    def rotation(self) -> np.ndarray:
        """Rotation taking the source axes to the canonical ones (up -> +z, front -> +x)."""
        return rotation_from_axes(_AXES[self.up_axis], _AXES[self.front_axis])


def load_meta(path: Path | str) -> ImportMeta:
    """Read and validate ``meta.yaml``; raise ``CadImportError`` on any problem."""
    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8")) or {}
    except (OSError, yaml.YAMLError, UnicodeDecodeError) as exc:
        raise CadImportError(f"{p}: cannot read metadata: {exc}") from exc
    return parse_meta(data, p)


def parse_meta(data: Any, where: Path | str = "<meta>") -> ImportMeta:
    if not isinstance(data, Mapping):
        raise CadImportError(f"{where}: metadata must be a mapping")
    unknown = sorted(set(data) - _META_KEYS)
    if unknown:
        raise CadImportError(f"{where}: unknown metadata keys {unknown}; allowed {sorted(_META_KEYS)}")
    up, front = str(data.get("up_axis", "+z")), str(data.get("front_axis", "+x"))
    for key, axis in (("up_axis", up), ("front_axis", front)):
        if axis not in _AXES:
            raise CadImportError(f"{where}: {key} must be one of {sorted(_AXES)}, got {axis!r}")
    if abs(float(np.dot(_AXES[up], _AXES[front]))) > 0.5:
        raise CadImportError(f"{where}: up_axis {up} and front_axis {front} must be perpendicular")
    scale = data.get("scale", 1.0)
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not math.isfinite(scale) or scale <= 0:
        raise CadImportError(f"{where}: scale must be a positive number, got {scale!r}")
    cls = data.get("class")
    mid = data.get("model_id")
    return ImportMeta(
        class_name=None if cls is None else sanitize_name(str(cls)),
        model_id=None if mid is None else sanitize_name(str(mid)),
        up_axis=up,
        front_axis=front,
        scale=float(scale),
    )


def find_urdf(model_dir: Path | str) -> Path:
    """The model's URDF: ``mobility.urdf`` if present, else the only ``*.urdf`` in the folder."""
    d = Path(model_dir)
    if not d.is_dir():
        raise CadImportError(f"{d}: not a directory")
    preferred = d / PREFERRED_URDF
    if preferred.is_file():
        return preferred
    found = sorted(p for p in d.glob("*.urdf") if p.is_file())
    if len(found) != 1:
        raise CadImportError(f"{d}: expected one *.urdf file, found {[p.name for p in found]}")
    return found[0]


def _parse_xml(path: Path) -> etree._Element:
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise CadImportError(f"{path}: cannot read: {exc}") from exc
    if size > MAX_URDF_BYTES:
        raise CadImportError(f"{path}: file too large ({size} bytes > {MAX_URDF_BYTES})")
    parser = etree.XMLParser(
        resolve_entities=False, no_network=True, load_dtd=False, huge_tree=False, remove_blank_text=True
    )
    try:
        root = etree.parse(str(path), parser).getroot()
    except (etree.XMLSyntaxError, OSError) as exc:
        raise CadImportError(f"{path}: not a well-formed URDF/XML file: {exc}") from exc
    if root.tag != "robot":
        raise CadImportError(f"{path}: root element must be <robot>, got <{root.tag}>")
    return root


def _check_structure(root: etree._Element, urdf: Path) -> None:
    """Link/joint graph checks yourdfpy would otherwise fail on with cryptic errors."""
    links = [lk.get("name") for lk in root.iterfind("link")]
    if not links or any(not n for n in links):
        raise CadImportError(f"{urdf}: every <link> needs a name and there must be at least one")
    if len(set(links)) != len(links):
        raise CadImportError(f"{urdf}: duplicate link names")
    known, parent_of = set(links), {}
    for joint in root.iterfind("joint"):
        name = joint.get("name")
        parent, child = joint.find("parent"), joint.find("child")
        ends = (None if parent is None else parent.get("link"), None if child is None else child.get("link"))
        if not name or None in ends:
            raise CadImportError(f"{urdf}: joint {name!r} needs a name, a parent and a child link")
        if not set(ends) <= known:
            raise CadImportError(f"{urdf}: joint {name!r} connects unknown links {ends[0]!r} -> {ends[1]!r}")
        if ends[1] in parent_of:
            raise CadImportError(f"{urdf}: link {ends[1]!r} has two parent joints")
        parent_of[ends[1]] = ends[0]
    roots = [n for n in links if n not in parent_of]
    reached, frontier = set(roots[:1]), roots[:1]
    while frontier:
        frontier = [c for c, p in parent_of.items() if p in frontier and c not in reached]
        reached.update(frontier)
    if len(roots) != 1 or len(reached) != len(links):
        raise CadImportError(f"{urdf}: the joints must form a tree with exactly one root link (roots {roots})")


def _resolve_mesh(fname: str, base: Path, urdf: Path) -> Path:
    """Map a URDF mesh filename onto a file inside ``base`` (relative, package://, file://)."""
    raw = fname.strip()
    candidates: list[Path] = []
    if raw.startswith("package://"):
        rest = raw[len("package://") :]
        pkg, _, sub = rest.partition("/")
        candidates = [base / sub, base / pkg / sub]
    elif raw.startswith("file://"):
        candidates = [Path(raw[len("file://") :])]
    else:
        candidates = [Path(raw) if Path(raw).is_absolute() else base / raw]
    base_resolved = base.resolve()
    for cand in candidates:
        resolved = cand.resolve()
        if not resolved.is_relative_to(base_resolved):
            raise CadImportError(f"{urdf}: mesh {fname!r} lies outside the model folder {base}")
        if resolved.is_file():
            if resolved.suffix.lower() not in MESH_SUFFIXES:
                raise CadImportError(f"{urdf}: mesh {fname!r} has unsupported format (use {MESH_SUFFIXES})")
            return resolved
    raise CadImportError(f"{urdf}: mesh file {fname!r} not found under {base}")


def _mesh_map(root: etree._Element, base: Path, urdf: Path) -> dict[str, str]:
    out = {}
    for mesh in root.iterfind("link/visual/geometry/mesh"):
        fname = mesh.get("filename")
        if not fname:
            raise CadImportError(f"{urdf}: <mesh> without a filename")
        out[fname] = str(_resolve_mesh(fname, base, urdf))
    return out


def _link_meshes(urdf_model: yourdfpy.URDF, urdf: Path) -> dict[str, trimesh.Trimesh]:
    """Visual geometry of every link, in its link frame (one concatenated mesh per link)."""
    scene = urdf_model.scene
    graph = scene.graph
    parents = graph.transforms.parents
    per_link: dict[str, list[trimesh.Trimesh]] = {}
    for node in graph.nodes_geometry:
        link = parents.get(node)
        _, geom_name = graph[node]
        geom = scene.geometry.get(geom_name)
        if link is None or not isinstance(geom, trimesh.Trimesh):
            continue
        m = geom.copy()
        m.apply_transform(graph.get(frame_to=node, frame_from=link)[0])
        per_link.setdefault(link, []).append(m)
    out = {}
    for lk in urdf_model.robot.links:
        meshes = [m for m in per_link.get(lk.name, []) if len(m.faces)]
        if any(v.geometry is not None for v in lk.visuals) and not meshes:
            raise CadImportError(
                f"{urdf}: visual geometry of link {lk.name!r} could not be loaded (empty or broken mesh)"
            )
        out[lk.name] = as_mesh(trimesh.util.concatenate(meshes)) if meshes else trimesh.Trimesh()
    return out


def _joints(urdf_model: yourdfpy.URDF, urdf: Path, link_names: Mapping[str, str]) -> list[Joint]:
    names = unique_names([j.name for j in urdf_model.robot.joints], "joint")
    out = []
    for name, j in zip(names, urdf_model.robot.joints, strict=True):
        if j.parent not in link_names or j.child not in link_names:
            raise CadImportError(f"{urdf}: joint {j.name!r} connects unknown links {j.parent!r} -> {j.child!r}")
        if j.mimic is not None:
            raise CadImportError(f"{urdf}: joint {j.name!r}: mimic joints are not supported")
        origin = np.eye(4) if j.origin is None else np.asarray(j.origin, dtype=np.float64)
        if not is_rigid(origin, tol=1e-4):
            raise CadImportError(f"{urdf}: joint {j.name!r} has a non-rigid origin")
        # Re-orthonormalise what survived the text round trip (URDF rpy printed with few digits).
        u, _, vt = np.linalg.svd(origin[:3, :3])
        origin[:3, :3] = u @ vt
        axis = np.array([1.0, 0.0, 0.0]) if j.axis is None else np.asarray(j.axis, dtype=np.float64)
        jtype = j.type
        lower = upper = 0.0
        if jtype == "continuous":
            jtype, lower, upper = "revolute", -math.pi, math.pi
        elif jtype in ("revolute", "prismatic"):
            if j.limit is None or j.limit.lower is None or j.limit.upper is None:
                raise CadImportError(f"{urdf}: {jtype} joint {j.name!r} needs <limit lower=.. upper=..>")
            lower, upper = float(j.limit.lower), float(j.limit.upper)
            if not lower < upper:
                raise CadImportError(f"{urdf}: joint {j.name!r} has empty range [{lower}, {upper}]")
        elif jtype != "fixed":
            raise CadImportError(
                f"{urdf}: joint {j.name!r}: type {jtype!r} unsupported (revolute/prismatic/continuous/fixed)"
            )
        try:
            out.append(
                Joint(
                    name=name,
                    type=jtype,
                    parent=link_names[j.parent],
                    child=link_names[j.child],
                    origin=origin,
                    axis=axis,
                    lower=lower,
                    upper=upper,
                )
            )
        except ValueError as exc:
            raise CadImportError(f"{urdf}: {exc}") from exc
    return out


def _canonicalize(model: CadModel, meta: ImportMeta) -> CadModel:
    """Scale, rotate into z-up/front-+x and move the origin to the closed model's bottom centre."""
    if meta.scale != 1.0:
        model = model.scaled(meta.scale)
    rot = np.eye(4)
    rot[:3, :3] = meta.rotation()
    model = model.reframed(rot)
    lo = model.features.box_center - 0.5 * model.features.box_size
    shift = -np.array([model.features.box_center[0], model.features.box_center[1], lo[2]])
    return model.reframed(translation(shift))


def import_urdf_model(
    path: Path | str,
    *,
    class_name: str | None = None,
    model_id: str | None = None,
    meta: ImportMeta | None = None,
    compute_features: bool = True,
    seed: int = 0,
) -> CadModel:
    """Import one URDF model (a ``.urdf`` file or its model folder) as a canonical ``CadModel``.

    ``meta`` defaults to the folder's ``meta.yaml`` (if any). The class comes from ``class_name``,
    else ``meta.class``; one of them is required. ``model_id`` defaults to ``meta.model_id``, else
    the folder name. With ``compute_features=False`` only the bounding box is filled in (the
    library's cache supplies the rest).
    """
    p = Path(path)
    urdf_path = find_urdf(p) if p.is_dir() else p
    if not urdf_path.is_file():
        raise CadImportError(f"{urdf_path}: no such URDF file")
    base = urdf_path.parent
    if meta is None:
        meta = load_meta(base / META_FILE) if (base / META_FILE).is_file() else ImportMeta()
    cls = class_name if class_name is not None else meta.class_name
    if not cls:
        raise CadImportError(f"{urdf_path}: unknown class; pass class_name or set 'class' in {META_FILE}")
    mid = sanitize_name(model_id or meta.model_id or base.name, "model")

    root = _parse_xml(urdf_path)
    _check_structure(root, urdf_path)
    mesh_map = _mesh_map(root, base, urdf_path)

    def handler(fname: str) -> str:
        return mesh_map.get(fname, "")

    try:
        urdf_model = yourdfpy.URDF.load(
            io.BytesIO(etree.tostring(root)),
            build_scene_graph=True,
            load_meshes=True,
            build_collision_scene_graph=False,
            load_collision_meshes=False,
            filename_handler=handler,
            force_mesh=False,  # one node per loaded geometry; _link_meshes concatenates per link
        )
    except CadImportError:
        raise
    except Exception as exc:  # yourdfpy/trimesh raise many types; wrap them all with context
        raise CadImportError(f"{urdf_path}: cannot load URDF: {type(exc).__name__}: {exc}") from exc
    if not urdf_model.robot.links:
        raise CadImportError(f"{urdf_path}: URDF has no links")
    if not urdf_model.validate():
        raise CadImportError(f"{urdf_path}: invalid URDF: {[str(e) for e in urdf_model.errors]}")

    try:
        raw_meshes = _link_meshes(urdf_model, urdf_path)
    except CadImportError:
        raise
    except Exception as exc:
        raise CadImportError(f"{urdf_path}: cannot assemble link meshes: {type(exc).__name__}: {exc}") from exc
    link_names = dict(
        zip(
            [lk.name for lk in urdf_model.robot.links],
            unique_names([lk.name for lk in urdf_model.robot.links], "link"),
            strict=True,
        )
    )
    links = [Link(name=link_names[lk.name], mesh=raw_meshes[lk.name]) for lk in urdf_model.robot.links]
    joints = _joints(urdf_model, urdf_path, link_names)
    placeholder = ModelFeatures(box_center=np.zeros(3), box_size=np.zeros(3))
    try:
        model = CadModel(
            class_name=sanitize_name(cls),
            model_id=mid,
            links=tuple(links),
            joints=tuple(joints),
            features=placeholder,
            params={"scale": meta.scale, "up_axis": meta.up_axis, "front_axis": meta.front_axis},
            source=f"urdf:{urdf_path}",
        )
    except ValueError as exc:
        raise CadImportError(f"{urdf_path}: invalid kinematic structure: {exc}") from exc
    if all(len(lk.mesh.faces) == 0 for lk in model.links):
        raise CadImportError(f"{urdf_path}: model has no visual geometry")
    model = _canonicalize(model.with_features(bounding_box_features(model.mesh())), meta)
    if compute_features:
        model = model.with_features(model_mesh_features(model, seed=seed))
    return model
