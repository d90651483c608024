"""Entity sources of ``scene-recon graph``: a ground-truth folder or a mapped-scene folder.

A mapped-scene folder is what `scene-recon map` writes: ``entities.json`` + ``meshes/<id>.ply``
in the format of `panoptic_mapping.entities` (one format, one reader: that module). Entities of
class -1 ("unknown", the map's unclaimed surface) are read too; the builder ignores them by default.

A ground-truth folder (``*_groundtruth/`` with ``scene.json``, from ``scene-recon generate``)
gives the entities with their complete meshes: the paper's cg_map setting.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from panoptic_mapping.entities import MappedEntity, load_entities, save_entities

from .entity import Entity, EntityError, entities_from_ground_truth


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
    """Write a mapped-scene folder (the mapper's format); returns the path of entities.json."""
    mapped = [MappedEntity(e.id, e.class_id, e.class_name, e.id if e.is_thing else 0, e.is_thing,
                           e.category or "rigid", e.confidence, len(e.vertices), e.revision, e.vertices, e.faces,
                           e.name)
              for e in entities]
    return save_entities(mapped, folder, frame_id, name)


def read_entities(folder: str | Path) -> EntitySource:
    """Read a mapped-scene folder."""
    folder = Path(folder)
    f = folder / "entities.json" if folder.is_dir() else folder
    try:
        mapped = load_entities(f)
        meta = json.loads(f.read_text(encoding="utf-8"))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise SourceError(f"{f}: cannot read entities: {exc}") from exc
    entities = []
    for m in mapped:
        try:
            entities.append(Entity(int(m.id), m.label, m.class_name, m.vertices, m.faces,
                                   class_id=int(m.class_id), category=m.category, is_thing=bool(m.is_thing),
                                   confidence=float(m.confidence), revision=int(m.revision)))
        except (EntityError, ValueError) as exc:
            raise SourceError(f"{f}: entity {m.id}: {exc}") from exc
    return EntitySource(entities, meta.get("name") or f.parent.name, meta.get("map_frame", "map"), "mapped", f.parent)


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
