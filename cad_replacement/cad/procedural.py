"""Registry of procedural CAD classes and ``build_model`` (class name + seed -> ``CadModel``).

One class holds many distinct instances: the seed drives ``numpy.random.default_rng`` through the
class's parameter table (dimensions and styles), so ``build_model("table", 3)`` is always the same
table and ``build_model("table", 4)`` usually a different one. Explicit ``overrides`` pin
individual parameters; ``target_size`` rescales the result to exact overall extents (fitting).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from cad_replacement.cad import builders_articulated, builders_furniture, builders_objects
from cad_replacement.cad.assembly import Assembly
from cad_replacement.cad.feature_types import ModelFeatures
from cad_replacement.cad.model import CadModel, ParamValue
from cad_replacement.cad.params import ParamSpec, sample_params
from recon_core.errors import UnknownClassError

#: Bump when any builder's geometry or parameter table changes: it invalidates cached features.
PROCEDURAL_VERSION = "1"


@dataclass(frozen=True)
class ClassBuilder:
    """How to make instances of one class: its parameter table and geometry function."""

    name: str
    params: ParamSpec
    build: Callable[[dict[str, ParamValue]], Assembly]
    articulated: bool
    #: Models differ in functional layout, not only in size: fronts (doors, drawers, their counts) or
    #: the number and spacing of support levels. A library needs more of them (``CadLibrary``).
    layout_varied: bool = False


def _registry() -> Mapping[str, ClassBuilder]:
    out: dict[str, ClassBuilder] = {}
    for module, articulated in (
        (builders_articulated, True),
        (builders_furniture, False),
        (builders_objects, False),
    ):
        for name, fn in module.BUILDERS.items():
            varied = articulated or name in builders_furniture.LEVELLED
            out[name] = ClassBuilder(name, module.SPECS[name], fn, articulated, varied)
    return MappingProxyType(dict(sorted(out.items())))


#: Supported procedural classes (read-only): name -> ClassBuilder.
CLASS_BUILDERS: Mapping[str, ClassBuilder] = _registry()


def class_builder(class_name: str) -> ClassBuilder:
    try:
        return CLASS_BUILDERS[class_name]
    except KeyError:
        raise UnknownClassError(
            f"no procedural CAD class {class_name!r}; supported: {sorted(CLASS_BUILDERS)}"
        ) from None


def _check_seed(seed: int) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def _target(target_size: ArrayLike) -> np.ndarray:
    t = np.asarray(target_size, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(t)) or np.any(t <= 0.0):
        raise ValueError(f"target_size must be three positive extents (x, y, z), got {t.tolist()}")
    return t


def procedural_definition(
    class_name: str,
    seed: int,
    overrides: Mapping[str, Any] | None = None,
    target_size: ArrayLike | None = None,
) -> dict[str, Any]:
    """Everything that determines a procedural model (hashed by the feature cache)."""
    return {
        "kind": "procedural",
        "version": PROCEDURAL_VERSION,
        "class": class_name,
        "seed": _check_seed(seed),
        "overrides": {k: v for k, v in sorted((overrides or {}).items())},
        "target_size": None if target_size is None else _target(target_size).tolist(),
    }


def definition_digest(definition: Mapping[str, Any]) -> str:
    """Stable SHA-256 of a JSON-serialisable definition."""
    blob = json.dumps(definition, sort_keys=True, separators=(",", ":"), default=str).encode()
    return hashlib.sha256(blob).hexdigest()


def procedural_model_id(
    class_name: str, seed: int, overrides: Mapping[str, Any] | None = None, target_size: ArrayLike | None = None
) -> str:
    """``<class>_s<seed>`` plus a short hash when overrides/target size make it a variant."""
    base = f"{class_name}_s{_check_seed(seed):04d}"
    if not overrides and target_size is None:
        return base
    return f"{base}_{definition_digest(procedural_definition(class_name, seed, overrides, target_size))[:8]}"


def _assembly(class_name: str, seed: int,
              overrides: Mapping[str, Any] | None) -> tuple[Assembly, dict[str, ParamValue]]:
    builder = class_builder(class_name)
    rng = np.random.default_rng(_check_seed(seed))
    params = sample_params(builder.params, rng, overrides)
    return builder.build(params), params


def procedural_features(class_name: str, seed: int, *, overrides: Mapping[str, Any] | None = None) -> ModelFeatures:
    """``build_model(class_name, seed, overrides=overrides).features``, without building the model's meshes
    (``Assembly.features``: the same numbers, a fraction of the time)."""
    return _assembly(class_name, seed, overrides)[0].features()


def build_model(
    class_name: str,
    seed: int,
    *,
    overrides: Mapping[str, Any] | None = None,
    target_size: ArrayLike | None = None,
) -> CadModel:
    """Build a deterministic instance of ``class_name`` from ``seed``.

    ``overrides`` pins parameters of the class table (``CLASS_BUILDERS[name].params``; unknown keys
    raise). Every class has ``depth`` (x), ``width`` (y) and ``height`` (z) in its final ``params``
    and the unscaled model's extents equal them. ``target_size`` = (x, y, z) rescales per axis
    afterwards so the extents match exactly; the scale factors are recorded in ``params``.
    """
    seed = _check_seed(seed)
    asm, params = _assembly(class_name, seed, overrides)
    model_id = procedural_model_id(class_name, seed, overrides, target_size)
    model = asm.build(model_id, params, source=f"procedural:{class_name}:seed={seed}")
    if target_size is None:
        return model
    target = _target(target_size)
    factors = target / model.size
    scaled = model.scaled(factors)
    new_params = dict(scaled.params)
    new_params.update(
        depth=float(target[0]),
        width=float(target[1]),
        height=float(target[2]),
        scale_x=float(factors[0]),
        scale_y=float(factors[1]),
        scale_z=float(factors[2]),
    )
    return CadModel(
        class_name=scaled.class_name,
        model_id=scaled.model_id,
        links=scaled.links,
        joints=scaled.joints,
        features=scaled.features,
        params=new_params,
        source=scaled.source,
    )
