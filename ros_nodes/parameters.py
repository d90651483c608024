"""ROS 2 parameters declared from the config dataclasses, so that a setting exists once.

A node's parameters are the dotted keys of its config tree (`tsdf.voxel_size_m`, `keyframes.enabled`,
`oracle.levels.hard.miss_prob`): the names come from the dataclass fields, the types from their
annotations, the defaults from the YAML file the node loads (its `config_file` parameter; empty: the
package's default file), the accepted ranges from the fields' `setting(...)` rules. Node-level settings
(topics, frames, timeouts) are small dataclasses declared the same way, without a file.

Values given on the command line or in a launch file go through the config's own converter and
validator (`recon_core.config.from_dict`): an int for a float field is accepted (`rate:=1`), a bool
is never a number, and an invalid value is logged as an error naming the parameter while the node
keeps the file's (or the default) value, instead of dying at start-up. After resolution every
parameter holds the value in effect, with the schema's type, so `ros2 param get` tells the truth.
The nodes read their parameters once, at start-up: changing one later is refused with that reason,
rather than silently accepted and ignored.
"""

from __future__ import annotations

import array
import difflib
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from recon_core.config import SettingInfo, build_config, iter_settings, load_config, to_dict
from recon_core.errors import ConfigError

T = TypeVar("T")

#: Name of the parameter that picks a node's YAML file (empty: the package's default file).
CONFIG_FILE_PARAMETER = "config_file"

_SCALAR_TYPES: dict[Any, Parameter.Type] = {
    bool: Parameter.Type.BOOL,
    int: Parameter.Type.INTEGER,
    float: Parameter.Type.DOUBLE,
    str: Parameter.Type.STRING,
}
_ARRAY_TYPES: dict[Any, Parameter.Type] = {
    bool: Parameter.Type.BOOL_ARRAY,
    int: Parameter.Type.INTEGER_ARRAY,
    float: Parameter.Type.DOUBLE_ARRAY,
    str: Parameter.Type.STRING_ARRAY,
}


def parameter_type(annotation: Any) -> Parameter.Type | None:
    """ROS parameter type of a config field's annotation; None when ROS has no such type (mappings).

    An optional field (`float | None`) has its value's type; None is a parameter that is not set."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        inner = [a for a in typing.get_args(annotation) if a is not type(None)]
        return parameter_type(inner[0]) if len(inner) == 1 else None
    if annotation in _SCALAR_TYPES:
        return _SCALAR_TYPES[annotation]
    if typing.get_origin(annotation) is typing.Literal:
        kinds = {type(a) for a in typing.get_args(annotation)}
        return _SCALAR_TYPES.get(kinds.pop()) if len(kinds) == 1 else None
    if typing.get_origin(annotation) in (list, tuple):
        args = typing.get_args(annotation)
        if args and args[0] in _ARRAY_TYPES:
            return _ARRAY_TYPES[args[0]]
    return None


def declare_config_file(node: Node, default: Path | None) -> Path | None:
    """Declare `config_file` and return the YAML file to load: the parameter, else `default`
    (None, or a default that does not exist: the dataclass defaults)."""
    value = node.declare_parameter(
        CONFIG_FILE_PARAMETER, "",
        ParameterDescriptor(description=f"YAML file of the node's settings (empty: {default})"),
    ).value
    if value:
        return Path(str(value))
    return default if default is not None and default.is_file() else None


def declare_config(node: Node, cls: type[T], yaml_path: str | Path | None = None, prefix: str = "") -> T:
    """Declare one ROS parameter per leaf of `cls` (named `prefix` + dotted key) and return the config
    in effect: the YAML file's values (or the defaults), with every valid parameter override applied.

    An unreadable or invalid file is logged and replaced by the dataclass defaults; an invalid override
    is logged (naming the parameter and what is accepted) and ignored. Fields ROS cannot hold (mappings
    of plain values) are left to the YAML file.
    """
    log = node.get_logger()
    source = str(yaml_path) if yaml_path is not None else "the defaults"
    try:
        base = load_config(cls, yaml_path)
    except ConfigError as exc:
        log.error(f"{exc}; using the built-in defaults of {cls.__name__}")
        base, source = cls(), "the defaults"

    declared: dict[str, tuple[SettingInfo, Parameter.Type]] = {}
    for info in iter_settings(base):
        name = prefix + info.key
        ptype = parameter_type(info.annotation)
        if ptype is None:
            log.warning(f"{name} ({info.annotation}) cannot be a ROS parameter; set it in the YAML file")
            continue
        rule = info.rule
        doc = rule.doc if rule is not None and rule.doc else info.key
        node.declare_parameter(name, _plain(info.value), ParameterDescriptor(
            description=f"{doc} [{ptype.name.lower()}; default from {source}]",
            additional_constraints=rule.describe() if rule is not None else "",
            dynamic_typing=True,  # any type may come in; the schema converts or rejects it below
        ))
        declared[name] = (info, ptype)

    data = to_dict(base)
    accepted: dict[str, Any] = {}
    config = base
    for name, (info, _) in declared.items():
        param = node.get_parameter(name)
        if param.type_ == Parameter.Type.NOT_SET:
            continue
        value = _plain(param.value)
        if repr(value) == repr(_plain(info.value)):
            continue
        try:  # on top of the overrides accepted so far: cross-field conditions see them all
            config = build_config(cls, data, {**accepted, info.key: value})
        except ConfigError as exc:
            reason = str(exc).removeprefix(f"{info.key}: ")  # the parameter's name says it already
            log.error(f"parameter '{name}': {reason}; keeping {_plain(info.value)!r} from {source}")
            continue
        accepted[info.key] = value

    # Publish the values in effect with the schema's types (an int given for a float becomes a double,
    # a rejected override goes back to the file's value, an empty list gets its element type).
    effective = {prefix + s.key: s.value for s in iter_settings(config)}
    updates = []
    for name, (_, ptype) in declared.items():
        value = _plain(effective[name])
        param = node.get_parameter(name)
        if value is None:  # an optional setting left unset: the parameter stays NOT_SET
            if param.type_ != Parameter.Type.NOT_SET:
                updates.append(Parameter(name, Parameter.Type.NOT_SET, None))
            continue
        if param.type_ != ptype or repr(_plain(param.value)) != repr(value):
            updates.append(Parameter(name, ptype, value))
    for param, result in zip(updates, node.set_parameters(updates), strict=True):
        if not result.successful:
            log.warning(f"parameter '{param.name}' does not show the value in effect: {result.reason}")

    names = frozenset(declared)

    def _read_at_startup(params: list[Parameter]) -> SetParametersResult:
        late = [p.name for p in params if p.name in names]
        if late:
            return SetParametersResult(successful=False, reason=(
                f"{', '.join(late)}: read once at start-up; restart the node with the new value"))
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(_read_at_startup)
    return config


#: Parameters rclpy or a launch system may set on any node; never reported as unknown.
_FRAMEWORK_PARAMETERS = ("use_sim_time", "start_type_description_service", "qos_overrides.")


def unknown_parameters(node: Node) -> dict[str, str]:
    """Parameters given to the node (`-p name:=value`, a launch file, a params file) that it does not
    declare, each with the nearest declared name ("" when none is close): rclpy ignores them silently."""
    declared = [n for n in node._parameters if not n.startswith(_FRAMEWORK_PARAMETERS)]
    leaves = {n: n.rsplit(".", 1)[-1] for n in declared}
    out: dict[str, str] = {}
    for name in node._parameter_overrides:  # rclpy keeps the overrides it was given here
        if name in node._parameters or name.startswith(_FRAMEWORK_PARAMETERS):
            continue
        leaf = name.rsplit(".", 1)[-1]

        def score(candidate: str, name: str = name, leaf: str = leaf) -> float:
            return max(difflib.SequenceMatcher(None, name, candidate).ratio(),
                       difflib.SequenceMatcher(None, leaf, leaves[candidate]).ratio())

        best = max(declared, key=score, default="")
        out[name] = best if best and score(best) >= 0.6 else ""
    return out


def warn_unknown_parameters(node: Node) -> dict[str, str]:
    """Warn about every parameter the node was given but does not have, naming the nearest valid one."""
    unknown = unknown_parameters(node)
    for name, near in sorted(unknown.items()):
        hint = f"; did you mean '{near}'?" if near else "; `ros2 param list` shows the valid names"
        node.get_logger().warning(f"unknown parameter '{name}' is ignored{hint}")
    return unknown


def _plain(value: Any) -> Any:
    """Parameter values as Python lists and scalars (rclpy may hand out arrays; configs hold tuples)."""
    if isinstance(value, (array.array, tuple, list)):
        return [_plain(v) for v in value]
    return value


__all__ = ["CONFIG_FILE_PARAMETER", "declare_config", "declare_config_file", "parameter_type",
           "unknown_parameters", "warn_unknown_parameters"]
