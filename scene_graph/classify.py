"""Node categories V^L / V^R / V^A (paper Sec. 2.1) from the semantic class table.

The class table (``config/classes.yaml``) is the one source of truth for categories and for
which classes a robot may move. A class it does not know becomes a rigid object (the safest
assumption: it has no joints to invent and is not part of the room's shell), with a warning.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from functools import lru_cache

from recon_core.classes import CATEGORIES, ClassInfo, ClassTable, load_class_table

log = logging.getLogger(__name__)

LAYOUT, RIGID, ARTICULATED = "layout", "rigid", "articulated"


@dataclass(frozen=True)
class NodeClass:
    """What the graph needs to know about a node's class."""

    class_name: str
    class_id: int
    category: str
    movable: bool
    known: bool


@lru_cache(maxsize=8)
def _table(path: str) -> ClassTable:
    return load_class_table(path or None)


_warned: set[str] = set()


def classify(class_name: str, category_hint: str = "", table_path: str = "") -> NodeClass:
    """Category of ``class_name``; unknown classes -> rigid (warned once per class name)."""
    table = _table(table_path)
    if class_name in table:
        info = table.by_name(class_name)
        return NodeClass(info.name, info.id, info.category, info.movable, True)
    if category_hint in CATEGORIES:
        return NodeClass(class_name, -1, category_hint, False, False)
    if class_name not in _warned:
        _warned.add(class_name)
        log.warning("class %r is not in the class table: treated as a rigid object", class_name)
    return NodeClass(class_name, -1, RIGID, False, False)


def class_info(class_name: str, table_path: str = "") -> ClassInfo | None:
    """The class table's entry of ``class_name`` (None for classes it does not know)."""
    table = _table(table_path)
    return table.by_name(class_name) if class_name in table else None
