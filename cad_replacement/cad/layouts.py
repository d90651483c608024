"""Front-layout variants of procedural articulated models: the same carcass with other doors and drawers.

A library of a few dozen models per class cannot hold every front an object may have: a cabinet
with five drawers, a fridge with its freezer on top, a wardrobe with two doors over a drawer. When
none of the library's models has the object's front, the best fit takes another layout's joints
and, with those parts open, stretches its carcass to cover the parts it cannot move (a five-drawer
chest with its drawers pulled out became a cabinet 1.56x too deep). Procedural models can do
better: the discrete parameters that decide the front (``builders_articulated.FRONT_LAYOUTS``) are
re-chosen while every other parameter of the model (its sizes, styles) stays, and the fit compares
those variants on the observation (``replace_object``). Imported models have no such parameters.

A variant is a ``CadEntry`` of the base model with ``overrides``; its key is the base key plus
``@name=value;name=value`` so ``replacement.json`` names it and ``CadLibrary.entry`` rebuilds it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from functools import lru_cache

import numpy as np

from cad_replacement.cad.builders_articulated import FRONT_LAYOUTS
from cad_replacement.cad.library import CadEntry
from cad_replacement.cad.params import ParamValue, sample_params
from cad_replacement.cad.procedural import CLASS_BUILDERS

#: Separates a variant's overrides from its base key (``cabinet_s0004@drawer_count=5;layout=drawers``).
VARIANT_SEP = "@"
_ITEM_SEP = ";"


def variant_key(base_key: str, overrides: Mapping[str, ParamValue]) -> str:
    """The key of ``base_key`` with ``overrides`` pinned (sorted, so one variant has one key)."""
    items = _ITEM_SEP.join(f"{k}={overrides[k]}" for k in sorted(overrides))
    return f"{base_key}{VARIANT_SEP}{items}"


def variant_entry(base: CadEntry, overrides: Mapping[str, ParamValue]) -> CadEntry:
    """``base`` (a procedural entry) with ``overrides`` checked against its class's parameter table.

    Raises ValueError for an imported model, an unknown parameter or a value out of its table."""
    if base.kind != "procedural" or base.seed is None:
        raise ValueError(f"{base.key}: only procedural models have layout variants")
    spec = CLASS_BUILDERS[base.class_name].params
    merged = dict(base.overrides)
    for name, value in overrides.items():
        if name not in spec:
            raise ValueError(f"{base.key}: no parameter {name!r} (valid: {list(spec)})")
        merged[name] = spec[name].check(name, value)
    pinned = tuple(sorted(merged.items()))
    root = base.key.split(VARIANT_SEP, 1)[0]
    return replace(base, key=variant_key(root, dict(pinned)), overrides=pinned)


#: ``resized_variants`` pins the fitted width to this step (m), so that one object's fits share a few models.
WIDTH_STEP = 0.01


def _front_parts(entry: CadEntry) -> tuple[str, ...]:
    """The moving joints' types of an entry's front (how many doors and drawers it has)."""
    assert entry.seed is not None
    return tuple(sorted(j[1] for j in front_signature(entry.class_name, entry.seed, entry.overrides)))


def resized_variants(entry: CadEntry, layouts: list[CadEntry], width: float) -> list[CadEntry]:
    """``entry`` and its ``layouts`` built at ``width`` (the width the fit stretched the model to), each only
    where that width gives its front other doors or drawers (the builders choose how many doors a front has
    and whether drawers stand in one column or two from the width: ``builders_articulated._door_count``).

    The alignment's transform scales the CAD model to the observed box (the paper's Eqs. 9-10; ours per
    axis), and scaling a model does not add a door: a one-door cabinet fitted 1.5x wide to a two-door one
    keeps one door, whose handle and hinge are where neither of the object's are (issue 23: gen-7373's
    two-door cabinet replaced by a 0.59 m one-door model, seed:47's three doors by a two-door one). Empty
    for a class without a ``width`` parameter or an imported model."""
    if entry.kind != "procedural" or entry.seed is None or "width" not in CLASS_BUILDERS[entry.class_name].params:
        return []
    pinned = round(float(width) / WIDTH_STEP) * WIDTH_STEP
    if not np.isfinite(pinned) or pinned <= 0.0:
        return []
    out: list[CadEntry] = []
    kinds: set[tuple[tuple[ParamValue, ...], tuple[str, ...]]] = set()
    for base in (entry, *layouts):
        variant = variant_entry(base, {"width": round(pinned, 3)})
        parts = _front_parts(variant)
        layout = tuple(v for k, v in sorted(variant.overrides) if k != "width")
        if parts != _front_parts(base) and (layout, parts) not in kinds:
            kinds.add((layout, parts))
            out.append(variant)
    return out


def parse_variant_key(key: str) -> tuple[str, dict[str, ParamValue]]:
    """``(base key, overrides)`` of a key made by ``variant_key`` (no overrides for a plain key).

    Values come back as strings or numbers by the shape of their text; ``variant_entry`` checks
    them against the class's table. Raises nothing: a malformed item is left out."""
    base, _, tail = key.partition(VARIANT_SEP)
    out: dict[str, ParamValue] = {}
    for item in filter(None, tail.split(_ITEM_SEP)):
        name, sep, text = item.partition("=")
        if not sep:
            continue
        out[name] = _number_or_text(text)
    return base, out


def _number_or_text(text: str) -> ParamValue:
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            continue
    return text


FrontSignature = tuple[tuple[str, str, tuple[float, ...], tuple[float, ...]], ...]


@lru_cache(maxsize=4096)
def front_signature(class_name: str, seed: int, overrides: tuple[tuple[str, ParamValue], ...]) -> FrontSignature:
    """What tells two fronts apart: every moving joint's name, type, anchor (mm) and axis.

    Read off the builder's assembly, before any geometry is made (a fraction of a build)."""
    builder = CLASS_BUILDERS[class_name]
    asm = builder.build(sample_params(builder.params, np.random.default_rng(seed), dict(overrides)))
    return tuple(sorted((j.name, str(j.type), tuple(np.round(j.anchor, 3)), tuple(np.round(j.axis, 3)))
                        for j in asm.joints if j.type != "fixed"))


def layout_variants(entry: CadEntry) -> list[CadEntry]:
    """The other front layouts of a procedural model (``FRONT_LAYOUTS`` of its class), in table order.

    A layout that builds the model's own front, or one listed before it (a hinge side of a
    two-door cabinet, a drawer count its height cannot hold), is left out."""
    layouts = FRONT_LAYOUTS.get(entry.class_name)
    if not layouts or entry.kind != "procedural" or entry.seed is None:
        return []
    seen = {front_signature(entry.class_name, entry.seed, entry.overrides)}
    out = []
    for layout in layouts:
        variant = variant_entry(entry, layout)
        sig = front_signature(variant.class_name, entry.seed, variant.overrides)
        if sig not in seen:
            seen.add(sig)
            out.append(variant)
    return out
