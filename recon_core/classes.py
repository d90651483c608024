"""The project's semantic class table (``config/classes.yaml``): ids, categories, COCO mapping.

One file is the single source of truth for class ids, which classes are layout/rigid/articulated,
which ones a robot may move (floating vs. fixed joints in the exported kinematic tree), the
density used for link masses, how COCO panoptic labels map onto project classes and which classes
a segmentation network tends to confuse. The id ``UNKNOWN_CLASS_ID`` (-1) is reserved for
"unknown" and never appears in the file.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import yaml

from recon_core.config import CONFIG_DIR
from recon_core.errors import ConfigError, UnknownClassError

#: Id of the "unknown" class; handled in code, never listed in the YAML file.
UNKNOWN_CLASS_ID = -1
#: Name of the generic thing class that detector classes without a class of their own map to (a
#: COCO sink, bowl or laptop): mapped and exported with its observed mesh, since no CAD model
#: exists for it. Optional in a class table.
GENERIC_CLASS_NAME = "object"
#: Default location of the class table in a source checkout.
DEFAULT_CLASS_TABLE = CONFIG_DIR / "classes.yaml"

Category = Literal["layout", "rigid", "articulated"]
CATEGORIES: tuple[str, ...] = ("layout", "rigid", "articulated")
_NAME_RE = re.compile(r"^[a-z][a-z0-9_]*$")
_CLASS_KEYS = {"id", "name", "category", "is_thing", "movable", "density", "coco"}
#: Keys a class may leave out (default false).
_OPTIONAL_CLASS_KEYS = {"round", "max_size_m", "flush", "symmetry"}
#: Values of a class's ``symmetry`` key: "round" (any yaw; order 0) or the order of its turn symmetry.
SYMMETRY_ROUND = 0
_SYMMETRY_VALUES = {"round": SYMMETRY_ROUND, 1: 1, 2: 2, 4: 4}
_TOP_KEYS = {"version", "classes", "confusion_groups"}


@dataclass(frozen=True)
class ClassInfo:
    """One semantic class; see ``config/classes.yaml`` for the meaning of each field."""

    id: int
    name: str
    category: Category
    is_thing: bool
    movable: bool
    density: float | None
    coco_names: tuple[str, ...] = ()
    confusable_with: tuple[str, ...] = ()
    #: The body is a solid of revolution about the vertical (cups, bottles): its two horizontal
    #: extents are one radius, so CAD alignment fits them as one scale.
    round: bool = False
    #: Largest extent (m) an instance of the class can have (None: unknown). A mapped instance whose
    #: mesh holds a horizontal or vertical plane much larger than this has swallowed layout surface
    #: (a detection mask bleeding onto the wall): the contact-graph builder gives that plane back.
    max_size_m: float | None = None
    #: Instances may lie flat in a layout plane (a screen on a wall): the faces they have in a floor or
    #: wall plane are theirs. Other things give such faces to the layout (scene_graph.geometric_layout).
    flush: bool = False
    #: Every instance of the class looks the same after these turns about the vertical: 0 (round: any
    #: yaw, a bottle), 2 (a half turn), 4 (a quarter turn), 1 (none: it has a front); None when the
    #: class does not say and each model's own geometry decides (a cup with a handle has a front, one
    #: without is round). Stage 4 tries only the orientations the symmetry leaves distinct, and the
    #: evaluation scores a yaw modulo it.
    symmetry: int | None = None

    @property
    def is_layout(self) -> bool:
        return self.category == "layout"

    @property
    def is_articulated(self) -> bool:
        return self.category == "articulated"


class ClassTable:
    """Immutable lookup tables over the classes (by name, id and COCO name)."""

    def __init__(self, classes: Sequence[ClassInfo], confusion_groups: Sequence[Sequence[str]] = ()) -> None:
        self._classes = tuple(classes)
        self._by_name = {c.name: c for c in self._classes}
        self._by_id = {c.id: c for c in self._classes}
        self._by_coco = {coco: c for c in self._classes for coco in c.coco_names}
        self.confusion_groups = tuple(tuple(g) for g in confusion_groups)

    def __iter__(self) -> Iterator[ClassInfo]:
        return iter(self._classes)

    def __len__(self) -> int:
        return len(self._classes)

    def __contains__(self, name: object) -> bool:
        return name in self._by_name

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self._classes)

    def by_name(self, name: str) -> ClassInfo:
        try:
            return self._by_name[name]
        except KeyError:
            raise UnknownClassError(f"unknown class name {name!r}; known: {sorted(self._by_name)}") from None

    def by_id(self, class_id: int) -> ClassInfo:
        try:
            return self._by_id[class_id]
        except KeyError:
            hint = " (-1 is the reserved 'unknown' id)" if class_id == UNKNOWN_CLASS_ID else ""
            raise UnknownClassError(f"unknown class id {class_id!r}{hint}; known: {sorted(self._by_id)}") from None

    def from_coco(self, coco_name: str) -> ClassInfo:
        """Project class of a COCO panoptic category name; raises for unmapped names."""
        try:
            return self._by_coco[coco_name]
        except KeyError:
            raise UnknownClassError(f"COCO category {coco_name!r} maps to no project class") from None

    def get_by_coco(self, coco_name: str) -> ClassInfo | None:
        """Like ``from_coco`` but ``None`` for unmapped names (most COCO classes are ignored)."""
        return self._by_coco.get(coco_name)

    def id_of(self, name: str) -> int:
        """Id of a class name; ``UNKNOWN_CLASS_ID`` maps back from the name "unknown"."""
        if name == "unknown":
            return UNKNOWN_CLASS_ID
        return self.by_name(name).id

    def of_category(self, category: Category) -> tuple[ClassInfo, ...]:
        return tuple(c for c in self._classes if c.category == category)


def _fail(path: Path, where: str, msg: str) -> ConfigError:
    return ConfigError(f"{path}: {where}: {msg}")


def _parse_class(path: Path, index: int, raw: Any) -> ClassInfo:
    where = f"classes[{index}]"
    if not isinstance(raw, Mapping):
        raise _fail(path, where, "expected a mapping")
    keys = set(raw)
    if not _CLASS_KEYS <= keys <= _CLASS_KEYS | _OPTIONAL_CLASS_KEYS:
        missing, extra = sorted(_CLASS_KEYS - keys), sorted(keys - _CLASS_KEYS - _OPTIONAL_CLASS_KEYS)
        raise _fail(path, where, f"missing keys {missing}, unknown keys {extra}")
    cid, name = raw["id"], raw["name"]
    if isinstance(cid, bool) or not isinstance(cid, int) or cid < 0:
        raise _fail(path, where, f"id must be a non-negative integer, got {cid!r}")
    if not isinstance(name, str) or not _NAME_RE.match(name) or name == "unknown":
        raise _fail(path, where, f"name must match {_NAME_RE.pattern} and not be 'unknown', got {name!r}")
    where = f"class {name!r}"
    if raw["category"] not in CATEGORIES:
        raise _fail(path, where, f"category must be one of {CATEGORIES}, got {raw['category']!r}")
    for flag in ("is_thing", "movable", "round", "flush"):
        if not isinstance(raw.get(flag, False), bool):
            raise _fail(path, where, f"{flag} must be true/false, got {raw.get(flag)!r}")
    density = raw["density"]
    if density is not None:
        if (
            isinstance(density, bool)
            or not isinstance(density, (int, float))
            or not math.isfinite(density)
            or density <= 0
        ):
            raise _fail(path, where, f"density must be a positive number or null, got {density!r}")
        density = float(density)
    max_size = raw.get("max_size_m")
    if max_size is not None and (isinstance(max_size, bool) or not isinstance(max_size, (int, float))
                                 or not math.isfinite(max_size) or max_size <= 0):
        raise _fail(path, where, f"max_size_m must be a positive number, got {max_size!r}")
    symmetry = raw.get("symmetry")
    if symmetry is not None and (isinstance(symmetry, bool) or symmetry not in _SYMMETRY_VALUES):
        raise _fail(path, where, f"symmetry must be round, 1, 2 or 4, got {symmetry!r}")
    if raw["category"] != "layout" and density is None:
        raise _fail(path, where, "object classes need a density")
    if raw["category"] == "layout" and raw["movable"]:
        raise _fail(path, where, "layout classes cannot be movable")
    coco = raw["coco"]
    if not isinstance(coco, list) or not all(isinstance(c, str) and c for c in coco):
        raise _fail(path, where, f"coco must be a list of names, got {coco!r}")
    return ClassInfo(
        id=cid,
        name=name,
        category=raw["category"],
        is_thing=raw["is_thing"],
        movable=raw["movable"],
        density=density,
        coco_names=tuple(coco),
        round=raw.get("round", False),
        max_size_m=float(max_size) if max_size is not None else None,
        flush=raw.get("flush", False),
        symmetry=_SYMMETRY_VALUES[symmetry] if symmetry is not None else None,
    )


def parse_class_table(data: Any, path: Path | str = "<memory>") -> ClassTable:
    """Validate an already-loaded YAML document and build the table."""
    path = Path(path)
    if not isinstance(data, Mapping):
        raise _fail(path, "top level", "expected a mapping with 'classes'")
    extra = sorted(set(data) - _TOP_KEYS)
    if extra or "classes" not in data:
        raise _fail(path, "top level", f"need 'classes'; unknown keys {extra}")
    raw_classes = data["classes"]
    if not isinstance(raw_classes, list) or not raw_classes:
        raise _fail(path, "classes", "expected a non-empty list")
    parsed = [_parse_class(path, i, c) for i, c in enumerate(raw_classes)]
    for attr in ("id", "name"):
        values = [getattr(c, attr) for c in parsed]
        dupes = sorted({v for v in values if values.count(v) > 1}, key=str)
        if dupes:
            raise _fail(path, "classes", f"duplicate {attr}s {dupes}")
    coco_all = [n for c in parsed for n in c.coco_names]
    dupes = sorted({n for n in coco_all if coco_all.count(n) > 1})
    if dupes:
        raise _fail(path, "classes", f"COCO names mapped to several classes: {dupes}")
    names = {c.name for c in parsed}
    groups = data.get("confusion_groups") or []
    if not isinstance(groups, list):
        raise _fail(path, "confusion_groups", "expected a list of lists")
    confusable: dict[str, set[str]] = {n: set() for n in names}
    for i, g in enumerate(groups):
        if not isinstance(g, list) or len(g) < 2 or not all(isinstance(n, str) for n in g):
            raise _fail(path, f"confusion_groups[{i}]", f"expected a list of >= 2 class names, got {g!r}")
        unknown = sorted(set(g) - names)
        if unknown:
            raise _fail(path, f"confusion_groups[{i}]", f"unknown classes {unknown}")
        for n in g:
            confusable[n].update(set(g) - {n})
    classes = [dataclasses.replace(c, confusable_with=tuple(sorted(confusable[c.name]))) for c in parsed]
    return ClassTable(classes, groups)


def load_class_table(path: Path | str | None = None) -> ClassTable:
    """Load and validate the class table (default: the repository's ``config/classes.yaml``)."""
    p = Path(path) if path is not None else DEFAULT_CLASS_TABLE
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read class table: {exc}") from exc
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{p}: invalid YAML: {exc}") from exc
    return parse_class_table(data, p)
