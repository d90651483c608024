"""Files of an external CAD asset folder: its URDFs, where their meshes are, how a mesh file loads.

Layouts met in the wild (all handled):

* PartNet-Mobility / SAPIEN: ``<id>/mobility.urdf`` + ``textured_objs/*.obj`` (relative paths);
  newer releases add ``mobility_vhacd.urdf`` (the same model with decomposed collisions), so
  ``mobility.urdf`` wins when present.
* ReplicaCAD (Habitat): one folder with several ``*.urdf`` next to their ``*.glb``: one model each.
* ROS packages (Isaac/Franka ``sektion_cabinet_model``): ``<pkg>/urdf/*.urdf`` referring to
  ``package://<pkg>/meshes/...``.

The *asset root* is the folder a model may read from: the model folder in a ``CadLibrary``, else
the URDF's folder (its parent when that folder is a ROS package's ``urdf/``). Every mesh reference
must resolve to a file inside it -- a URDF is data from elsewhere and must not make us read
``../../etc/passwd``, ``file:///home/...`` or whatever a symlink points at -- or the import fails
with ``CadImportError``. ``package://<pkg>/<rest>`` never needs ROS: ``<pkg>`` may be the asset
root's own name or anything else, so ``<rest>`` (or ``<pkg>/<rest>``) is looked up as a path suffix
among the files under the root, and must match exactly one.
"""

from __future__ import annotations

import importlib
import os
import posixpath
from pathlib import Path
from urllib.parse import unquote

import numpy as np
import trimesh
from lxml import etree

from recon_core.errors import CadImportError
from recon_core.names import sanitize_name

#: Preferred URDF file name inside a model folder (PartNet-Mobility).
PREFERRED_URDF = "mobility.urdf"
#: Sub-folder holding the URDFs of a ROS package.
URDF_SUBDIR = "urdf"
#: Mesh formats the importer reads (``.dae`` needs pycollada).
MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".glb", ".gltf", ".dae")
#: Optional Python packages some formats need: suffix -> (module, distribution).
FORMAT_PACKAGES = {".dae": ("collada", "pycollada")}


def find_urdfs(folder: Path | str) -> list[Path]:
    """The URDFs of a model folder: ``mobility.urdf`` alone if present, else every ``*.urdf``.

    Looks in the folder itself, then in its ``urdf/`` sub-folder (ROS package layout).
    """
    d = Path(folder)
    if not d.is_dir():
        raise CadImportError(f"{d}: not a directory")
    for where in (d, d / URDF_SUBDIR):
        if not where.is_dir():
            continue
        preferred = where / PREFERRED_URDF
        if preferred.is_file():
            return [preferred]
        found = sorted(p for p in where.glob("*.urdf") if p.is_file())
        if found:
            return found
    raise CadImportError(f"{d}: no *.urdf file (looked in the folder and in its {URDF_SUBDIR}/ sub-folder)")


def find_urdf(folder: Path | str) -> Path:
    """The one URDF of a single-model folder (see ``find_urdfs``); several raise ``CadImportError``."""
    found = find_urdfs(folder)
    if len(found) != 1:
        raise CadImportError(
            f"{folder}: holds several models {[p.name for p in found]}; import one file or the whole "
            "folder with import_urdf_folder"
        )
    return found[0]


def default_asset_root(urdf: Path) -> Path:
    """The folder a URDF may read from: its own, or the package root when it sits in ``urdf/``."""
    parent = urdf.parent
    return parent.parent if parent.name == URDF_SUBDIR else parent


def default_model_id(urdf: Path, asset_root: Path) -> str:
    """The asset root's name when the URDF is its only model (PartNet ids), else the file stem."""
    try:
        alone = [p.resolve() for p in find_urdfs(asset_root)] == [urdf.resolve()]
    except CadImportError:
        alone = False
    return sanitize_name(asset_root.name if alone else urdf.stem, "model")


def holds_several_models(asset_root: Path) -> bool:
    try:
        return len(find_urdfs(asset_root)) > 1
    except CadImportError:
        return False


class MeshResolver:
    """Maps the mesh references of one URDF onto files inside its asset root."""

    def __init__(self, asset_root: Path, urdf: Path) -> None:
        self.root = asset_root.resolve()
        self.urdf = urdf
        self._files: list[str] | None = None

    def resolve(self, ref: str) -> Path:
        """The file ``ref`` (relative, absolute, ``file://`` or ``package://``) names, checked."""
        raw = ref.strip()
        if not raw:
            raise CadImportError(f"{self.urdf}: <mesh> without a filename")
        if raw.startswith("package://"):
            path = self._package(raw[len("package://") :], ref)
        elif raw.startswith("file://"):
            path = self._inside(self._local(raw[len("file://") :]), ref)
        elif "://" in raw:
            raise CadImportError(
                f"{self.urdf}: mesh {ref!r}: unsupported URI scheme (use a relative path, package:// or file://)"
            )
        else:
            path = self._inside(self._local(raw), ref)
        if not path.is_file():
            raise CadImportError(f"{self.urdf}: mesh file {ref!r} not found under {self.root}")
        if path.suffix.lower() not in MESH_SUFFIXES:
            raise CadImportError(f"{self.urdf}: mesh {ref!r} has an unsupported format (use {MESH_SUFFIXES})")
        return path

    def _local(self, raw: str) -> Path:
        p = Path(unquote(raw))
        return p if p.is_absolute() else self.urdf.parent / p

    def _inside(self, path: Path, ref: str) -> Path:
        resolved = path.resolve()  # follows symlinks: a link pointing out is caught too
        if not resolved.is_relative_to(self.root):
            raise CadImportError(f"{self.urdf}: mesh {ref!r} lies outside the model folder {self.root}")
        return resolved

    def _package(self, rest: str, ref: str) -> Path:
        pkg, _, sub = unquote(rest).partition("/")
        sub = posixpath.normpath(sub) if sub else ""
        if not pkg or not sub or sub == ".":
            raise CadImportError(f"{self.urdf}: mesh {ref!r}: expected package://<package>/<path>")
        if sub == ".." or sub.startswith("../") or posixpath.isabs(sub):
            raise CadImportError(f"{self.urdf}: mesh {ref!r} lies outside the model folder {self.root}")
        if pkg == self.root.name and (self.root / sub).exists():
            return self._inside(self.root / sub, ref)
        for suffix in (f"{pkg}/{sub}", sub):
            hits = [f for f in self.files() if f == suffix or f.endswith("/" + suffix)]
            if len(hits) > 1:
                raise CadImportError(
                    f"{self.urdf}: mesh {ref!r} is ambiguous: {sorted(hits)[:5]} under {self.root} all match"
                )
            if hits:
                return self._inside(self.root / hits[0], ref)
        raise CadImportError(f"{self.urdf}: mesh file {ref!r} not found under {self.root} (searched for .../{sub})")

    def files(self) -> list[str]:
        """Every file under the root as a POSIX path relative to it (listed once, lazily)."""
        if self._files is None:
            out: list[str] = []
            for folder, _, names in os.walk(self.root):
                rel = Path(folder).relative_to(self.root).as_posix()
                out.extend(name if rel == "." else f"{rel}/{name}" for name in names)
            self._files = sorted(out)
        return self._files


def load_mesh_file(path: Path, urdf: Path) -> trimesh.Trimesh:
    """All triangles of a mesh file as one mesh, each part moved by its scene-graph transform.

    glTF/DAE/OBJ files often hold several geometries placed by nodes; they are concatenated in the
    file's own frame. Collada ``<unit meter>`` is applied (RViz does), its ``<up_axis>`` is not
    (see ``import_meta``). Materials and textures are skipped: only the geometry matters here.
    """
    suffix = path.suffix.lower()
    _require_format_package(suffix, path, urdf)
    try:
        loaded = trimesh.load(str(path), force="scene", skip_materials=True)
    except CadImportError:
        raise
    except Exception as exc:  # trimesh's loaders raise anything from KeyError to struct.error
        raise CadImportError(f"{urdf}: cannot read mesh {path.name}: {type(exc).__name__}: {exc}") from exc
    mesh = scene_mesh(loaded)
    if len(mesh.faces) == 0:
        raise CadImportError(f"{urdf}: mesh {path.name} holds no triangles (empty or broken file)")
    if suffix == ".dae":
        mesh.apply_scale(collada_unit(path, urdf))
    return mesh


def _require_format_package(suffix: str, path: Path, urdf: Path) -> None:
    """Fail with the package name instead of trimesh's silent empty scene when one is missing."""
    if suffix not in FORMAT_PACKAGES:
        return
    module, distribution = FORMAT_PACKAGES[suffix]
    try:
        importlib.import_module(module)
    except ImportError as exc:
        raise CadImportError(
            f"{urdf}: mesh {path.name}: reading {suffix} files needs the optional package "
            f"{distribution!r} (pip install {distribution}), which is not installed"
        ) from exc


def scene_mesh(loaded: object) -> trimesh.Trimesh:
    """Triangle geometry of a loaded file as one plain mesh (no visuals) in the file's frame."""
    if isinstance(loaded, trimesh.Trimesh):
        return trimesh.Trimesh(loaded.vertices, loaded.faces, process=False)
    if not isinstance(loaded, trimesh.Scene):
        return trimesh.Trimesh()
    vertices, faces, offset = [], [], 0
    for node in loaded.graph.nodes_geometry:
        transform, name = loaded.graph[node]
        geom = loaded.geometry.get(name)
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            continue  # paths, point clouds: nothing to stand on or collide with
        tf = np.asarray(transform, dtype=np.float64)
        f = np.asarray(geom.faces, dtype=np.int64)
        if np.linalg.det(tf[:3, :3]) < 0.0:  # a mirroring node turns the faces inside out
            f = f[:, ::-1]
        vertices.append(trimesh.transform_points(np.asarray(geom.vertices, dtype=np.float64), tf))
        faces.append(f + offset)
        offset += len(geom.vertices)
    if not faces:
        return trimesh.Trimesh()
    return trimesh.Trimesh(np.concatenate(vertices), np.concatenate(faces), process=False)


def collada_unit(path: Path, urdf: Path) -> float:
    """Metres per unit from a Collada file's ``<asset><unit meter=..>`` (1 when absent)."""
    try:
        for _, el in etree.iterparse(
            str(path), events=("end",), resolve_entities=False, no_network=True, load_dtd=False, huge_tree=False
        ):
            tag = etree.QName(el).localname
            if tag == "unit":
                value = float(el.get("meter", "1"))
                if not (np.isfinite(value) and value > 0.0):
                    raise ValueError(f"unit meter={value}")
                return value
            if tag == "asset":
                break
    except (etree.XMLSyntaxError, OSError, ValueError) as exc:
        raise CadImportError(f"{urdf}: mesh {path.name}: bad Collada <unit>: {exc}") from exc
    return 1.0
