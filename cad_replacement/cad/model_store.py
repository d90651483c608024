"""``ModelStore``: built procedural models, with their collision shapes, on disk for the next process.

A command-line ``replace`` is a new process each time. Its fits come back from the result store, but
the chosen models were built again in the main process (the exact unions of their parts, 10-15 ms a
model) and their collision shapes computed again (a cup's wall is 32 convex hulls: 0.1 s a cup) before
the physical check and the export could run: 0.3-0.8 s of a warm run, after the fits of a first run.
A worker that chose a model now stores it here, collisions included, and ``CadLibrary.model`` reads
it back.

A file is named by the library's digest of the entry (the model's definition and the cache
versions) and the code's digest (``result_store.code_digest``: any change of the code is a miss), and
holds plain arrays and one JSON header (no pickle): the links' meshes, colours and
collision shapes, the joints, the parameters. Restored models are the built ones number for number
(floats pass through JSON as their shortest repr, which reads back exactly). Written atomically
(temp + rename); a damaged, foreign or older file is rebuilt from the definition, never trusted.
"""

from __future__ import annotations

import json
import logging
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from numpy.typing import NDArray

from cad_replacement.cad.feature_types import ModelFeatures
from cad_replacement.cad.model import CadModel, Link
from recon_core.io import write_npz_atomic
from recon_core.kinematic_tree import CollisionShape, Joint

log = logging.getLogger(__name__)

#: Bump when what is stored (or how a model is rebuilt from it) changes: older files are then ignored.
MODEL_STORE_VERSION = 2
_FORMAT = "scene_recon.cad_model"


def _concat(arrays: list[NDArray[Any]], width: int, dtype: Any) -> NDArray[Any]:
    return np.concatenate(arrays).astype(dtype, copy=False) if arrays else np.zeros((0, width), dtype)


def model_arrays(model: CadModel) -> dict[str, NDArray[Any]]:
    """A model with every link's collision shapes (computed here if they were not) as a few plain arrays
    (the meshes concatenated, with their vertex and face counts: an npz member costs 0.3 ms to read)."""
    links = []
    verts, faces, counts = [], [], []
    c_origin, c_size, c_verts, c_faces, c_counts = [], [], [], [], []
    for lk in model.links:
        if lk.inertial is not None:
            raise ValueError(f"link {lk.name!r} has an inertial: not a procedural model")
        verts.append(np.asarray(lk.mesh.vertices, dtype=np.float64))
        faces.append(np.asarray(lk.mesh.faces, dtype=np.int64))
        counts.append((len(verts[-1]), len(faces[-1])))
        shapes = lk.collisions
        record: dict[str, Any] = {"name": lk.name, "color": None if lk.color is None else list(lk.color),
                                  "collisions": None}
        if shapes is not None:
            record["collisions"] = [{"kind": s.kind, "radius": s.radius, "length": s.length,
                                     "mesh": s.mesh is not None} for s in shapes]
            for s in shapes:
                c_origin.append(np.asarray(s.origin, dtype=np.float64))
                c_size.append(np.asarray(s.size, dtype=np.float64))
                if s.mesh is not None:
                    c_verts.append(np.asarray(s.mesh.vertices, dtype=np.float64))
                    c_faces.append(np.asarray(s.mesh.faces, dtype=np.int64))
                    c_counts.append((len(c_verts[-1]), len(c_faces[-1])))
                else:
                    c_counts.append((0, 0))
        links.append(record)
    joints = [{"name": jt.name, "type": jt.type, "parent": jt.parent, "child": jt.child, "lower": jt.lower,
               "upper": jt.upper, "effort": jt.effort, "velocity": jt.velocity} for jt in model.joints]
    header = {"format": _FORMAT, "version": MODEL_STORE_VERSION, "class_name": model.class_name,
              "model_id": model.model_id, "params": dict(model.params), "source": model.source,
              "links": links, "joints": joints}
    return {
        "header": np.array(json.dumps(header, allow_nan=False)),
        "v": _concat(verts, 3, np.float64), "f": _concat(faces, 3, np.int64),
        "counts": np.array(counts, dtype=np.int64).reshape(-1, 2),
        "c_origin": np.array(c_origin, dtype=np.float64).reshape(-1, 4, 4),
        "c_size": np.array(c_size, dtype=np.float64).reshape(-1, 3),
        "c_v": _concat(c_verts, 3, np.float64), "c_f": _concat(c_faces, 3, np.int64),
        "c_counts": np.array(c_counts, dtype=np.int64).reshape(-1, 2),
        "j_origin": np.array([jt.origin for jt in model.joints], dtype=np.float64).reshape(-1, 4, 4),
        "j_axis": np.array([jt.axis for jt in model.joints], dtype=np.float64).reshape(-1, 3),
    }


class _Cursor:
    """Reads consecutive meshes out of concatenated vertex and face arrays."""

    def __init__(self, vertices: NDArray[Any], faces: NDArray[Any]) -> None:
        self.vertices, self.faces = vertices, faces
        self.v = self.f = 0

    def mesh(self, n_vertices: int, n_faces: int) -> trimesh.Trimesh:
        v = self.vertices[self.v:self.v + n_vertices].copy()
        f = self.faces[self.f:self.f + n_faces].copy()
        if len(v) != n_vertices or len(f) != n_faces:
            raise ValueError("model file: mesh arrays shorter than their counts")
        self.v += n_vertices
        self.f += n_faces
        return trimesh.Trimesh(v, f, process=False)


def restore_model(data: dict[str, NDArray[Any]], features: ModelFeatures) -> CadModel:
    """The model ``model_arrays`` stored (with ``features``: the library's for the entry)."""
    header = json.loads(str(data["header"]))
    if header.get("format") != _FORMAT or header.get("version") != MODEL_STORE_VERSION:
        raise ValueError(f"not a version-{MODEL_STORE_VERSION} model file")
    meshes = _Cursor(data["v"], data["f"])
    pieces = _Cursor(data["c_v"], data["c_f"])
    counts, c_counts = data["counts"], data["c_counts"]
    k = 0  # collision shapes read so far
    links = []
    for i, rec in enumerate(header["links"]):
        mesh = meshes.mesh(int(counts[i, 0]), int(counts[i, 1]))
        shapes: list[CollisionShape] | None = None
        if rec["collisions"] is not None:
            shapes = []
            for c in rec["collisions"]:
                piece = pieces.mesh(int(c_counts[k, 0]), int(c_counts[k, 1])) if c["mesh"] else None
                shapes.append(CollisionShape(c["kind"], origin=data["c_origin"][k], size=data["c_size"][k],
                                             radius=float(c["radius"]), length=float(c["length"]), mesh=piece))
                k += 1
        color = None if rec["color"] is None else tuple(float(v) for v in rec["color"])
        links.append(Link(rec["name"], mesh, color,  # type: ignore[arg-type]
                          None if shapes is None else tuple(shapes)))
    joints = [Joint(name=j["name"], type=j["type"], parent=j["parent"], child=j["child"],
                    origin=data["j_origin"][i], axis=data["j_axis"][i], lower=float(j["lower"]),
                    upper=float(j["upper"]), effort=float(j["effort"]), velocity=float(j["velocity"]))
              for i, j in enumerate(header["joints"])]
    return CadModel(class_name=header["class_name"], model_id=header["model_id"], links=tuple(links),
                    joints=tuple(joints), features=features, params=header["params"], source=header["source"])


@dataclass
class ModelStore:
    """Folder of ``<digest>_<code>_m<version>.npz`` model files (``digest``: the library's, per entry;
    ``code``: the first 16 hex digits of ``result_store.code_digest``)."""

    folder: Path
    digest: Callable[[Any], str]

    def path(self, entry: Any) -> Path:
        # the code's digest too (``result_store.code_digest``): the collision shapes come from code that no
        # model definition's version names (``collision.py``), and a stale shape would be a silent error
        from cad_replacement.result_store import code_digest

        return self.folder / f"{self.digest(entry)}_{code_digest()[:16]}_m{MODEL_STORE_VERSION}.npz"

    def has(self, entry: Any) -> bool:
        return self.path(entry).is_file()

    def load(self, entry: Any, features: Callable[[], ModelFeatures]) -> CadModel | None:
        path = self.path(entry)
        if not path.is_file():
            return None
        try:
            with np.load(path, allow_pickle=False) as npz:
                data = {k: npz[k] for k in npz.files}
            return restore_model(data, features())
        except (OSError, ValueError, KeyError, TypeError, IndexError, zipfile.BadZipFile) as exc:
            log.warning("model store %s unreadable (%s): building the model", path, exc)
            return None

    def save(self, entry: Any, model: CadModel) -> None:
        path = self.path(entry)
        try:
            write_npz_atomic(path, model_arrays(model), sync=False)
        except (OSError, ValueError, TypeError) as exc:  # a read-only or full cache costs speed, never a run
            log.warning("model store %s not written (%s)", path, exc)


__all__ = ["MODEL_STORE_VERSION", "ModelStore", "model_arrays", "restore_model"]
