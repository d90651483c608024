"""Small rigid-transform helpers shared by the CAD modules (4x4 homogeneous matrices, float64).

Kept separate so the kinematics, the importer and the exporter agree on one convention:
a pose ``T`` maps points from a child frame into its parent frame, ``p_parent = T @ p_child``.
"""

from __future__ import annotations

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

#: Norm below which a vector is treated as zero (guarded normalisation).
EPS_NORM = 1e-12
#: Tolerance for accepting a 3x3 matrix as a rotation.
ROTATION_TOL = 1e-6


def unit(vector: ArrayLike, what: str = "vector") -> NDArray[np.float64]:
    """Return ``vector`` normalised to unit length; raise instead of dividing by ~0."""
    v = np.asarray(vector, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(v))
    if not np.isfinite(n) or n < EPS_NORM:
        raise ValueError(f"{what} must be a finite non-zero 3-vector, got {v.tolist()}")
    return v / n


def translation(offset: ArrayLike) -> NDArray[np.float64]:
    """4x4 pure translation."""
    t = np.eye(4)
    t[:3, 3] = np.asarray(offset, dtype=np.float64).reshape(3)
    return t


def rotation_about(axis: ArrayLike, angle: float) -> NDArray[np.float64]:
    """4x4 rotation by ``angle`` (rad) about the unit ``axis`` through the origin (Rodrigues)."""
    a = unit(axis, "rotation axis")
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    r = np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)
    t = np.eye(4)
    t[:3, :3] = r
    return t


_EYE3 = np.eye(3)
_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])


def is_rigid(t: ArrayLike, tol: float = ROTATION_TOL) -> bool:
    """True when ``t`` is a finite 4x4 rigid transform (orthonormal rotation, det +1, last row 0001)."""
    m = np.asarray(t, dtype=np.float64)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        return False
    r = m[:3, :3]
    # plain max-abs tests: called for every collision shape and joint built, np.allclose is 10x slower
    return bool(
        float(np.abs(r.T @ r - _EYE3).max()) <= tol
        and abs(np.linalg.det(r) - 1.0) < tol
        and float(np.abs(m[3] - _LAST_ROW).max()) <= tol
    )


def invert_rigid(t: ArrayLike) -> NDArray[np.float64]:
    """Inverse of a rigid transform without a general matrix inverse."""
    m = np.asarray(t, dtype=np.float64)
    inv = np.eye(4)
    inv[:3, :3] = m[:3, :3].T
    inv[:3, 3] = -m[:3, :3].T @ m[:3, 3]
    return inv


def transform_points(t: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """Apply a 4x4 (affine) transform to an (N, 3) array of points."""
    m = np.asarray(t, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return p @ m[:3, :3].T + m[:3, 3]


def rotation_from_axes(up: ArrayLike, front: ArrayLike) -> NDArray[np.float64]:
    """3x3 rotation taking a source frame's ``up`` to +z and its ``front`` to +x.

    Used to bring imported CAD models (e.g. y-up meshes) into the canonical frame.
    """
    u = unit(up, "up axis")
    f = unit(front, "front axis")
    if abs(float(u @ f)) > 1e-6:
        raise ValueError(f"up {u.tolist()} and front {f.tolist()} axes must be perpendicular")
    return np.stack([f, np.cross(u, f), u])


def as_mesh(geometry: object) -> trimesh.Trimesh:
    """``geometry`` as a triangle mesh: trimesh's loaders and concatenation are typed as returning any
    geometry; a scene is flattened, anything else that is not a mesh is an error."""
    if isinstance(geometry, trimesh.Trimesh):
        return geometry
    if isinstance(geometry, trimesh.Scene):
        dumped = geometry.to_geometry()
        if isinstance(dumped, trimesh.Trimesh):
            return dumped
    raise TypeError(f"expected a triangle mesh, got {type(geometry).__name__}")
