"""Panoptic entities extracted from the map (Sec. 3.4) and their on-disk exchange format.

A mapped scene folder (written by `scene-recon map`, read by `eval-map` and `graph`):

    entities.json   {"format_version": 1, "map_frame": "map", "name": "<scene>", "entities": [
                        {"id", "name", "class_id", "class_name", "instance_id", "is_thing", "category",
                         "confidence", "num_voxels", "revision", "mesh_file": "meshes/<id>.ply"}, ...]}
    meshes/<id>.ply the entity's triangle mesh in the map frame
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

ENTITIES_FORMAT_VERSION = 1


@dataclass
class MappedEntity:
    """One object instance or stuff region of the map, as a mesh in the map frame."""

    id: int
    class_id: int
    class_name: str
    instance_id: int
    is_thing: bool
    category: str = "rigid"
    confidence: float = 1.0  # share of the entity's votes that agree with its class (detection score)
    num_voxels: int = 0
    revision: int = 0  # increases whenever the entity's voxels change
    vertices: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    faces: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    #: Display / link name; empty: "<class_name>_<id>".
    name: str = ""

    @property
    def label(self) -> str:
        return self.name or f"{self.class_name}_{int(self.id)}"

    def mesh(self) -> trimesh.Trimesh:
        return trimesh.Trimesh(self.vertices, self.faces, process=False)

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": int(self.id), "class_id": int(self.class_id), "class_name": self.class_name,
            "instance_id": int(self.instance_id), "is_thing": bool(self.is_thing), "category": self.category,
            "confidence": float(self.confidence), "num_voxels": int(self.num_voxels),
            "revision": int(self.revision), "mesh_file": f"meshes/{int(self.id)}.ply", "name": self.label,
        }


def save_entities(entities: list[MappedEntity], folder: str | Path, map_frame: str = "map", name: str = "") -> Path:
    folder = Path(folder)
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    for e in entities:
        e.mesh().export(folder / "meshes" / f"{int(e.id)}.ply")
    data = {"format_version": ENTITIES_FORMAT_VERSION, "map_frame": map_frame, "name": name or folder.name,
            "entities": [e.to_dict() for e in entities]}
    out = folder / "entities.json"
    out.write_text(json.dumps(data, indent=1), encoding="utf-8")
    return out


def load_entities(folder: str | Path) -> list[MappedEntity]:
    folder = Path(folder)
    f = folder / "entities.json" if folder.is_dir() else folder
    if not f.is_file():
        raise FileNotFoundError(f"{f} not found: expected a mapped scene folder written by `scene-recon map`")
    data = json.loads(f.read_text(encoding="utf-8"))
    if data.get("format_version") != ENTITIES_FORMAT_VERSION:
        raise ValueError(f"{f}: unsupported entities format {data.get('format_version')!r}")
    out = []
    for d in data["entities"]:
        mesh_path = f.parent / d["mesh_file"]
        if mesh_path.is_file():
            mesh = trimesh.load(mesh_path, force="mesh", process=False)
            v, fc = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
        else:
            v, fc = np.zeros((0, 3)), np.zeros((0, 3), np.int64)
        out.append(MappedEntity(d["id"], d["class_id"], d["class_name"], d["instance_id"], d["is_thing"],
                                d.get("category", "rigid"), d.get("confidence", 1.0), d.get("num_voxels", 0),
                                d.get("revision", 0), v, fc, d.get("name", "")))
    return out
