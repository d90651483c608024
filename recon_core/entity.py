"""The scene entity: one object instance or stuff region with its geometry in the map frame.

One type for every producer and consumer: the panoptic mapper extracts entities from the map
(paper Sec. 3.4, Eq. 6), the contact-graph builder turns them into nodes, the CAD replacer aligns
models to them, the ROS nodes convert them to and from ``PanopticEntity`` messages, and the
synthetic world's ground truth is exported as entities too (the paper's cg_map setting).
The map frame is gravity aligned with z up.

On disk (a "mapped scene" folder, written by ``scene-recon map``, read by ``eval-map``, ``graph``):

    entities.json   {"format_version": 1, "map_frame": "map", "name": "<scene>", "entities": [
                        {"id", "name", "class_id", "class_name", "instance_id", "is_thing", "category",
                         "confidence", "num_voxels", "revision", "core_vertices",
                         "mesh_file": "meshes/<id>.ply",
                         "observed_space": {"origin", "cell", "shape", "bits"} (optional)}, ...]}
    meshes/<id>.ply the entity's triangle mesh in the map frame
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from recon_core.errors import EntityError, InputError
from recon_core.geometry.observed_space import ObservedSpace
from recon_core.geometry.transforms import as_mesh
from recon_core.io import write_text_atomic

ENTITIES_FORMAT_VERSION = 1
#: Below this many core faces ``Entity.core_mesh`` returns the whole mesh, fringe included: a thin
#: sliver of votes says too little about an object's extent.
MIN_CORE_FACES = 20


@dataclass(eq=False)
class Entity:
    """A segmented scene entity: vertices (N, 3) in the map frame and optional triangles (M, 3).

    ``name`` defaults to ``"<class_name>_<id>"``. ``category`` may be left empty: the graph builder
    then takes it from the class table. ``revision`` increases whenever the entity's geometry
    changes, so incremental consumers rebuild only what changed. ``instance_id`` is the panoptic
    instance (0 for stuff); ``num_voxels`` the map voxels behind the entity (0 when not mapped).

    ``core_vertices``: the first ``core_vertices`` vertices carry the entity's own label votes; the
    rest are the unvoted fringe the mapper's extraction joined to it by proximity
    (``extraction.fill_radius_m``). The fringe completes the surface (panoptic quality counts it) but
    also picks up the neighbouring background along depth edges, which inflates a small object's
    extent: model fitting reads ``core_mesh``. -1 (the default): every vertex is core.
    """

    id: int
    class_name: str
    vertices: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))
    faces: NDArray[np.int64] = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    name: str = ""
    class_id: int = -1
    instance_id: int = 0
    category: str = ""
    is_thing: bool = True
    confidence: float = 1.0
    revision: int = 0
    num_voxels: int = 0
    core_vertices: int = -1
    #: Space around the entity the cameras observed (``ObservedSpace``); None: not known (a map without
    #: stored views, ground truth, an older file). Stage 4 treats model surface in unknown space as unseen.
    observed_space: ObservedSpace | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.id = int(self.id)
        self.set_geometry(self.vertices, self.faces, self.core_vertices)
        if not self.name:
            self.name = f"{self.class_name}_{self.id}"

    def set_geometry(self, vertices: ArrayLike, faces: ArrayLike | None = None, core_vertices: int = -1) -> None:
        """Replace the geometry (validated: finite vertices, face indices in range); ``core_vertices``
        as in the class docstring (-1 or out of range: all vertices are core)."""
        v = np.asarray(vertices, dtype=np.float64)
        v = v.reshape(-1, 3) if v.size else np.zeros((0, 3))
        f = np.asarray(faces if faces is not None else np.zeros((0, 3)), dtype=np.int64)
        f = f.reshape(-1, 3) if f.size else np.zeros((0, 3), np.int64)
        if not np.all(np.isfinite(v)):
            raise EntityError(f"entity {self.name or self.class_name!r} ({self.id}): non-finite vertex coordinates")
        if len(f) and (f.min() < 0 or f.max() >= len(v)):
            raise EntityError(f"entity {self.name or self.class_name!r} ({self.id}): face index out of range")
        self.vertices, self.faces = v, f
        core = int(core_vertices)
        self.core_vertices = core if 0 <= core < len(v) else -1

    def core_mesh(self, min_faces: int = MIN_CORE_FACES) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """Vertices and faces of the voted core (faces whose three vertices are core), or the whole
        mesh when there is no fringe or the core holds fewer than ``min_faces`` faces."""
        if self.core_vertices < 0:
            return self.vertices, self.faces
        n = self.core_vertices
        keep = np.all(self.faces < n, axis=1)
        if int(keep.sum()) < max(min_faces, 1):
            return self.vertices, self.faces
        return self.vertices[:n], self.faces[keep]

    @property
    def label(self) -> str:
        """Display / link name (kept for readers of older code: the same as ``name``)."""
        return self.name

    @property
    def has_faces(self) -> bool:
        return len(self.faces) > 0

    @property
    def is_empty(self) -> bool:
        return len(self.vertices) == 0

    def mesh(self) -> trimesh.Trimesh:
        """The geometry as a trimesh (no processing: indices stay as given)."""
        return trimesh.Trimesh(self.vertices, self.faces, process=False)

    @classmethod
    def from_mesh(cls, id: int, name: str, class_name: str, mesh: trimesh.Trimesh, **kw: Any) -> Entity:
        return cls(id, class_name, np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64),
                   name=name, **kw)

    @classmethod
    def from_points(cls, id: int, name: str, class_name: str, points: ArrayLike, **kw: Any) -> Entity:
        return cls(id, class_name, np.asarray(points, np.float64), name=name, **kw)

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id, "class_id": int(self.class_id), "class_name": self.class_name,
            "instance_id": int(self.instance_id), "is_thing": bool(self.is_thing),
            "category": self.category or "rigid", "confidence": float(self.confidence),
            "num_voxels": int(self.num_voxels), "revision": int(self.revision),
            "mesh_file": f"meshes/{self.id}.ply", "name": self.name, "core_vertices": int(self.core_vertices),
            **({"observed_space": self.observed_space.to_dict()} if self.observed_space is not None else {}),
        }


def save_entities(entities: list[Entity], folder: str | Path, map_frame: str = "map", name: str = "") -> Path:
    """Write a mapped-scene folder; ``entities.json`` is replaced atomically after the meshes."""
    folder = Path(folder)
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    for e in entities:
        e.mesh().export(folder / "meshes" / f"{e.id}.ply")
    data = {"format_version": ENTITIES_FORMAT_VERSION, "map_frame": map_frame, "name": name or folder.name,
            "entities": [e.to_dict() for e in entities]}
    out = folder / "entities.json"
    write_text_atomic(out, json.dumps(data, indent=1))
    return out


def read_entities_json(folder: str | Path) -> tuple[dict[str, Any], Path]:
    """The parsed ``entities.json`` of a mapped-scene folder (or the file itself) and its path."""
    folder = Path(folder)
    f = folder / "entities.json" if folder.is_dir() else folder
    if not f.is_file():
        raise InputError(f"{f} not found: expected a mapped scene folder written by `scene-recon map`")
    try:
        data = json.loads(f.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(f"{f}: cannot read entities: {exc}") from exc
    if not isinstance(data, dict) or data.get("format_version") != ENTITIES_FORMAT_VERSION:
        version = data.get("format_version") if isinstance(data, dict) else None
        raise InputError(f"{f}: cannot read entities: unsupported format {version!r} "
                         f"(expected {ENTITIES_FORMAT_VERSION})")
    return data, f


def load_entities(folder: str | Path) -> list[Entity]:
    """Entities of a mapped-scene folder; a missing mesh file gives an entity without geometry."""
    data, f = read_entities_json(folder)
    out = []
    for d in data["entities"]:
        try:
            mesh_path = f.parent / d["mesh_file"]
            if mesh_path.is_file():
                mesh = as_mesh(trimesh.load(mesh_path, force="mesh", process=False))
                v, fc = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
            else:
                v, fc = np.zeros((0, 3)), np.zeros((0, 3), np.int64)
            out.append(Entity(d["id"], d["class_name"], v, fc, name=d.get("name", ""), class_id=d["class_id"],
                              instance_id=d["instance_id"], category=d.get("category", "rigid"),
                              is_thing=d["is_thing"], confidence=d.get("confidence", 1.0),
                              revision=d.get("revision", 0), num_voxels=d.get("num_voxels", 0),
                              core_vertices=int(d.get("core_vertices", -1)),
                              observed_space=ObservedSpace.from_dict(d["observed_space"])
                              if d.get("observed_space") is not None else None))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{f}: entity {d.get('id') if isinstance(d, dict) else d!r}: {exc}") from exc
    return out


__all__ = ["ENTITIES_FORMAT_VERSION", "MIN_CORE_FACES", "Entity",
           "EntityError", "load_entities", "read_entities_json", "save_entities"]
