"""Hand-made scenes for the contact-graph tests: entities built from axis-aligned boxes."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import pytest
import trimesh

from recon_core.entity import Entity
from scene_graph.config import SceneGraphConfig


def box_mesh(lo: Sequence[float], hi: Sequence[float], yaw: float = 0.0) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    m = trimesh.creation.box(extents=hi - lo)
    if yaw:
        m.apply_transform(trimesh.transformations.rotation_matrix(yaw, [0, 0, 1]))
    m.apply_translation((lo + hi) / 2)
    return m


def make_entity(eid: int, cls: str, parts: Sequence[tuple[Sequence[float], Sequence[float]]] | trimesh.Trimesh,
                name: str | None = None, **kw) -> Entity:
    mesh = parts if isinstance(parts, trimesh.Trimesh) else trimesh.util.concatenate([box_mesh(a, b) for a, b in parts])
    return Entity.from_mesh(eid, name or f"{cls}_{eid}", cls, mesh, **kw)


@pytest.fixture
def entity() -> Callable[..., Entity]:
    """entity(id, class, [(lo, hi), ...] or a mesh, name=None) -> Entity."""
    return make_entity


@pytest.fixture
def box() -> Callable[..., trimesh.Trimesh]:
    return box_mesh


@pytest.fixture
def cfg() -> SceneGraphConfig:
    return SceneGraphConfig()


@pytest.fixture
def room(entity) -> list[Entity]:
    """Floor, two walls, a table with a cup, a shelf with a book on its middle level."""
    shelf_parts = [([2.0, -1.0, 0.0], [2.02, -0.6, 1.2]), ([2.38, -1.0, 0.0], [2.4, -0.6, 1.2]),  # sides
                   ([2.0, -1.0, 0.0], [2.4, -0.98, 1.2])]  # back
    shelf_parts += [([2.02, -0.98, z - 0.02], [2.38, -0.6, z]) for z in (0.1, 0.5, 0.9, 1.2)]  # levels
    return [
        entity(1, "floor", [([-3, -3, -0.05], [3, 3, 0])]),
        entity(2, "wall", [([-3, 3, 0], [3, 3.1, 2.5])]),
        entity(3, "wall", [([3, -3, 0], [3.1, 3, 2.5])]),
        entity(4, "table", [([-0.5, -0.4, 0.72], [0.5, 0.4, 0.75])] +
               [([x, y, 0], [x + 0.05, y + 0.05, 0.72]) for x in (-0.5, 0.45) for y in (-0.4, 0.35)]),
        entity(5, "cup", [([0.1, 0.1, 0.75], [0.18, 0.18, 0.85])]),
        entity(6, "shelf", shelf_parts),
        entity(7, "book", [([2.1, -0.9, 0.5], [2.13, -0.7, 0.75])]),
    ]
