"""Import external articulated CAD models (URDF + meshes: PartNet-Mobility, ReplicaCAD, ROS packages).

Folder layout (what ``CadLibrary`` scans)::

    <root>/<class_name>/<folder>/*.urdf          # or <folder>/urdf/*.urdf; mobility.urdf wins
    <root>/<class_name>/<folder>/<meshes...>     # .obj/.stl/.ply/.off/.glb/.gltf/.dae
    <root>/<class_name>/<folder>/meta.yaml       # optional, see ``import_meta``
    <root>/<class_name>/<folder>/<stem>.meta.yaml  # optional, per URDF

Each URDF is one model; its id is the folder name when it is the folder's only model (PartNet ids),
else the file stem (ReplicaCAD keeps many objects in one folder). Mesh references -- relative,
``package://`` or ``file://`` -- resolve inside the folder (``asset_files``).

The importer converts the source units (``scale``) and rotates the model into the canonical frame
(z up, front +x; the source frame comes from ``meta.yaml`` or the mesh formats, see
``import_meta``), moves the origin to the bottom centre of its bounding box in the closed
configuration, sanitises every name to ``[A-Za-z0-9_]`` and computes the matching features by RANSAC
(``features.model_mesh_features``). What the URDF says about physics is kept, so the exporter uses
it instead of guessing: ``<collision>`` boxes, cylinders and spheres become the link's collision
primitives and collision meshes its convex pieces; ``<inertial>`` becomes its inertial (mass 0, the
URDF idiom for "static", leaves it to the exporter).

Safety/robustness: the URDF is parsed strictly (no entity expansion, no network); vector attributes
written with commas (``xyz="0.1,0.2,0.3"``, found in Isaac assets) are normalised before yourdfpy
sees them; every mesh path must resolve to an existing file inside the asset folder; and any
failure -- bad XML, missing or unreadable mesh, unsupported joint, broken kinematic tree, ambiguous
up axis -- raises ``CadImportError`` naming the file, never a low-level exception from deep inside
a parser. Imported meshes are kept as they are (PartNet meshes are often not watertight);
``Link.mesh.is_watertight`` tells.
"""

from __future__ import annotations

import dataclasses
import io
import logging
import math
import re
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import trimesh
import yourdfpy
from lxml import etree
from numpy.typing import NDArray

from cad_replacement.cad.asset_files import (
    MESH_SUFFIXES,
    PREFERRED_URDF,
    MeshResolver,
    default_asset_root,
    default_model_id,
    find_urdf,
    find_urdfs,
    holds_several_models,
    load_mesh_file,
)
from cad_replacement.cad.feature_types import ModelFeatures
from cad_replacement.cad.features import model_mesh_features
from cad_replacement.cad.import_meta import (
    META_FILE,
    ImportMeta,
    SourceFrame,
    load_meta,
    load_model_meta,
    parse_meta,
    source_frame,
)
from cad_replacement.cad.model import CadModel, Joint, Link, bounding_box_features
from cad_replacement.collision import convex_pieces, mesh_shape
from recon_core.errors import CadImportError
from recon_core.geometry.transforms import is_rigid, translation
from recon_core.kinematic_tree import CollisionShape, Inertial
from recon_core.names import sanitize_name, unique_names

_log = logging.getLogger(__name__)

#: Largest URDF file accepted (bytes); PartNet files are a few kB.
MAX_URDF_BYTES = 20 * 1024 * 1024
#: Vector attributes per element and how many numbers each takes (a mesh scale may be uniform).
_VECTOR_ATTRS: dict[str, dict[str, tuple[int, ...]]] = {
    "origin": {"xyz": (3,), "rpy": (3,)},
    "axis": {"xyz": (3,)},
    "box": {"size": (3,)},
    "mesh": {"scale": (1, 3)},
    "color": {"rgba": (4,)},
}
_NUMBER_SEPARATORS = re.compile(r"[\s,]+")
#: yourdfpy validation complaints that do not matter for a CAD model (PartNet omits both).
_IGNORED_VALIDATION = ("'effort'", "'velocity'")
#: Segments of tessellated visual cylinders (as the procedural models).
_CYLINDER_SECTIONS = 32
#: Relative size of negative inertia eigenvalues forgiven as rounding (and clipped to 0).
_INERTIA_RTOL = 1e-9

__all__ = [
    "MAX_URDF_BYTES",
    "MESH_SUFFIXES",
    "META_FILE",
    "PREFERRED_URDF",
    "CadImportError",
    "ImportMeta",
    "find_urdf",
    "find_urdfs",
    "import_urdf_folder",
    "import_urdf_model",
    "load_meta",
    "normalise_vectors",
    "parse_meta",
]


# ---------------------------------------------------------------------------- XML
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


def normalise_vectors(root: etree._Element, urdf: Path | str) -> None:
    """Rewrite vector attributes as space-separated numbers, checking their count and finiteness.

    Some exporters write ``xyz="0.1,0.2,0.3"``; yourdfpy splits on spaces only and would fail with
    a bare ``could not convert string to float``.
    """
    for tag, attrs in _VECTOR_ATTRS.items():
        for el in root.iter(tag):
            for attr, counts in attrs.items():
                value = el.get(attr)
                if value is None:
                    continue
                parts = [p for p in _NUMBER_SEPARATORS.split(value.strip()) if p]
                try:
                    numbers = [float(p) for p in parts]
                except ValueError:
                    numbers = []
                if len(numbers) not in counts or not all(math.isfinite(v) for v in numbers):
                    wanted = " or ".join(str(c) for c in counts)
                    raise CadImportError(
                        f"{urdf}: line {el.sourceline}: <{tag} {attr}={value!r}> must hold {wanted} finite "
                        "numbers separated by spaces or commas"
                    )
                el.set(attr, " ".join(parts))


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


def _load_urdf(root: etree._Element, urdf: Path) -> yourdfpy.URDF:
    """yourdfpy's parse of the (normalised) tree: kinematics and geometry elements, no meshes."""
    try:
        model = yourdfpy.URDF.load(
            io.BytesIO(etree.tostring(root)),
            build_scene_graph=False,
            load_meshes=False,
            build_collision_scene_graph=False,
            load_collision_meshes=False,
        )
    except Exception as exc:  # yourdfpy raises many types; wrap them all with context
        raise CadImportError(f"{urdf}: cannot load URDF: {type(exc).__name__}: {exc}") from exc
    if not model.robot.links:
        raise CadImportError(f"{urdf}: URDF has no links")

    def relevant(errors: Sequence[Exception]) -> list[str]:
        return [str(e) for e in errors if not any(k in str(e) for k in _IGNORED_VALIDATION)]

    if not model.validate(validation_fn=lambda errors: not relevant(errors)):
        raise CadImportError(f"{urdf}: invalid URDF: {relevant(model.errors)}")
    return model


# ---------------------------------------------------------------------------- link geometry
def _transformed(mesh: trimesh.Trimesh, tf: NDArray[np.float64]) -> trimesh.Trimesh:
    """A plain copy of ``mesh`` moved by the affine ``tf`` (faces flipped under a mirror)."""
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if np.linalg.det(tf[:3, :3]) < 0.0:
        faces = faces[:, ::-1]
    return trimesh.Trimesh(trimesh.transform_points(np.asarray(mesh.vertices, dtype=np.float64), tf), faces,
                           process=False)


def _concatenate(parts: Sequence[trimesh.Trimesh]) -> trimesh.Trimesh:
    """Plain meshes joined into one (an empty mesh for none)."""
    if not parts:
        return trimesh.Trimesh()
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    faces = [np.asarray(p.faces, dtype=np.int64) + off for p, off in zip(parts, offsets, strict=True)]
    return trimesh.Trimesh(np.concatenate([p.vertices for p in parts]), np.concatenate(faces), process=False)


def _origin(origin: NDArray[np.float64] | None) -> NDArray[np.float64]:
    return np.eye(4) if origin is None else np.asarray(origin, dtype=np.float64)


class _LinkGeometry:
    """Builds link meshes, collision shapes and inertials from yourdfpy elements.

    Mesh files are loaded once (visual and collision elements often share them).
    """

    def __init__(self, resolver: MeshResolver, urdf: Path) -> None:
        self.resolver = resolver
        self.urdf = urdf
        self._cache: dict[Path, trimesh.Trimesh] = {}

    def mesh_suffix(self, geometry: yourdfpy.Geometry | None) -> str | None:
        if geometry is None or geometry.mesh is None:
            return None
        return self.resolver.resolve(geometry.mesh.filename).suffix.lower()

    def _mesh_file(self, mesh: yourdfpy.Mesh) -> trimesh.Trimesh:
        path = self.resolver.resolve(mesh.filename)
        if path not in self._cache:
            self._cache[path] = load_mesh_file(path, self.urdf)
        loaded = self._cache[path]
        scale = np.broadcast_to(np.asarray(1.0 if mesh.scale is None else mesh.scale, dtype=np.float64), (3,))
        if not np.all(np.isfinite(scale)) or np.any(scale == 0.0):
            raise CadImportError(f"{self.urdf}: mesh {mesh.filename!r}: scale {scale.tolist()} must be non-zero")
        return _transformed(loaded, np.diag(np.append(scale, 1.0)))

    def geometry_mesh(self, geometry: yourdfpy.Geometry, what: str) -> trimesh.Trimesh:
        """A visual's geometry as a mesh in its own frame (primitives tessellated)."""
        if geometry.mesh is not None:
            return self._mesh_file(geometry.mesh)
        try:
            if geometry.box is not None:
                size = np.asarray(geometry.box.size, dtype=np.float64)
                if np.any(size <= 0.0):
                    raise ValueError(f"box size {size.tolist()} must be positive")
                return trimesh.creation.box(extents=size)
            if geometry.cylinder is not None:
                r, h = float(geometry.cylinder.radius), float(geometry.cylinder.length)
                if not (r > 0.0 and h > 0.0):
                    raise ValueError(f"cylinder radius {r} and length {h} must be positive")
                return trimesh.creation.cylinder(radius=r, height=h, sections=_CYLINDER_SECTIONS)
            if geometry.sphere is not None:
                r = float(geometry.sphere.radius)
                if not r > 0.0:
                    raise ValueError(f"sphere radius {r} must be positive")
                return trimesh.creation.icosphere(subdivisions=2, radius=r)
        except (TypeError, ValueError) as exc:
            raise CadImportError(f"{self.urdf}: {what}: {exc}") from exc
        raise CadImportError(f"{self.urdf}: {what}: <geometry> without box, cylinder, sphere or mesh")

    def visual_mesh(self, link: yourdfpy.Link) -> trimesh.Trimesh:
        """All visuals of a link in the link frame, concatenated."""
        parts = []
        for k, vis in enumerate(link.visuals):
            if vis.geometry is None:
                continue
            mesh = self.geometry_mesh(vis.geometry, f"link {link.name!r} visual {k}")
            parts.append(_transformed(mesh, _origin(vis.origin)))
        return _concatenate(parts)

    def collisions(self, link: yourdfpy.Link) -> tuple[CollisionShape, ...] | None:
        """The link's ``<collision>`` elements as shapes (``None`` when it has none).

        Primitives stay primitives. A collision mesh becomes convex pieces (``convex_pieces``:
        itself when convex, else a decomposition): simulators would collide it as one hull.
        """
        if not link.collisions:
            return None
        shapes: list[CollisionShape] = []
        for k, col in enumerate(link.collisions):
            what = f"link {link.name!r} collision {col.name or k}"
            if col.geometry is None:
                raise CadImportError(f"{self.urdf}: {what}: <geometry> is missing")
            shapes.extend(self._collision_shapes(col.geometry, _origin(col.origin), what))
        if not shapes:
            _log.warning("%s: link %r: no usable collision geometry, the exporter derives it", self.urdf, link.name)
            return None
        return tuple(shapes)

    def _collision_shapes(self, g: yourdfpy.Geometry, origin: NDArray[np.float64], what: str) -> list[CollisionShape]:
        try:
            if g.box is not None:
                return [CollisionShape("box", origin=origin, size=np.asarray(g.box.size, dtype=np.float64))]
            if g.cylinder is not None:
                return [CollisionShape("cylinder", origin=origin, radius=float(g.cylinder.radius),
                                       length=float(g.cylinder.length))]
            if g.sphere is not None:
                return [CollisionShape("sphere", origin=origin, radius=float(g.sphere.radius))]
        except (TypeError, ValueError) as exc:
            raise CadImportError(f"{self.urdf}: {what}: {exc}") from exc
        mesh = _transformed(self.geometry_mesh(g, what), origin)
        return [mesh_shape(p) for p in convex_pieces(mesh)]

    def inertial(self, link: yourdfpy.Link) -> Inertial | None:
        """The link's ``<inertial>`` in the project's form (inertia about the COM in link axes)."""
        src = link.inertial
        if src is None or src.mass is None:
            return None
        mass = float(src.mass)
        if not math.isfinite(mass) or mass < 0.0:
            raise CadImportError(f"{self.urdf}: link {link.name!r}: mass {mass} must be finite and >= 0")
        if mass == 0.0 or src.inertia is None:
            _log.info("%s: link %r: no usable <inertial> (mass 0 or no inertia), the exporter derives it",
                      self.urdf, link.name)
            return None
        frame = _origin(src.origin)
        rot = frame[:3, :3]
        inertia = rot @ np.asarray(src.inertia, dtype=np.float64) @ rot.T
        inertia = 0.5 * (inertia + inertia.T)
        if not np.all(np.isfinite(inertia)):
            raise CadImportError(f"{self.urdf}: link {link.name!r}: inertia must be finite")
        values, vectors = np.linalg.eigh(inertia)
        if values.min() < -_INERTIA_RTOL * max(float(np.abs(values).max()), 1e-300):
            raise CadImportError(
                f"{self.urdf}: link {link.name!r}: inertia tensor is not positive semi-definite "
                f"(eigenvalues {values.tolist()}); fix or remove its <inertial>"
            )
        inertia = (vectors * np.clip(values, 0.0, None)) @ vectors.T
        return Inertial(mass=mass, center_of_mass=frame[:3, 3].copy(), inertia=0.5 * (inertia + inertia.T))


# ---------------------------------------------------------------------------- joints
def _joints(urdf_model: yourdfpy.URDF, urdf: Path, link_names: dict[str, str]) -> list[Joint]:
    names = unique_names([j.name for j in urdf_model.robot.joints], "joint")
    out = []
    for name, j in zip(names, urdf_model.robot.joints, strict=True):
        if j.parent not in link_names or j.child not in link_names:
            raise CadImportError(f"{urdf}: joint {j.name!r} connects unknown links {j.parent!r} -> {j.child!r}")
        if j.mimic is not None:
            raise CadImportError(f"{urdf}: joint {j.name!r}: mimic joints are not supported")
        origin = _origin(j.origin).copy()
        if not is_rigid(origin, tol=1e-4):
            raise CadImportError(f"{urdf}: joint {j.name!r} has a non-rigid origin")
        # Re-orthonormalise what survived the text round trip (URDF rpy printed with few digits).
        u, _, vt = np.linalg.svd(origin[:3, :3])
        origin[:3, :3] = u @ vt
        axis = np.array([1.0, 0.0, 0.0]) if j.axis is None else np.asarray(j.axis, dtype=np.float64)
        jtype, lower, upper = _joint_range(j, urdf)
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


def _joint_range(j: yourdfpy.Joint, urdf: Path) -> tuple[str, float, float]:
    """Joint type and limits in the project's terms (continuous -> revolute over one turn)."""
    if j.type == "continuous":
        return "revolute", -math.pi, math.pi
    if j.type in ("revolute", "prismatic"):
        if j.limit is None or j.limit.lower is None or j.limit.upper is None:
            raise CadImportError(f"{urdf}: {j.type} joint {j.name!r} needs <limit lower=.. upper=..>")
        lower, upper = float(j.limit.lower), float(j.limit.upper)
        if not lower < upper:
            raise CadImportError(f"{urdf}: joint {j.name!r} has empty range [{lower}, {upper}]")
        return j.type, lower, upper
    if j.type == "fixed":
        return "fixed", 0.0, 0.0
    raise CadImportError(
        f"{urdf}: joint {j.name!r}: type {j.type!r} unsupported (revolute/prismatic/continuous/fixed)"
    )


# ---------------------------------------------------------------------------- canonical frame
def _unit_scaled(model: CadModel, s: float) -> CadModel:
    """Lengths converted to metres; masses stay (the URDF gives kg), inertias follow (kg m^2).

    ``CadModel.scaled`` keeps the density instead (right for stretching a model to a target box,
    wrong for a unit change), so the imported inertials are put back with only their lengths scaled.
    """
    scaled = model.scaled(s)
    links = []
    for old, new in zip(model.links, scaled.links, strict=True):
        if old.inertial is not None and new.inertial is not None:
            fixed = Inertial(mass=old.inertial.mass, center_of_mass=new.inertial.center_of_mass,
                             inertia=old.inertial.inertia * s**2)
            new = new.with_inertial(fixed)
        links.append(new)
    return dataclasses.replace(scaled, links=tuple(links))


def _canonicalize(model: CadModel, frame: SourceFrame, scale: float) -> CadModel:
    """Scale, rotate into z-up/front-+x and move the origin to the closed model's bottom centre."""
    if scale != 1.0:
        model = _unit_scaled(model, scale)
    rot = np.eye(4)
    rot[:3, :3] = frame.rotation()
    model = model.reframed(rot)
    lo = model.features.box_center - 0.5 * model.features.box_size
    shift = -np.array([model.features.box_center[0], model.features.box_center[1], lo[2]])
    return model.reframed(translation(shift))


# ---------------------------------------------------------------------------- entry points
def _locate(path: Path, asset_root: Path | str | None) -> tuple[Path, Path]:
    """The URDF file and the asset root it may read from."""
    if path.is_dir():
        urdf = find_urdf(path)
        root = Path(asset_root) if asset_root is not None else path
    else:
        urdf = path
        if not urdf.is_file():
            raise CadImportError(f"{urdf}: no such URDF file")
        root = Path(asset_root) if asset_root is not None else default_asset_root(urdf)
    if not root.is_dir():
        raise CadImportError(f"{root}: asset folder is not a directory")
    return urdf, root


def import_urdf_model(
    path: Path | str,
    *,
    class_name: str | None = None,
    model_id: str | None = None,
    meta: ImportMeta | None = None,
    asset_root: Path | str | None = None,
    compute_features: bool = True,
    collisions: bool = True,
    seed: int = 0,
) -> CadModel:
    """Import one URDF model (a ``.urdf`` file or a single-model folder) as a canonical ``CadModel``.

    ``asset_root``: the folder meshes may be read from (default: the model folder, see
    ``asset_files.default_asset_root``). ``meta`` defaults to the folder's metadata files. The
    class comes from ``class_name``, else ``meta.class``; one of them is required. ``model_id``
    defaults to ``meta.model_id``, else ``asset_files.default_model_id``. ``compute_features=False``
    fills in only the bounding box (the library's cache supplies the rest); ``collisions=False``
    skips the collision elements (no convex decomposition when only features are wanted).
    """
    urdf_path, root_dir = _locate(Path(path), asset_root)
    if meta is None:
        meta = load_model_meta(urdf_path, root_dir, shared_folder=holds_several_models(root_dir))
    cls = class_name if class_name is not None else meta.class_name
    if not cls:
        raise CadImportError(f"{urdf_path}: unknown class; pass class_name or set 'class' in {META_FILE}")
    mid = sanitize_name(model_id or meta.model_id or default_model_id(urdf_path, root_dir), "model")

    root = _parse_xml(urdf_path)
    normalise_vectors(root, urdf_path)
    _check_structure(root, urdf_path)
    urdf_model = _load_urdf(root, urdf_path)
    geometry = _LinkGeometry(MeshResolver(root_dir, urdf_path), urdf_path)
    suffixes = {
        s for lk in urdf_model.robot.links for v in lk.visuals if (s := geometry.mesh_suffix(v.geometry)) is not None
    }
    frame = source_frame(meta, suffixes, urdf_path)
    model = _build_model(urdf_model, urdf_path, geometry, collisions=collisions, class_name=cls, model_id=mid)
    model = dataclasses.replace(
        model,
        params={"scale": meta.scale, "up_axis": frame.up, "front_axis": frame.front, "up_source": frame.reason},
    )
    model = _canonicalize(model.with_features(bounding_box_features(model.mesh())), frame, meta.scale)
    if compute_features:
        model = model.with_features(model_mesh_features(model, seed=seed))
    return model


def _build_model(
    urdf_model: yourdfpy.URDF,
    urdf: Path,
    geometry: _LinkGeometry,
    *,
    collisions: bool,
    class_name: str,
    model_id: str,
) -> CadModel:
    """The model in the URDF's own frame (links with meshes, collisions and inertials; joints)."""
    robot_links = urdf_model.robot.links
    link_names = dict(zip([lk.name for lk in robot_links], unique_names([lk.name for lk in robot_links], "link"),
                          strict=True))
    links = []
    for lk in robot_links:
        links.append(
            Link(
                name=link_names[lk.name],
                mesh=geometry.visual_mesh(lk),
                collisions=geometry.collisions(lk) if collisions else None,
                inertial=geometry.inertial(lk),
            )
        )
    if all(len(lk.mesh.faces) == 0 for lk in links):
        raise CadImportError(f"{urdf}: model has no visual geometry")
    joints = _joints(urdf_model, urdf, link_names)
    try:
        return CadModel(
            class_name=sanitize_name(class_name),
            model_id=model_id,
            links=tuple(links),
            joints=tuple(joints),
            features=ModelFeatures(box_center=np.zeros(3), box_size=np.zeros(3)),
            source=f"urdf:{urdf}",
        )
    except ValueError as exc:
        raise CadImportError(f"{urdf}: invalid kinematic structure: {exc}") from exc


def import_urdf_folder(
    folder: Path | str,
    *,
    class_name: str | None = None,
    compute_features: bool = True,
    collisions: bool = True,
    seed: int = 0,
    on_error: Callable[[Path, CadImportError], None] | None = None,
) -> list[CadModel]:
    """Import every URDF of an asset folder (one model each; see ``asset_files.find_urdfs``).

    Model ids come from the metadata or ``default_model_id`` (file stems when the folder holds
    several), made unique. A broken URDF raises ``CadImportError``, or is reported to ``on_error`` and skipped.
    """
    root = Path(folder)
    models = []
    for urdf in find_urdfs(root):
        try:
            models.append(
                import_urdf_model(
                    urdf,
                    class_name=class_name,
                    asset_root=root,
                    compute_features=compute_features,
                    collisions=collisions,
                    seed=seed,
                )
            )
        except CadImportError as exc:
            if on_error is None:
                raise
            on_error(urdf, exc)
    ids = unique_names([m.model_id for m in models], "model")
    return [dataclasses.replace(m, model_id=mid) for m, mid in zip(models, ids, strict=True)]
