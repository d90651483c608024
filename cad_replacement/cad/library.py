"""The CAD database: procedural models (class x seeds) plus imported URDF models, with a feature cache.

Matching (paper Sec. 4.2) compares a segmented object against *every* CAD model of its class, so
the models' features (box, planes, support surfaces) must be at hand without rebuilding meshes or
re-running RANSAC. ``CadLibrary`` computes them once per model definition and stores them as JSON
files named by a SHA-256 digest of the definition:

* procedural: class, seed, overrides, ``PROCEDURAL_VERSION`` and ``FEATURE_CACHE_VERSION``;
* imported: the bytes of the URDF, meshes and ``meta.yaml`` of the model folder, the class and
  ``FEATURE_CACHE_VERSION``.

Change the code or the files and the digest changes, so stale entries are never read. No pickle is
used anywhere; a corrupt cache file is ignored and rewritten.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from cad_replacement.cad.feature_types import ModelFeatures
from cad_replacement.cad.model import CadModel
from cad_replacement.cad.procedural import (
    CLASS_BUILDERS,
    build_model,
    definition_digest,
    procedural_definition,
    procedural_model_id,
)
from cad_replacement.cad.urdf_import import (
    MESH_SUFFIXES,
    META_FILE,
    CadImportError,
    find_urdf,
    import_urdf_model,
    load_meta,
)
from recon_core.classes import ClassTable
from recon_core.names import sanitize_name

_log = logging.getLogger(__name__)

#: Bump whenever feature extraction (analytic or RANSAC) changes: invalidates every cache file.
FEATURE_CACHE_VERSION = "1"
#: Procedural seeds per class enumerated by default.
DEFAULT_SEEDS_PER_CLASS = 10
#: Files of an imported model folder that enter its digest.
_HASHED_SUFFIXES = (*MESH_SUFFIXES, ".urdf", ".yaml", ".yml", ".mtl")
_CACHE_FORMAT = "scene_recon.cad_features"


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/scene_recon/cad_features`` (``~/.cache/...`` when unset)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "scene_recon" / "cad_features"


@dataclass(frozen=True)
class CadEntry:
    """One model of the library, cheap to enumerate (nothing is built or loaded)."""

    key: str
    class_name: str
    kind: Literal["procedural", "urdf"]
    seed: int | None = None
    path: Path | None = None


@dataclass
class CacheStats:
    """How feature requests were served (for tests and logging)."""

    memory_hits: int = 0
    disk_hits: int = 0
    computed: int = 0


@dataclass
class CadLibrary:
    """Enumerates CAD models and serves their cached features.

    ``root``: folder of imported models (``<root>/<class>/<model_id>/*.urdf``; see
    ``urdf_import``), or ``None``. ``cache_dir``: where feature JSON files go (default
    ``default_cache_dir()``). ``classes`` restricts the procedural classes; ``class_table``
    (optional) drops imported models whose class it does not know.
    """

    root: Path | str | None = None
    cache_dir: Path | str | None = None
    seeds_per_class: int = DEFAULT_SEEDS_PER_CLASS
    classes: Iterable[str] | None = None
    class_table: ClassTable | None = None
    stats: CacheStats = field(default_factory=CacheStats)
    #: Problems met while scanning or loading imported models: (path, message).
    errors: list[tuple[str, str]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.cache_dir = Path(self.cache_dir) if self.cache_dir is not None else default_cache_dir()
        self.root = Path(self.root) if self.root is not None else None
        if self.seeds_per_class < 0:
            raise ValueError("seeds_per_class must be >= 0")
        wanted = set(self.classes) if self.classes is not None else set(CLASS_BUILDERS)
        unknown = sorted(wanted - set(CLASS_BUILDERS))
        if unknown:
            raise ValueError(f"no procedural builders for {unknown}; supported: {sorted(CLASS_BUILDERS)}")
        self._procedural_classes = sorted(wanted)
        self._memory: dict[str, ModelFeatures] = {}
        self._digests: dict[str, str] = {}
        self._entries = self._scan()

    # ------------------------------------------------------------------ enumeration
    def _scan(self) -> list[CadEntry]:
        entries = [
            CadEntry(f"procedural/{c}/{procedural_model_id(c, s)}", c, "procedural", seed=s)
            for c in self._procedural_classes
            for s in range(self.seeds_per_class)
        ]
        root = self.root
        if not isinstance(root, Path) or not root.is_dir():
            return entries
        for class_dir in sorted(p for p in root.iterdir() if p.is_dir()):
            for model_dir in sorted(p for p in class_dir.iterdir() if p.is_dir()):
                try:
                    find_urdf(model_dir)
                    meta = load_meta(model_dir / META_FILE) if (model_dir / META_FILE).is_file() else None
                except CadImportError as exc:
                    self._skip(model_dir, str(exc))
                    continue
                cls = (meta.class_name if meta and meta.class_name else None) or sanitize_name(class_dir.name)
                if self.class_table is not None and cls not in self.class_table:
                    self._skip(model_dir, f"class {cls!r} is not in the class table")
                    continue
                model_id = (meta.model_id if meta and meta.model_id else None) or sanitize_name(model_dir.name)
                entries.append(CadEntry(f"urdf/{cls}/{model_id}", cls, "urdf", path=model_dir))
        return entries

    def _skip(self, path: Path, message: str) -> None:
        _log.warning("skipping CAD model %s: %s", path, message)
        self.errors.append((str(path), message))

    def entries(self, class_name: str | None = None) -> list[CadEntry]:
        """All models, or those of one class."""
        return [e for e in self._entries if class_name is None or e.class_name == class_name]

    @property
    def class_names(self) -> list[str]:
        return sorted({e.class_name for e in self._entries})

    # ------------------------------------------------------------------ digests
    def digest(self, entry: CadEntry) -> str:
        """SHA-256 of everything that determines the entry's features (see module docstring)."""
        cached = self._digests.get(entry.key)
        if cached is not None:
            return cached
        if entry.kind == "procedural":
            assert entry.seed is not None
            definition: dict[str, Any] = procedural_definition(entry.class_name, entry.seed)
            definition["features"] = FEATURE_CACHE_VERSION
            value = definition_digest(definition)
        else:
            assert entry.path is not None
            h = hashlib.sha256(f"urdf\0{FEATURE_CACHE_VERSION}\0{entry.class_name}\0".encode())
            files = sorted(p for p in entry.path.rglob("*") if p.is_file() and p.suffix.lower() in _HASHED_SUFFIXES)
            for p in files:
                h.update(p.relative_to(entry.path).as_posix().encode() + b"\0")
                h.update(hashlib.sha256(p.read_bytes()).digest())
            value = h.hexdigest()
        self._digests[entry.key] = value
        return value

    def cache_path(self, entry: CadEntry) -> Path:
        assert isinstance(self.cache_dir, Path)
        return self.cache_dir / f"{self.digest(entry)}.json"

    # ------------------------------------------------------------------ features and models
    def features(self, entry: CadEntry) -> ModelFeatures:
        """The entry's features: from memory, else the JSON cache, else computed and stored."""
        digest = self.digest(entry)
        hit = self._memory.get(digest)
        if hit is not None:
            self.stats.memory_hits += 1
            return hit
        feats = self._read_cache(entry, digest)
        if feats is not None:
            self.stats.disk_hits += 1
        else:
            feats = self._compute(entry, digest)
            self.stats.computed += 1
            self._write_cache(entry, digest, feats)
        self._memory[digest] = feats
        return feats

    def model(self, entry: CadEntry) -> CadModel:
        """Full model (meshes and joints); imported models get their features from the cache."""
        if entry.kind == "procedural":
            assert entry.seed is not None
            return build_model(entry.class_name, entry.seed)
        assert entry.path is not None
        m = import_urdf_model(
            entry.path, class_name=entry.class_name, model_id=entry.key.rsplit("/", 1)[-1], compute_features=False
        )
        return m.with_features(self.features(entry))

    def candidates(self, class_name: str) -> list[tuple[CadEntry, ModelFeatures]]:
        """Features of every usable model of a class; broken imports are logged and skipped."""
        out = []
        for e in self.entries(class_name):
            try:
                out.append((e, self.features(e)))
            except CadImportError as exc:
                self._skip(e.path or Path(e.key), str(exc))
        return out

    def _compute(self, entry: CadEntry, digest: str) -> ModelFeatures:
        if entry.kind == "procedural":
            assert entry.seed is not None
            return build_model(entry.class_name, entry.seed).features
        assert entry.path is not None
        seed = int(digest[:8], 16)
        return import_urdf_model(entry.path, class_name=entry.class_name, seed=seed).features

    # ------------------------------------------------------------------ JSON cache
    def _read_cache(self, entry: CadEntry, digest: str) -> ModelFeatures | None:
        path = self.cache_path(entry)
        if not path.is_file():
            return None
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            if data.get("format") != _CACHE_FORMAT or data.get("digest") != digest:
                raise ValueError("format/digest mismatch")
            return ModelFeatures.from_dict(data["features"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            _log.warning("ignoring unreadable feature cache %s: %s", path, exc)
            return None

    def _write_cache(self, entry: CadEntry, digest: str, feats: ModelFeatures) -> None:
        path = self.cache_path(entry)
        payload = {
            "format": _CACHE_FORMAT,
            "version": FEATURE_CACHE_VERSION,
            "digest": digest,
            "key": entry.key,
            "class": entry.class_name,
            "features": feats.to_dict(),
        }
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".json")
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                json.dump(payload, f)
            os.replace(tmp, path)
        except OSError as exc:  # a read-only cache must not break matching
            _log.warning("cannot write feature cache %s: %s", path, exc)
