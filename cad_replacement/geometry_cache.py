"""``GeometryCache``: alignment geometry of library models, in memory and on disk.

Matching scores every top-k candidate of every object at its box start, so a scene touches dozens
of library models (77 on the kitchen of the benchmark suite); building each one's alignment
geometry (procedural CSG, surface samples, self-visibility rays, the swept envelope of its moving
parts) took a third of a scene's replacement time. The geometry depends only on the model and the
sample count, so it is stored beside the library's feature cache, keyed by the library's digest of
the entry (which covers the model definition and the cache versions), and restored with the full
model left unbuilt: only the few candidates that reach the full fit or are chosen build it.

Files are written atomically (temp + rename); a damaged or foreign file is rebuilt, never trusted.
"""

from __future__ import annotations

import logging
import zipfile
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from numpy.typing import NDArray

from cad_replacement.alignment import ModelGeometry, raycasting_scene
from cad_replacement.cad.library import CadEntry
from cad_replacement.cad.model import CadModel
from recon_core.io import write_npz_atomic

log = logging.getLogger(__name__)

#: Bump when ``ModelGeometry.build`` changes what it computes: older files are then ignored.
GEOMETRY_CACHE_VERSION = 1
_FORMAT = "scene_recon.model_geometry"


def geometry_arrays(geom: ModelGeometry, mesh: trimesh.Trimesh, envelope: trimesh.Trimesh | None) -> dict[str, NDArray]:
    """What ``restore_geometry`` needs, as plain arrays (the raycasting scenes are rebuilt from meshes)."""
    names = list(geom.link_names)
    zero = geom.joint_values
    out: dict[str, NDArray] = {
        "format": np.array([_FORMAT, str(GEOMETRY_CACHE_VERSION)]),
        "center": geom.center, "size": geom.size, "samples": geom.samples, "normals": geom.normals,
        "self_visible": geom.self_visible, "sample_links": geom.sample_links,
        "link_samples": geom.link_samples, "link_normals": geom.link_normals,
        "link_names": np.array(names), "sample_area": np.array(geom.sample_area),
        "articulated": np.array(geom.articulated_model),
        "joint_names": np.array(list(zero), dtype=str), "joint_zero": np.array(list(zero.values()), dtype=np.float64),
        "mesh_vertices": np.asarray(mesh.vertices, dtype=np.float64), "mesh_faces": np.asarray(mesh.faces, np.int64),
    }
    if envelope is not None and geom.static_samples is not None:
        out["envelope_vertices"] = np.asarray(envelope.vertices, dtype=np.float64)
        out["envelope_faces"] = np.asarray(envelope.faces, dtype=np.int64)
        out["static_samples"] = geom.static_samples
    return out


def restore_geometry(key: str, data: dict[str, NDArray], source: Callable[[], CadModel]) -> ModelGeometry:
    """A ``ModelGeometry`` from ``geometry_arrays`` output; the model is built by ``source`` on first use."""
    fmt = [str(v) for v in data["format"]]
    if fmt != [_FORMAT, str(GEOMETRY_CACHE_VERSION)]:
        raise ValueError(f"not a version-{GEOMETRY_CACHE_VERSION} geometry file: {fmt}")
    mesh = trimesh.Trimesh(data["mesh_vertices"], data["mesh_faces"], process=False)
    envelope = None
    if "envelope_vertices" in data:
        envelope = raycasting_scene(trimesh.Trimesh(data["envelope_vertices"], data["envelope_faces"], process=False))
    samples = np.asarray(data["samples"], dtype=np.float64)
    for name in ("normals", "link_samples", "link_normals"):
        if data[name].shape != samples.shape or not np.all(np.isfinite(data[name])):
            raise ValueError(f"geometry file: bad {name}")
    return ModelGeometry(
        key=key,
        source=source,
        scene=raycasting_scene(mesh),
        center=np.asarray(data["center"], dtype=np.float64),
        size=np.asarray(data["size"], dtype=np.float64),
        samples=samples,
        normals=np.asarray(data["normals"], dtype=np.float64),
        self_visible=np.asarray(data["self_visible"], dtype=bool),
        sample_links=np.asarray(data["sample_links"], dtype=np.int64),
        link_samples=np.asarray(data["link_samples"], dtype=np.float64),
        link_normals=np.asarray(data["link_normals"], dtype=np.float64),
        link_names=tuple(str(n) for n in data["link_names"]),
        sample_area=float(data["sample_area"]),
        envelope=envelope,
        static_samples=np.asarray(data["static_samples"], dtype=bool) if "static_samples" in data else None,
        joint_values={str(n): float(v) for n, v in zip(data["joint_names"], data["joint_zero"], strict=True)},
        articulated_model=bool(data["articulated"]),
    )


@dataclass
class GeometryStore:
    """Folder of ``<digest>_s<samples>.npz`` geometry files (``digest``: the library's, per entry)."""

    folder: Path
    digest: Callable[[CadEntry], str]

    def path(self, entry: CadEntry, samples: int) -> Path:
        return self.folder / f"{self.digest(entry)}_s{samples}_g{GEOMETRY_CACHE_VERSION}.npz"

    def load(self, entry: CadEntry, samples: int, source: Callable[[], CadModel]) -> ModelGeometry | None:
        path = self.path(entry, samples)
        if not path.is_file():
            return None
        try:
            with np.load(path, allow_pickle=False) as npz:
                data = {k: npz[k] for k in npz.files}
            return restore_geometry(entry.key, data, source)
        except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
            log.warning("geometry cache %s unreadable (%s): rebuilding it", path, exc)
            return None

    def save(self, entry: CadEntry, samples: int, geom: ModelGeometry) -> None:
        mesh = geom.mesh if geom.mesh is not None else geom.model.mesh()
        arrays = geometry_arrays(geom, mesh, geom.swept)
        path = self.path(entry, samples)
        try:
            write_npz_atomic(path, arrays, sync=False)
        except OSError as exc:  # a read-only or full cache folder costs speed, never a run
            log.warning("geometry cache %s not written (%s)", path, exc)


@dataclass
class GeometryCache:
    """LRU cache of ``ModelGeometry`` by library entry key (models repeat across a scene), backed
    by an optional ``GeometryStore`` on disk (models repeat across scenes and runs too)."""

    loader: Callable[[CadEntry], CadModel]
    capacity: int = 256
    samples: int = 1200
    store: GeometryStore | None = None
    built: int = 0  # geometry computed from a model (not from memory or disk), for the records
    restored: int = 0
    _items: OrderedDict[str, ModelGeometry] = field(default_factory=OrderedDict)

    def get(self, entry: CadEntry) -> ModelGeometry:
        hit = self._items.get(entry.key)
        if hit is not None:
            self._items.move_to_end(entry.key)
            return hit
        geom = None
        if self.store is not None:
            geom = self.store.load(entry, self.samples, lambda: self.loader(entry))
        if geom is not None:
            self.restored += 1
        else:
            geom = ModelGeometry.build(entry.key, self.loader(entry), samples=self.samples)
            self.built += 1
            if self.store is not None:
                self.store.save(entry, self.samples, geom)
        self._items[entry.key] = geom
        while len(self._items) > self.capacity:
            self._items.popitem(last=False)
        return geom


def library_store(library: object) -> GeometryStore | None:
    """The disk store beside a library's feature cache, when the library has one."""
    cache_dir = getattr(library, "cache_dir", None)
    digest = getattr(library, "digest", None)
    if not isinstance(cache_dir, Path) or digest is None:
        return None
    return GeometryStore(cache_dir.parent / "cad_geometry" if cache_dir.name == "cad_features"
                         else cache_dir / "geometry", digest)


__all__ = ["GEOMETRY_CACHE_VERSION", "GeometryCache", "GeometryStore", "library_store", "restore_geometry"]
