"""Iterative RANSAC plane detection with outward normals (paper Sec. 2.2 / 4.1).

Shared by the contact graph (planes of reconstructed meshes) and the CAD library (planes of CAD
models), so both sides of the plane-matching term (Eq. 9) come from the same detector: 3 cm
threshold, 200 iterations, keep extracting while a plane takes > 10 % of the cloud.
"""

from __future__ import annotations

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from recon_core.geometry.plane import Plane
from recon_core.geometry.transforms import EPS_NORM

#: Paper defaults (Sec. 4.1 / REFERENCE.md): inlier distance, RANSAC iterations, stop fraction.
PLANE_DISTANCE = 0.03
PLANE_ITERATIONS = 200
PLANE_MIN_FRACTION = 0.10
#: Surface samples drawn from a mesh for plane extraction.
PLANE_SAMPLES = 4000
#: |cos| between a sample's normal and a candidate plane normal for it to count as an inlier.
PLANE_NORMAL_COS = 0.8
#: Hard cap on the number of planes per object.
MAX_PLANES = 16
#: Preemptive RANSAC: hypotheses are ranked on this many random points, the best
#: ``PREEMPTIVE_KEEP`` are counted on all of them (0 disables the shortcut).
PREEMPTIVE_SUBSET = 300
PREEMPTIVE_KEEP = 8

def sample_mesh(mesh: trimesh.Trimesh, count: int, seed: int = 0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Area-uniform surface samples and their (outward) face normals."""
    if len(mesh.faces) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    points, face_idx = trimesh.sample.sample_surface(mesh, count, seed=seed)
    return np.asarray(points, dtype=np.float64), np.asarray(mesh.face_normals[face_idx], dtype=np.float64)


def _fit_plane(points: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
    """Least-squares plane through points (normal = smallest principal direction)."""
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    n = vt[-1]
    return n, float(-n @ centroid)


def extract_planes(
    geometry: trimesh.Trimesh | ArrayLike,
    *,
    normals: ArrayLike | None = None,
    distance_threshold: float = PLANE_DISTANCE,
    iterations: int = PLANE_ITERATIONS,
    min_inlier_fraction: float = PLANE_MIN_FRACTION,
    max_planes: int = MAX_PLANES,
    sample_count: int = PLANE_SAMPLES,
    normal_cos: float = PLANE_NORMAL_COS,
    seed: int = 0,
    score_subset: int = PREEMPTIVE_SUBSET,
) -> list[Plane]:
    """Detect planes by iterative RANSAC and return them with outward unit normals.

    ``geometry`` is a mesh (``sample_count`` surface samples with face normals are drawn) or an
    (N, 3) point cloud with optional per-point ``normals`` (randomly thinned to ``sample_count``).
    Each round draws ``iterations`` random point triples (vectorised), keeps the plane with most
    inliers (distance below ``distance_threshold`` and, with normals, normal agreement
    ``|cos| > normal_cos``), refits it by least squares and removes its inliers; it stops once
    the best plane holds fewer than ``min_inlier_fraction`` of the *original* cloud.

    Outward orientation: with normals, the plane normal follows the inliers' normals (and only
    inliers on that side are consumed, so the two faces of a thin board become two planes);
    without normals it points away from the cloud's centroid. ``Plane.area`` is the inlier share
    of the mesh area (mesh input) or the inlier fraction (point input).
    """
    rng = np.random.default_rng(seed)
    nrm: NDArray[np.float64] | None
    if isinstance(geometry, trimesh.Trimesh):
        pts, nrm = sample_mesh(geometry, sample_count, seed)
        total_area = float(geometry.area)
    else:
        pts = np.asarray(geometry, dtype=np.float64).reshape(-1, 3)
        nrm = None if normals is None else np.asarray(normals, dtype=np.float64).reshape(-1, 3)
        total_area = 1.0
        if nrm is not None:
            if len(nrm) != len(pts):
                raise ValueError("normals must have one row per point")
            lengths = np.linalg.norm(nrm, axis=1, keepdims=True)
            nrm = nrm / np.maximum(lengths, EPS_NORM)
        if len(pts) > sample_count:  # bound the (points x iterations) inlier matrix
            keep = rng.choice(len(pts), size=sample_count, replace=False)
            pts = pts[keep]
            nrm = None if nrm is None else nrm[keep]
    n_total = len(pts)
    if n_total < 3:
        return []
    min_inliers = max(3, int(np.ceil(min_inlier_fraction * n_total)))
    cloud_center = pts.mean(axis=0)
    remaining = np.arange(n_total)
    planes: list[Plane] = []
    while len(planes) < max_planes and len(remaining) >= min_inliers:
        p = pts[remaining]
        triples = rng.integers(0, len(p), size=(iterations, 3))
        a, b, c = p[triples[:, 0]], p[triples[:, 1]], p[triples[:, 2]]
        cand = np.cross(b - a, c - a)
        norm = np.linalg.norm(cand, axis=1)
        ok = norm > EPS_NORM
        if not np.any(ok):
            break
        cand = cand[ok] / norm[ok, None]
        offs = -np.einsum("ij,ij->i", cand, a[ok])
        # Preemptive scoring: every hypothesis is counted on a random subset of the points, the
        # few best on all of them (the (points x hypotheses) matrix was most of the cost; a plane
        # holding >= min_inlier_fraction of the cloud is ranked reliably by a few hundred points).
        sub = rng.choice(len(p), size=score_subset, replace=False) if 0 < 2 * score_subset < len(p) else None
        nrm_r = None if nrm is None else nrm[remaining]
        if sub is not None:
            inl_s = np.abs(p[sub] @ cand.T + offs) < distance_threshold
            if nrm_r is not None:
                inl_s &= np.abs(nrm_r[sub] @ cand.T) > normal_cos
            top = np.argsort(-inl_s.sum(axis=0), kind="stable")[:PREEMPTIVE_KEEP]
            cand, offs = cand[top], offs[top]
        inl = np.abs(p @ cand.T + offs) < distance_threshold
        if nrm_r is not None:
            inl &= np.abs(nrm_r @ cand.T) > normal_cos
        counts = inl.sum(axis=0)
        best = int(np.argmax(counts))
        if counts[best] < min_inliers:
            break
        n, d = _fit_plane(p[inl[:, best]])
        if n @ cand[best] < 0.0:
            n, d = -n, -d
        mask = np.abs(p @ n + d) < distance_threshold
        if nrm is not None:
            agree = nrm[remaining] @ n
            if agree[mask].sum() < 0.0:
                n, d, agree = -n, -d, -agree
            mask &= agree > normal_cos
        elif n @ (cloud_center - p[mask].mean(axis=0)) > 0.0:
            n, d = -n, -d
        count = int(mask.sum())
        if count < min_inliers:
            break
        planes.append(Plane(normal=n, d=d, area=total_area * count / n_total))
        remaining = remaining[~mask]
    return planes
