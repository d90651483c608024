"""Entity sources of ``scene-recon graph``: a ground-truth folder or a mapped-scene folder.

Mapped-scene folder (written by the panoptic mapper, read here; version 1)::

    <folder>/entities.json
        {"format": "scene_recon.entities", "version": 1, "name": "office", "frame_id": "map",
         "entities": [{"id": 3, "name": "table_3", "class_name": "table", "class_id": 10,
                       "category": "rigid", "is_thing": true, "confidence": 0.93, "revision": 7,
                       "mesh_file": "meshes/3.ply"}, ...]}
    <folder>/meshes/<id>.ply      triangle mesh (or point cloud) in the frame ``frame_id``

``frame_id`` is the gravity-aligned map frame (z up). ``name``, ``class_id``, ``category``,
``is_thing``, ``confidence`` and ``revision`` are optional (defaults: "<class>_<id>", -1, from the
class table, true, 1.0, 0). Ids are positive (0 is the graph's root).

A ground-truth folder (``*_groundtruth/`` with ``scene.json``, from ``scene-recon generate``)
gives the entities with their complete meshes: the paper's cg_map setting.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from .entity import Entity, EntityError, entities_from_ground_truth

ENTITIES_FORMAT = "scene_recon.entities"
ENTITIES_VERSION = 1


class SourceError(ValueError):
    """A path is neither a ground-truth nor a mapped-scene folder, or its files are malformed."""


@dataclass
class EntitySource:
    """Entities read from a folder, with the scene's name, map frame and kind ("ground_truth"/"mapped")."""

    entities: list[Entity]
    name: str
    frame_id: str
    kind: str
    path: Path


def write_entities(folder: str | Path, entities: list[Entity], name: str = "", frame_id: str = "map") -> Path:
    """Write a mapped-scene folder (the format above); returns the path of entities.json."""
    folder = Path(folder)
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    records = []
    for e in entities:
        rel = f"meshes/{e.id}.ply"
        if e.has_faces:
            trimesh.Trimesh(e.vertices, e.faces, process=False).export(folder / rel)
        else:
            trimesh.PointCloud(e.vertices).export(folder / rel)
        records.append({"id": e.id, "name": e.name, "class_name": e.class_name, "class_id": e.class_id,
                        "category": e.category, "is_thing": e.is_thing, "confidence": e.confidence,
                        "revision": e.revision, "mesh_file": rel})
    data = {"format": ENTITIES_FORMAT, "version": ENTITIES_VERSION, "name": name, "frame_id": frame_id,
            "entities": records}
    path = folder / "entities.json"
    path.write_text(json.dumps(data, indent=1), encoding="utf-8")
    return path


def _load_geometry(path: Path) -> tuple[np.ndarray, np.ndarray]:
    if not path.is_file():
        raise SourceError(f"mesh file {path} does not exist")
    try:
        geom: Any = trimesh.load(path, process=False)
    except Exception as exc:  # trimesh raises many types for broken files
        raise SourceError(f"cannot read mesh {path}: {exc}") from exc
    if isinstance(geom, trimesh.Scene):
        geom = geom.to_geometry() if geom.geometry else trimesh.Trimesh()
    faces = np.asarray(getattr(geom, "faces", np.zeros((0, 3))), np.int64)
    return np.asarray(geom.vertices, np.float64), faces


def read_entities(folder: str | Path) -> EntitySource:
    """Read a mapped-scene folder."""
    folder = Path(folder)
    f = folder / "entities.json" if folder.is_dir() else folder
    try:
        data = json.loads(f.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise SourceError(f"{f}: cannot read entities: {exc}") from exc
    if data.get("format") != ENTITIES_FORMAT or data.get("version") != ENTITIES_VERSION:
        raise SourceError(f"{f}: not a {ENTITIES_FORMAT} v{ENTITIES_VERSION} file")
    entities = []
    for i, rec in enumerate(data.get("entities", [])):
        try:
            eid, cls = int(rec["id"]), str(rec["class_name"])
            v, faces = _load_geometry(f.parent / rec["mesh_file"])
            entities.append(Entity(eid, rec.get("name") or f"{cls}_{eid}", cls, v, faces,
                                   class_id=int(rec.get("class_id", -1)), category=rec.get("category", ""),
                                   is_thing=bool(rec.get("is_thing", True)),
                                   confidence=float(rec.get("confidence", 1.0)), revision=int(rec.get("revision", 0))))
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, SourceError):
                raise
            raise SourceError(f"{f}: entities[{i}]: {exc}") from exc
    return EntitySource(entities, data.get("name") or f.parent.name, data.get("frame_id", "map"), "mapped", f.parent)


def load_source(path: str | Path) -> EntitySource:
    """Entities of a ground-truth folder (scene.json) or of a mapped-scene folder (entities.json)."""
    path = Path(path)
    if not path.exists():
        raise SourceError(f"{path} does not exist")
    folder = path if path.is_dir() else path.parent
    if (folder / "scene.json").is_file() and (path.is_dir() or path.name == "scene.json"):
        from scene_recon.synthetic.scene import GroundTruthScene

        try:
            scene = GroundTruthScene.load(folder)
        except (ValueError, KeyError, OSError) as exc:
            raise SourceError(f"{folder}: cannot read the ground truth: {exc}") from exc
        return EntitySource(entities_from_ground_truth(scene), scene.name, "map", "ground_truth", folder)
    if (folder / "entities.json").is_file():
        return read_entities(folder)
    raise SourceError(f"{path} is neither a ground-truth folder (scene.json) nor a mapped-scene folder "
                      "(entities.json + meshes/)")


__all__ = ["EntityError", "EntitySource", "SourceError", "load_source", "read_entities", "write_entities"]
