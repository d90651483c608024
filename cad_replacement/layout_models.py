"""Box models for layout elements (floor, walls, ceiling) and for objects without a CAD model.

The room's shell has no CAD model in any library: it is replaced by boxes fitted to its contact-graph
nodes, so the interactive scene still has a floor to stand on and walls to collide with. A box model
is a one-link ``CadModel`` in the canonical frame (origin at the bottom centre) whose collision is
the box primitive itself, so simulators get an exact, cheap shape.
"""

from __future__ import annotations

import numpy as np
import trimesh
from numpy.typing import ArrayLike

from cad_replacement.cad.model import CadModel, Link, bounding_box_features
from recon_core.kinematic_tree import CollisionShape
from recon_core.names import sanitize_name

#: Smallest thickness (m) of a layout slab: a floor seen as a plane still needs a volume to collide with.
MIN_LAYOUT_THICKNESS = 0.05
#: Colour of layout boxes in viewers (RGBA).
LAYOUT_RGBA = (0.75, 0.75, 0.72, 1.0)


def box_model(class_name: str, size: ArrayLike, model_id: str = "",
              color: tuple[float, float, float, float] | None = LAYOUT_RGBA) -> CadModel:
    """A one-link box of ``size`` (x, y, z) standing on its bottom centre, with a box collision."""
    extents = np.asarray(size, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(extents)) or np.any(extents <= 0.0):
        raise ValueError(f"box model {class_name!r}: size must be positive and finite, got {extents.tolist()}")
    mesh = trimesh.creation.box(extents=extents)
    mesh.apply_translation([0.0, 0.0, 0.5 * extents[2]])
    centre = np.eye(4)
    centre[2, 3] = 0.5 * extents[2]
    link = Link("body", mesh, color, collisions=(CollisionShape("box", centre, extents),))
    return CadModel(class_name, model_id or sanitize_name(f"box_{class_name}"), (link,), (),
                    bounding_box_features(mesh), source="box")


__all__ = ["LAYOUT_RGBA", "MIN_LAYOUT_THICKNESS", "box_model"]
