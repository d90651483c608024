"""One configuration schema for the CLI, the library and the ROS parameters.

Every stage describes its tunables as a (nested) dataclass with documented defaults; the YAML files
in `config/` hold the same keys. `load_config` reads a YAML file into the dataclass, rejecting
unknown keys (a typo must not silently fall back to a default); `flatten`/`unflatten` map the
nested structure to the dotted names used for ROS 2 parameters (`sync.slop_s`).

Validation is written once, here: a field declared with `setting(default, min=..., max=...,
choices=...)` carries its accepted range as field metadata, and the same rule is applied wherever a
value enters a config: `from_dict` (file, CLI overrides, ROS parameters; errors name the dotted key),
`validate` (the whole tree, after loading) and `Settings.__post_init__` (objects built in code).
Only cross-field conditions that a per-field range cannot say stay in a class's own
`__post_init__` (which calls `super().__post_init__()` first).
"""

from __future__ import annotations

import copy
import dataclasses
import importlib.resources
import os
import types
import typing
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar

import yaml

from recon_core.errors import ConfigError

T = TypeVar("T")

#: Python package under which the top-level ``config/`` folder is installed (setup.py maps it), so
#: an editable install, a wheel and a colcon/ament install all find the YAML files the same way.
CONFIG_PACKAGE = "recon_core.default_config"
#: Environment variable naming another folder with the same layout (site-specific defaults).
CONFIG_DIR_ENV = "SCENE_RECON_CONFIG_DIR"


def _config_dir() -> Path:
    override = os.environ.get(CONFIG_DIR_ENV)
    if override:
        return Path(override)
    try:
        return Path(str(importlib.resources.files(CONFIG_PACKAGE)))
    except ModuleNotFoundError:  # running from a checkout that was never installed
        return Path(__file__).resolve().parent.parent / "config"


#: Folder holding the project's default YAML files (see ``_config_dir``).
CONFIG_DIR = _config_dir()


def config_file(name: str) -> Path:
    """Path of a default configuration file (``"mapper.yaml"``, ``"segmentation/yolo_seg.yaml"``)."""
    path = CONFIG_DIR / name
    if not path.is_file():
        raise ConfigError(f"default configuration {name!r} not found in {CONFIG_DIR}: reinstall the package "
                          f"or set {CONFIG_DIR_ENV} to a folder holding it")
    return path


#: Field-metadata key under which `setting` stores a field's `Rule`.
RULE_KEY = "scene_recon.rule"


def _fmt(x: Any) -> str:
    return f"{x:g}" if isinstance(x, float) else repr(x) if isinstance(x, str) else str(x)


@dataclasses.dataclass(frozen=True)
class Rule:
    """Accepted values of one setting; applied to each element when the value is a list or a mapping."""

    min: float | None = None
    max: float | None = None
    min_exclusive: bool = False
    max_exclusive: bool = False
    choices: tuple[Any, ...] | None = None
    doc: str = ""

    def describe(self) -> str:
        """The accepted values in words ("in [0, 1]", ">= 1", "one of ['full', 'baseline']"); "" when any."""
        if self.choices is not None:
            return f"one of {list(self.choices)}"
        if self.min is not None and self.max is not None:
            return (f"in {'(' if self.min_exclusive else '['}{_fmt(self.min)}, "
                    f"{_fmt(self.max)}{')' if self.max_exclusive else ']'}")
        if self.min is not None:
            return f"{'>' if self.min_exclusive else '>='} {_fmt(self.min)}"
        if self.max is not None:
            return f"{'<' if self.max_exclusive else '<='} {_fmt(self.max)}"
        return ""

    def check(self, value: Any, where: str) -> None:
        """Raise `ConfigError` naming `where` and the accepted values when `value` is outside them."""
        if isinstance(value, (list, tuple)):
            for i, item in enumerate(value):
                self.check(item, f"{where}[{i}]")
            return
        if isinstance(value, dict):
            for key, item in value.items():
                self.check(item, f"{where}.{key}")
            return
        if self.choices is not None:
            if value not in self.choices:
                raise ConfigError(f"{where}: got {value!r}; valid values: {list(self.choices)}")
            return
        if self.min is None and self.max is None:
            return
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number {self.describe()}, got {value!r}")
        too_low = self.min is not None and (value <= self.min if self.min_exclusive else value < self.min)
        too_high = self.max is not None and (value >= self.max if self.max_exclusive else value > self.max)
        if too_low or too_high:
            raise ConfigError(f"{where}: got {_fmt(value)}; allowed: {self.describe()}")


def setting(default: Any = dataclasses.MISSING, *, default_factory: Any = dataclasses.MISSING,
            min: float | None = None, max: float | None = None,
            min_exclusive: bool = False, max_exclusive: bool = False,
            choices: Sequence[Any] | None = None, doc: str = "") -> Any:
    """A dataclass field whose accepted values travel with it (see `Rule`).

    A mutable default (list, dict) is copied per instance, so `setting([1, 2], min=1)` is safe. `doc`
    is a one-line description (shown as the ROS parameter's description).
    """
    if isinstance(default, (list, dict)):
        default_factory, default = (lambda d=default: copy.deepcopy(d)), dataclasses.MISSING
    rule = Rule(min, max, min_exclusive, max_exclusive, tuple(choices) if choices is not None else None, doc)
    return dataclasses.field(default=default, default_factory=default_factory, metadata={RULE_KEY: rule})


def field_rule(f: dataclasses.Field) -> Rule | None:
    """The `Rule` of a dataclass field, or None for a field declared without `setting`."""
    return f.metadata.get(RULE_KEY)


class Settings:
    """Base of config dataclasses: construction checks every field's `Rule`.

    Objects built in code (`OracleNoiseConfig(miss_prob=1.5)`, presets) are checked the same way as
    loaded ones. A subclass with a cross-field condition overrides `__post_init__` and calls
    `super().__post_init__()` first.
    """

    def __post_init__(self) -> None:
        name = type(self).__name__
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            rule = field_rule(f)
            if rule is not None:
                rule.check(getattr(self, f.name), f"{name}.{f.name}")


def _convert(value: Any, annotation: Any, where: str) -> Any:
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if isinstance(annotation, type) and dataclasses.is_dataclass(annotation):
        if isinstance(value, annotation):
            return value
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping, got {type(value).__name__}")
        return from_dict(annotation, value, where)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _convert(value, arg, where)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(f"{where}: {value!r} matches none of {args}: {'; '.join(errors)}")
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        item_type = args[0] if args else Any
        items = [_convert(v, item_type, f"{where}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping, got {value!r}")
        return {k: _convert(v, args[1] if args else Any, f"{where}.{k}") for k, v in value.items()}
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if annotation is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true/false, got {value!r}")
        return value
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    return value


def from_dict(cls: type[T], data: dict[str, Any], where: str = "") -> T:
    """Build dataclass `cls` from a mapping, converting nested mappings and checking types and rules.

    Every given value is checked against its field's type and `Rule` before the object is built, so
    an error names the dotted key (`oracle.levels.hard.miss_prob`), not only the class.
    """
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(
            f"{where or cls.__name__}: unknown key(s) {unknown}; valid keys are {sorted(fields)}"
        )
    kwargs = {}
    for key, value in data.items():
        name = f"{where + '.' if where else ''}{key}"
        kwargs[key] = _convert(value, hints[key], name)
        rule = field_rule(fields[key])
        if rule is not None:
            rule.check(kwargs[key], name)
    try:
        return cls(**kwargs)
    except ConfigError as exc:  # a cross-field condition of `__post_init__`: say where the object sits
        if not where:
            raise
        raise ConfigError(f"{where}: {exc}") from None


def validate(obj: Any, where: str = "") -> None:
    """Check a whole config tree: every field's type and `Rule`, nested dataclasses, mappings and lists
    of them, and each class's cross-field `__post_init__` conditions. Raises `ConfigError` naming the
    dotted key. Catches what construction cannot: values assigned after the object was built."""
    hints = typing.get_type_hints(type(obj))
    for f in dataclasses.fields(obj):
        name = f"{where + '.' if where else ''}{f.name}"
        value = getattr(obj, f.name)
        _convert(value, hints[f.name], name)  # type check only; the converted copy is not kept
        rule = field_rule(f)
        if rule is not None:
            rule.check(value, name)
        if isinstance(value, dict):
            children = [(f"{name}.{k}", v) for k, v in value.items()]
        elif isinstance(value, (list, tuple)):
            children = [(f"{name}[{i}]", v) for i, v in enumerate(value)]
        else:
            children = [(name, value)]
        for child_name, child in children:
            if dataclasses.is_dataclass(child) and not isinstance(child, type):
                validate(child, child_name)
    post_init = getattr(obj, "__post_init__", None)
    if post_init is not None:
        try:
            post_init()
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}" if where else str(exc)) from None


@dataclasses.dataclass(frozen=True)
class SettingInfo:
    """One leaf of a config tree: its dotted key, declared type, current value and rule."""

    key: str
    annotation: Any
    value: Any
    rule: Rule | None


def iter_settings(obj: Any, prefix: str = "") -> Iterator[SettingInfo]:
    """The leaves of a config tree in declaration order, with the dotted keys `flatten` would give.

    Nested dataclasses and mappings of dataclasses (the oracle's noise `levels`) are walked into,
    so the keys are exactly those of the YAML file; everything else is a leaf.
    """
    hints = typing.get_type_hints(type(obj))
    for f in dataclasses.fields(obj):
        key, value = f"{prefix}{f.name}", getattr(obj, f.name)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            yield from iter_settings(value, key + ".")
        elif isinstance(value, dict) and value and all(dataclasses.is_dataclass(v) for v in value.values()):
            for name, child in value.items():
                yield from iter_settings(child, f"{key}.{name}.")
        else:
            yield SettingInfo(key, hints[f.name], value, field_rule(f))


def to_dict(obj: Any) -> dict[str, Any]:
    """Plain-data (YAML/JSON-ready) view of a config dataclass."""
    return dataclasses.asdict(obj)


def load_config(cls: type[T], path: str | Path | None = None, overrides: dict[str, Any] | None = None) -> T:
    """Read `cls` from a YAML file (missing keys keep their defaults) and apply dotted overrides."""
    data: dict[str, Any] = {}
    if path is not None:
        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"config file {path} does not exist")
        with path.open("r", encoding="utf-8") as fh:
            loaded = yaml.safe_load(fh) or {}
        if not isinstance(loaded, dict):
            raise ConfigError(f"{path}: top level must be a mapping of keys to values")
        data = loaded
    return build_config(cls, data, overrides)


def build_config(cls: type[T], data: dict[str, Any], overrides: dict[str, Any] | None = None) -> T:
    """`cls` from nested plain data plus dotted overrides, converted and checked (`from_dict`, then
    `validate` on the whole tree): the one path by which files, CLI options and ROS parameters enter."""
    if overrides:
        data = _merge(data, unflatten(overrides))
    obj = from_dict(cls, data)
    validate(obj)
    return obj


def dump_config(obj: Any, path: str | Path) -> None:
    """Write a config dataclass as YAML (e.g. next to results, for reproducibility)."""
    Path(path).write_text(yaml.safe_dump(to_dict(obj), sort_keys=False), encoding="utf-8")


def flatten(data: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """{'a': {'b': 1}} -> {'a.b': 1}; used for ROS 2 parameter names."""
    out: dict[str, Any] = {}
    for key, value in data.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, name + "."))
        else:
            out[name] = value
    return out


def unflatten(data: dict[str, Any]) -> dict[str, Any]:
    """{'a.b': 1} -> {'a': {'b': 1}}."""
    out: dict[str, Any] = {}
    for key, value in data.items():
        node = out
        parts = key.split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = value
    return out


def _merge(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    merged = dict(base)
    for key, value in extra.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _merge(merged[key], value)
        else:
            merged[key] = value
    return merged


# ---------------------------------------------------------------------------- presets
#: Folder (under the config folder) holding the named presets, one YAML file each.
PRESETS_DIR = "presets"
#: Sections of a preset file and the stage config each one overrides (through that stage's schema:
#: `load_config(..., overrides)`, so an unknown or out-of-range key is refused with its dotted name).
PRESET_SECTIONS = {
    "mapper": "config/mapper.yaml (panoptic_mapping.config.MapperConfig)",
    "data": "config/data.yaml (panoptic_mapping.dataio.DataInputConfig)",
    "scene_graph": "config/scene_graph.yaml (scene_graph.config.SceneGraphConfig)",
    "cad": "cad_replacement.replace_config.CadReplacementConfig",
}


@dataclasses.dataclass(frozen=True)
class Preset:
    """A named speed/accuracy trade-off: dotted-key overrides of each stage's existing config schema.

    Not a second parameter system: every value lands in the same dataclasses, through the same
    `load_config`/`build_config` path as the YAML files and the CLI options (which win over it).
    """

    name: str
    description: str
    mapper: dict[str, Any]
    data: dict[str, Any]
    scene_graph: dict[str, Any]
    cad: dict[str, Any]

    def section(self, name: str) -> dict[str, Any]:
        return dict(getattr(self, name))


def preset_names() -> list[str]:
    """Names of the presets in ``config/presets/`` (sorted)."""
    folder = CONFIG_DIR / PRESETS_DIR
    return sorted(p.stem for p in folder.glob("*.yaml")) if folder.is_dir() else []


def load_preset(name_or_path: str | Path | None) -> Preset | None:
    """The preset named ``name_or_path`` (``config/presets/NAME.yaml``) or read from a YAML path; None for None."""
    if name_or_path is None or name_or_path == "":
        return None
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml"):
        path = CONFIG_DIR / PRESETS_DIR / f"{name_or_path}.yaml"
    if not path.is_file():
        raise ConfigError(f"unknown preset {str(name_or_path)!r}: known presets are {preset_names()} "
                          f"(files in {CONFIG_DIR / PRESETS_DIR}) or give a YAML file")
    with path.open("r", encoding="utf-8") as fh:
        data = yaml.safe_load(fh) or {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: top level must be a mapping")
    unknown = sorted(set(data) - set(PRESET_SECTIONS) - {"description"})
    if unknown:
        raise ConfigError(f"{path}: unknown section(s) {unknown}; valid sections are "
                          f"{sorted(PRESET_SECTIONS)} (and description)")
    sections: dict[str, dict[str, Any]] = {}
    for key in PRESET_SECTIONS:
        value = data.get(key) or {}
        if not isinstance(value, dict):
            raise ConfigError(f"{path}: section {key!r} must be a mapping of config keys to values")
        sections[key] = flatten(value)  # nested or dotted keys alike
    return Preset(name=path.stem, description=str(data.get("description", "")), **sections)


def preset_overrides(preset: Preset | None, section: str, explicit: dict[str, Any] | None = None) -> dict[str, Any]:
    """Overrides for one stage: the preset's section, then the explicit (CLI) ones on top."""
    out = preset.section(section) if preset is not None else {}
    out.update(explicit or {})
    return out
