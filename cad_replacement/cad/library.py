"""The CAD database: procedural models (class x seeds) plus imported URDF models, with a feature cache.

Matching (paper Sec. 4.2) compares a segmented object against *every* CAD model of its class, so
the models' features (box, planes, support surfaces) must be at hand without rebuilding meshes or
re-running RANSAC. ``CadLibrary`` computes them once per model definition and stores them as JSON
files named by a SHA-256 digest of the definition:

* procedural: class, seed, overrides, ``PROCEDURAL_VERSION`` and ``FEATURE_CACHE_VERSION``;
* imported: the bytes of the URDFs, meshes and metadata files of the model folder, the URDF's
  path in it (a folder may hold several models), the class and ``FEATURE_CACHE_VERSION``.

Change the code or the files and the digest changes, so stale entries are never read. No pickle is
used anywhere; a corrupt cache file is ignored and rewritten.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from cad_replacement.cad.asset_files import MESH_SUFFIXES, default_model_id, find_urdfs
from cad_replacement.cad.feature_types import ModelFeatures
from cad_replacement.cad.import_meta import load_model_meta
from cad_replacement.cad.model import CadModel
from cad_replacement.cad.model_store import ModelStore
from cad_replacement.cad.params import ParamValue
from cad_replacement.cad.procedural import (
    CLASS_BUILDERS,
    build_model,
    definition_digest,
    procedural_definition,
    procedural_features,
    procedural_model_id,
)
from cad_replacement.cad.urdf_import import CadImportError, import_urdf_model
from recon_core.classes import ClassTable
from recon_core.names import sanitize_name

_log = logging.getLogger(__name__)

#: Bump whenever feature extraction (analytic or RANSAC) changes: invalidates every cache file.
FEATURE_CACHE_VERSION = "2"
#: Procedural seeds per class enumerated by default.
DEFAULT_SEEDS_PER_CLASS = 10
#: Classes of varied layout (``ClassBuilder.layout_varied``: articulated fronts, shelves' levels)
#: enumerate this many times the seeds: doors, drawers, drawers over doors, their counts and hinge
#: sides, or the number and spacing of shelf boards come in discrete variants that ten models cannot
#: cover, and a model with another layout gives the object the wrong joints or moves what stands in
#: it to another height. On the benchmark suite with an unseen library (factor 1 -> 2): joint
#: type/count right for 88.6 -> 91.0 % of objects, the contact graph's GED unchanged by replacement
#: (a book had been lifted 6.5 cm onto the nearest board of a shelf model). Factor 3 gave 91.6 % but
#: crowded the exact model out of the candidates with the library holding it (pose 91.0 -> 89.6 %).
LAYOUT_SEED_FACTOR = 2
#: Built models a library keeps in memory (``CadLibrary.model``).
MODEL_CACHE_SIZE = 128
#: Files of an imported model folder that enter its digest.
_HASHED_SUFFIXES = (*MESH_SUFFIXES, ".urdf", ".yaml", ".yml", ".mtl", ".bin")
_CACHE_FORMAT = "scene_recon.cad_features"


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/scene_recon/cad_features`` (``~/.cache/...`` when unset)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "scene_recon" / "cad_features"


@dataclass(frozen=True)
class CadEntry:
    """One model of the library, cheap to enumerate (nothing is built or loaded).

    Imported models: ``path`` is the URDF file, ``asset_root`` the model folder it may read from.
    """

    key: str
    class_name: str
    kind: Literal["procedural", "urdf"]
    seed: int | None = None
    path: Path | None = None
    asset_root: Path | None = None
    #: Procedural parameters pinned on top of the seed's draw (``cad.layouts``: the same model with
    #: another front layout); sorted (name, value) pairs, part of ``key``.
    overrides: tuple[tuple[str, ParamValue], ...] = ()


@dataclass
class CacheStats:
    """How feature requests were served (for tests and logging)."""

    memory_hits: int = 0
    disk_hits: int = 0
    computed: int = 0


@dataclass
class CadLibrary:
    """Enumerates CAD models and serves their cached features.

    ``root``: folder of imported models (``<root>/<class>/<folder>/*.urdf``, one model per URDF;
    see ``urdf_import``), or ``None``. ``cache_dir``: where feature JSON files go (default
    ``default_cache_dir()``). ``classes`` restricts the procedural classes; ``class_table``
    (optional) drops imported models whose class it does not know.
    """

    root: Path | str | None = None
    cache_dir: Path | str | None = None
    seeds_per_class: int = DEFAULT_SEEDS_PER_CLASS
    #: ``seeds_per_class`` times this for classes of varied layout (``LAYOUT_SEED_FACTOR``).
    layout_seed_factor: int = LAYOUT_SEED_FACTOR
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
        if self.layout_seed_factor < 1:
            raise ValueError("layout_seed_factor must be >= 1")
        wanted = set(self.classes) if self.classes is not None else set(CLASS_BUILDERS)
        unknown = sorted(wanted - set(CLASS_BUILDERS))
        if unknown:
            raise ValueError(f"no procedural builders for {unknown}; supported: {sorted(CLASS_BUILDERS)}")
        self._procedural_classes = sorted(wanted)
        self._memory: dict[str, ModelFeatures] = {}
        self._models: OrderedDict[str, CadModel] = OrderedDict()
        self._digests: dict[str, str] = {}
        self._folder_digests: dict[Path, bytes] = {}
        self._entries = self._scan()

    # ------------------------------------------------------------------ enumeration
    def _scan(self) -> list[CadEntry]:
        entries = [
            CadEntry(f"procedural/{c}/{procedural_model_id(c, s)}", c, "procedural", seed=s)
            for c in self._procedural_classes
            for s in range(self.seeds_for(c))
        ]
        root = self.root
        if not isinstance(root, Path) or not root.is_dir():
            return entries
        for class_dir in sorted(p for p in root.iterdir() if p.is_dir()):
            for model_dir in sorted(p for p in class_dir.iterdir() if p.is_dir()):
                try:
                    urdfs = find_urdfs(model_dir)
                except CadImportError as exc:
                    self._skip(model_dir, str(exc))
                    continue
                for urdf in urdfs:
                    entry = self._urdf_entry(urdf, model_dir, sanitize_name(class_dir.name), len(urdfs) > 1)
                    if entry is None:
                        continue
                    if any(e.key == entry.key for e in entries):
                        self._skip(urdf, f"model key {entry.key!r} is already taken by another URDF")
                        continue
                    entries.append(entry)
        return entries

    def seeds_for(self, class_name: str) -> int:
        """How many procedural seeds (0 .. n-1) the library enumerates for a class."""
        builder = CLASS_BUILDERS.get(class_name)
        factor = self.layout_seed_factor if builder is not None and builder.layout_varied else 1
        return self.seeds_per_class * factor

    def _urdf_entry(self, urdf: Path, model_dir: Path, folder_class: str, shared: bool) -> CadEntry | None:
        """The entry of one URDF (class and id from its metadata), or ``None`` when unusable."""
        try:
            meta = load_model_meta(urdf, model_dir, shared_folder=shared)
        except CadImportError as exc:
            self._skip(urdf, str(exc))
            return None
        cls = meta.class_name or folder_class
        if self.class_table is not None and cls not in self.class_table:
            self._skip(urdf, f"class {cls!r} is not in the class table")
            return None
        model_id = meta.model_id or default_model_id(urdf, model_dir)
        return CadEntry(f"urdf/{cls}/{model_id}", cls, "urdf", path=urdf, asset_root=model_dir)

    def _skip(self, path: Path, message: str) -> None:
        _log.warning("skipping CAD model %s: %s", path, message)
        self.errors.append((str(path), message))

    def entries(self, class_name: str | None = None) -> list[CadEntry]:
        """All models, or those of one class."""
        return [e for e in self._entries if class_name is None or e.class_name == class_name]

    def entry(self, key: str) -> CadEntry | None:
        """The model a ``cad_id`` names (``replacement.json``): one of ``entries()``, or a front-layout
        variant of a procedural one (``cad.layouts``); ``None`` when the library has no such model."""
        from cad_replacement.cad.layouts import parse_variant_key, variant_entry

        base_key, overrides = parse_variant_key(key)
        base = next((e for e in self._entries if e.key == base_key), None)
        if base is None or not overrides:
            return base
        try:
            return variant_entry(base, overrides)
        except ValueError:
            return None

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
            definition: dict[str, Any] = procedural_definition(entry.class_name, entry.seed, dict(entry.overrides))
            definition["features"] = FEATURE_CACHE_VERSION
            value = definition_digest(definition)
        else:
            assert entry.path is not None and entry.asset_root is not None
            urdf = entry.path.relative_to(entry.asset_root).as_posix()
            h = hashlib.sha256(f"urdf\0{FEATURE_CACHE_VERSION}\0{entry.class_name}\0{urdf}\0".encode())
            h.update(self._folder_digest(entry.asset_root))
            value = h.hexdigest()
        self._digests[entry.key] = value
        return value

    def _folder_digest(self, folder: Path) -> bytes:
        """SHA-256 over the relevant files of an asset folder, computed once for all its URDFs."""
        cached = self._folder_digests.get(folder)
        if cached is not None:
            return cached
        h = hashlib.sha256()
        files = sorted(p for p in folder.rglob("*") if p.is_file() and p.suffix.lower() in _HASHED_SUFFIXES)
        for p in files:
            h.update(p.relative_to(folder).as_posix().encode() + b"\0")
            h.update(hashlib.sha256(p.read_bytes()).digest())
        self._folder_digests[folder] = h.digest()
        return self._folder_digests[folder]

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
        """Full model (meshes and joints); imported models get their features from the cache.

        The last ``MODEL_CACHE_SIZE`` models are kept (models are immutable): every replacement of a
        running node's graph rebuilt its chosen models, 9 ms each for a procedural cabinet."""
        key = self.digest(entry)
        hit = self._models.get(key)
        if hit is not None:
            self._models.move_to_end(key)
            return hit
        store = self.model_store if entry.kind == "procedural" else None
        model = store.load(entry, lambda: self.features(entry)) if store is not None else None
        if model is None:
            model = self._build(entry)
        self._remember(key, model)
        return model

    @property
    def model_store(self) -> ModelStore | None:
        """Built procedural models with their collision shapes (``model_store``), beside the feature cache."""
        if not isinstance(self.cache_dir, Path):
            return None
        folder = self.cache_dir.parent / "cad_models" if self.cache_dir.name == "cad_features" \
            else self.cache_dir / "models"
        return ModelStore(folder, self.digest)

    def keep_model(self, entry: CadEntry) -> None:
        """Store the entry's built model with its collision shapes (computed now if they were not) for
        the next process: a worker does it for the model it chose, so that the process that checks and
        exports the scene reads it instead of building it (procedural models only; once per model)."""
        store = self.model_store if entry.kind == "procedural" else None
        if store is not None and not store.has(entry):
            store.save(entry, self.model(entry))

    def _remember(self, key: str, model: CadModel) -> None:
        self._models[key] = model
        while len(self._models) > MODEL_CACHE_SIZE:
            self._models.popitem(last=False)

    def __getstate__(self) -> dict[str, Any]:
        """Pickled (to worker processes) without the built models: they rebuild what they use."""
        state = dict(self.__dict__)
        state["_models"] = OrderedDict()
        return state

    def _build(self, entry: CadEntry) -> CadModel:
        if entry.kind == "procedural":
            assert entry.seed is not None
            return build_model(entry.class_name, entry.seed, overrides=dict(entry.overrides) or None)
        assert entry.path is not None
        m = import_urdf_model(
            entry.path,
            class_name=entry.class_name,
            model_id=entry.key.rsplit("/", 1)[-1],
            asset_root=entry.asset_root,
            compute_features=False,
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
            # analytic, from the builder's parts: no mesh is built for features (matching reads every model
            # of a class, alignment builds the shortlisted ones: 144 of the 220 models with empty caches on a
            # 20-object scene; building all 220 had cost 2.8 CPU s of the run's 9.5)
            model = self._models.get(digest)
            if model is not None:
                return model.features
            return procedural_features(entry.class_name, entry.seed, overrides=dict(entry.overrides) or None)
        assert entry.path is not None
        seed = int(digest[:8], 16)
        model = import_urdf_model(
            entry.path,
            class_name=entry.class_name,
            model_id=entry.key.rsplit("/", 1)[-1],
            asset_root=entry.asset_root,
            collisions=False,  # features need no convex decomposition
            seed=seed,
        )
        return model.features

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
                f.write(json.dumps(payload))  # one string: ``json.dump`` encodes in Python, 3x slower
            os.replace(tmp, path)
        except OSError as exc:  # a read-only cache must not break matching
            _log.warning("cannot write feature cache %s: %s", path, exc)
