"""Entity sources of ``scene-recon graph``/``replace``: a ground-truth folder or a mapped-scene folder.

A mapped-scene folder is what `scene-recon map` writes: ``entities.json`` + ``meshes/<id>.ply``
(one format, one reader: ``recon_core.entity``). Entities of class -1 ("unknown", the map's
unclaimed surface) are read too; the builder ignores them by default.

A ground-truth folder (``*_groundtruth/`` with ``scene.json``, from ``scene-recon generate``)
gives the entities with their complete meshes: the paper's cg_map setting. Reading it belongs to
the tool layer because only the synthetic world knows that format.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from recon_core.entity import Entity, load_entities, read_entities_json
from recon_core.errors import InputError


@dataclass
class EntitySource:
    """Entities read from a folder, with the scene's name, map frame and kind ("ground_truth"/"mapped")."""

    entities: list[Entity]
    name: str
    frame_id: str
    kind: str
    path: Path


def read_mapped(folder: str | Path) -> EntitySource:
    """A mapped-scene folder (entities.json + meshes/)."""
    meta, f = read_entities_json(folder)
    return EntitySource(load_entities(f), meta.get("name") or f.parent.name, meta.get("map_frame", "map"), "mapped",
                        f.parent)


def load_source(path: str | Path) -> EntitySource:
    """Entities of a ground-truth folder (scene.json) or of a mapped-scene folder (entities.json)."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path} does not exist")
    folder = path if path.is_dir() else path.parent
    if (folder / "scene.json").is_file() and (path.is_dir() or path.name == "scene.json"):
        from scene_recon.synthetic.scene import GroundTruthScene, entities_from_ground_truth

        try:
            scene = GroundTruthScene.load(folder)
        except (ValueError, KeyError, OSError) as exc:
            raise InputError(f"{folder}: cannot read the ground truth: {exc}") from exc
        return EntitySource(entities_from_ground_truth(scene), scene.name, "map", "ground_truth", folder)
    if (folder / "entities.json").is_file():
        return read_mapped(folder)
    raise InputError(f"{path} is neither a ground-truth folder (scene.json) nor a mapped-scene folder "
                     "(entities.json + meshes/)")


__all__ = ["EntitySource", "load_source", "read_mapped"]
