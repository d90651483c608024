"""Name sanitising for anything written into URDF/XML or used as a file name.

Imported files may carry arbitrary link/joint names ("door (left)", "../x", unicode); everything the
library writes is reduced to ``[A-Za-z0-9_]`` and made unique, so names are safe as XML attribute
values, file names and ROS frame ids.
"""

from __future__ import annotations

import re
from collections.abc import Iterable

_INVALID = re.compile(r"[^A-Za-z0-9_]")


def sanitize_name(name: str, fallback: str = "unnamed") -> str:
    """Replace every character outside ``[A-Za-z0-9_]`` by ``_``; empty names become ``fallback``."""
    cleaned = _INVALID.sub("_", str(name).strip())
    return cleaned if cleaned.strip("_") else fallback


def urdf_name(name: str, fallback: str = "unnamed") -> str:
    """A URDF/TF-safe name: ``sanitize_name`` and never starting with a digit (XML names cannot)."""
    safe = sanitize_name(name, fallback)
    return f"_{safe}" if safe[0].isdigit() else safe


def unique_names(names: Iterable[str], fallback: str = "unnamed") -> list[str]:
    """Sanitise each name and append ``_2``, ``_3``... to repeats (order preserved)."""
    out: list[str] = []
    seen: set[str] = set()
    for raw in names:
        base = sanitize_name(raw, fallback)  # idempotent on names that are already safe
        name, k = base, 2
        while name in seen:
            name, k = f"{base}_{k}", k + 1
        seen.add(name)
        out.append(name)
    return out
