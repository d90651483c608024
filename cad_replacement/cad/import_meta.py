"""Per-model metadata of imported CAD assets (``meta.yaml``) and which way is up.

An asset folder may hold ``meta.yaml`` (applies to every URDF in the folder) and, next to a URDF,
``<stem>.meta.yaml`` (applies to that URDF only and overrides the folder's keys): a ReplicaCAD-like
folder keeps a fridge and a kitchen counter side by side, so the class has to be per file.

Keys (all optional): ``class`` (overrides the folder name), ``model_id``, ``up_axis`` /
``front_axis`` (which source axis, e.g. ``+y``, points up / to the front) and ``scale`` (source
units -> metres; masses stay as given, the URDF states them in kg).

Up axis: an explicit ``up_axis`` always wins. Without one the mesh formats decide, because they
carry the only reliable convention: glTF (``.glb``/``.gltf``) is y-up with the front along +z by
specification and trimesh loads it untouched, so a URDF whose visuals are glTF (ReplicaCAD, authored
for Habitat's y-up world, joint axes included) is y-up as a whole; every other URDF follows ROS
REP 103 (z up, front +x). A URDF mixing glTF with other formats is ambiguous and must say
``up_axis``. The geometry is not used to guess: the bounding box of a cabinet cannot tell its height
from its width, and a wrong guess would silently lay furniture on its side. Collada's own
``<up_axis>`` tag is ignored like RViz and Gazebo do (ROS meshes are authored to look right there,
and many writers -- trimesh among them -- stamp ``Y_UP`` on z-up data).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from recon_core.errors import CadImportError
from recon_core.geometry.transforms import rotation_from_axes
from recon_core.names import sanitize_name

META_FILE = "meta.yaml"
#: Suffix of a per-URDF metadata file (``<stem>.meta.yaml``).
META_SUFFIX = ".meta.yaml"
GLTF_SUFFIXES = (".glb", ".gltf")
AXES = {
    "+x": (1.0, 0.0, 0.0),
    "-x": (-1.0, 0.0, 0.0),
    "+y": (0.0, 1.0, 0.0),
    "-y": (0.0, -1.0, 0.0),
    "+z": (0.0, 0.0, 1.0),
    "-z": (0.0, 0.0, -1.0),
}
#: (up, front) conventions: ROS REP 103 and glTF 2.0.
ROS_AXES = ("+z", "+x")
GLTF_AXES = ("+y", "+z")
_META_KEYS = {"class", "model_id", "up_axis", "front_axis", "scale"}


@dataclass(frozen=True)
class ImportMeta:
    """Optional per-model metadata; ``None`` axes mean "decide from the mesh formats"."""

    class_name: str | None = None
    model_id: str | None = None
    up_axis: str | None = None
    front_axis: str | None = None
    scale: float = 1.0


@dataclass(frozen=True)
class SourceFrame:
    """Which source axes point up and to the front, and why (recorded in the model's params)."""

    up: str
    front: str
    reason: str

    def rotation(self) -> np.ndarray:
        """Rotation taking the source axes to the canonical ones (up -> +z, front -> +x)."""
        return rotation_from_axes(AXES[self.up], AXES[self.front])


def load_meta(path: Path | str) -> ImportMeta:
    """Read and validate one metadata file; raise ``CadImportError`` on any problem."""
    return parse_meta(read_meta_mapping(Path(path)), path)


def read_meta_mapping(path: Path) -> dict[str, Any]:
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    except (OSError, yaml.YAMLError, UnicodeDecodeError) as exc:
        raise CadImportError(f"{path}: cannot read metadata: {exc}") from exc
    if not isinstance(data, Mapping):
        raise CadImportError(f"{path}: metadata must be a mapping")
    return dict(data)


def load_model_meta(urdf: Path, asset_root: Path, *, shared_folder: bool) -> ImportMeta:
    """Metadata of one URDF: the folder's ``meta.yaml`` overridden by ``<stem>.meta.yaml``.

    ``shared_folder`` says the folder holds several models: a ``model_id`` in the folder-wide
    file would then name them all alike, which is refused.
    """
    folder_file = asset_root / META_FILE
    own_file = urdf.with_name(urdf.stem + META_SUFFIX)
    data: dict[str, Any] = {}
    if folder_file.is_file():
        data = read_meta_mapping(folder_file)
        if shared_folder and "model_id" in data:
            raise CadImportError(
                f"{folder_file}: 'model_id' is ambiguous in a folder with several URDFs; "
                f"put it in <stem>{META_SUFFIX} next to each URDF"
            )
    if own_file.is_file():
        data.update(read_meta_mapping(own_file))
    where = own_file if own_file.is_file() else folder_file
    return parse_meta(data, where)


def parse_meta(data: Any, where: Path | str = "<meta>") -> ImportMeta:
    if not isinstance(data, Mapping):
        raise CadImportError(f"{where}: metadata must be a mapping")
    unknown = sorted(set(data) - _META_KEYS)
    if unknown:
        raise CadImportError(f"{where}: unknown metadata keys {unknown}; allowed {sorted(_META_KEYS)}")
    axes = {key: None if data.get(key) is None else str(data[key]) for key in ("up_axis", "front_axis")}
    for key, axis in axes.items():
        if axis is not None and axis not in AXES:
            raise CadImportError(f"{where}: {key} must be one of {sorted(AXES)}, got {axis!r}")
    up, front = axes["up_axis"], axes["front_axis"]
    if up is not None and front is not None:
        _check_perpendicular(up, front, where)
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


def _check_perpendicular(up: str, front: str, where: Path | str) -> None:
    if abs(float(np.dot(AXES[up], AXES[front]))) > 0.5:
        raise CadImportError(f"{where}: up_axis {up} and front_axis {front} must be perpendicular")


def source_frame(meta: ImportMeta, visual_suffixes: Iterable[str], where: Path | str) -> SourceFrame:
    """The source frame of a model (see the module docstring for the rules).

    ``visual_suffixes``: file suffixes of the visual meshes (lower case, with the dot).
    """
    suffixes = set(visual_suffixes)
    gltf = {s for s in suffixes if s in GLTF_SUFFIXES}
    if meta.up_axis is not None:
        convention, reason = ROS_AXES, "meta"
        if gltf and gltf == suffixes:
            convention = GLTF_AXES
    elif not gltf:
        convention, reason = ROS_AXES, "urdf"
    elif gltf == suffixes:
        convention, reason = GLTF_AXES, "gltf"
    else:
        raise CadImportError(
            f"{where}: up axis is ambiguous: the visual meshes mix glTF (y-up by specification) with "
            f"{sorted(suffixes - gltf)} (z-up in ROS); set up_axis (and front_axis) in {META_FILE}"
        )
    up = meta.up_axis or convention[0]
    front = meta.front_axis or (convention[1] if meta.up_axis is None else _default_front(up, convention[1]))
    _check_perpendicular(up, front, where)
    return SourceFrame(up=up, front=front, reason=reason)


def _default_front(up: str, preferred: str) -> str:
    """The convention's front when it is perpendicular to an explicit up, else the first that is."""
    for cand in (preferred, "+x", "+z", "+y"):
        if abs(float(np.dot(AXES[up], AXES[cand]))) < 0.5:
            return cand
    raise AssertionError("unreachable: three axes cannot all be parallel to one")
