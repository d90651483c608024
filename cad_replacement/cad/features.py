"""Mesh-based feature extraction, shared by CAD import and the reconstruction side.

* ``extract_planes``: iterative RANSAC plane detection with outward normals (paper Sec. 2.2 /
  4.1: 3 cm threshold, 200 iterations, keep extracting while a plane takes > 10 % of the cloud).
  Works on a mesh (area-uniform samples carry their face normals) or on a raw point cloud.
* ``gravity_aligned_box``: the minimal-area box around points whose vertical axis is gravity.
* ``find_support_surfaces``: upward horizontal regions of a mesh with outline and free clearance.
* ``mesh_features``/``model_mesh_features``: the three above bundled into ``ModelFeatures``.

Procedural models get their features analytically (``assembly.py``); imported models and
reconstructed object meshes use these functions.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import ConvexHull, QhullError

from .feature_types import SUPPORT_NORMAL_COS, ModelFeatures, Plane, SupportSurface, merge_planes
from .model import CadModel
from .transforms import EPS_NORM

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

#: Support surfaces: smallest area (m^2), height tolerance when grouping faces (m).
SUPPORT_MIN_AREA = 0.01
SUPPORT_HEIGHT_TOL = 0.01
#: Rays per support surface for clearance/enclosure tests.
SUPPORT_RAYS = 32
#: Fraction of rays that must be blocked in every direction for a surface to count as enclosed.
ENCLOSED_FRACTION = 0.8


@dataclass(frozen=True, eq=False)
class OrientedBox:
    """Gravity-aligned box: ``center``, ``size`` (along its own x, y, z) and ``yaw`` about +z."""

    center: NDArray[np.float64]
    size: NDArray[np.float64]
    yaw: float

    def rotation(self) -> NDArray[np.float64]:
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


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
        inl = np.abs(p @ cand.T + offs) < distance_threshold
        if nrm is not None:
            inl &= np.abs(nrm[remaining] @ cand.T) > normal_cos
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


def gravity_aligned_box(points: ArrayLike) -> OrientedBox:
    """Minimal-footprint box with a vertical axis (rotating calipers over the 2D convex hull).

    The box's yaw is the hull edge direction that minimises the footprint area; the vertical
    extent is the points' z range. Degenerate footprints fall back to the axis-aligned box.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0:
        raise ValueError("gravity_aligned_box needs at least one point")
    zlo, zhi = p[:, 2].min(), p[:, 2].max()
    xy = p[:, :2]
    yaw = 0.0
    try:
        hull = xy[ConvexHull(xy).vertices]
        edges = np.roll(hull, -1, axis=0) - hull
        angles = np.arctan2(edges[:, 1], edges[:, 0])
        c, s = np.cos(angles), np.sin(angles)
        # Hull in each candidate frame: rows (E, H) of u = R(-a) p.
        u = hull[None, :, 0] * c[:, None] + hull[None, :, 1] * s[:, None]
        v = -hull[None, :, 0] * s[:, None] + hull[None, :, 1] * c[:, None]
        areas = np.ptp(u, axis=1) * np.ptp(v, axis=1)
        yaw = float(angles[int(np.argmin(areas))])
    except (QhullError, ValueError):
        pass
    # Canonical yaw in [-pi/4, pi/4]: a quarter turn only swaps the box's x and y sizes.
    quarter = int(np.round(yaw / (0.5 * np.pi)))
    yaw -= quarter * 0.5 * np.pi
    c, s = np.cos(yaw), np.sin(yaw)
    u = xy[:, 0] * c + xy[:, 1] * s
    v = -xy[:, 0] * s + xy[:, 1] * c
    uc, vc = 0.5 * (u.min() + u.max()), 0.5 * (v.min() + v.max())
    center = np.array([uc * c - vc * s, uc * s + vc * c, 0.5 * (zlo + zhi)])
    size = np.array([np.ptp(u), np.ptp(v), zhi - zlo])
    return OrientedBox(center=center, size=size, yaw=yaw)


def _face_components(mesh: trimesh.Trimesh, faces: NDArray[np.int64]) -> list[NDArray[np.int64]]:
    """Groups of ``faces`` connected through shared vertices."""
    if len(faces) == 1:
        return [faces]
    tri = mesh.faces[faces]
    # Faces sharing a vertex: chain consecutive faces listed under each vertex.
    vert = tri.reshape(-1)
    owner = np.repeat(np.arange(len(faces)), 3)
    order = np.argsort(vert, kind="stable")
    same = vert[order][1:] == vert[order][:-1]
    edges = np.stack([owner[order][:-1][same], owner[order][1:][same]], axis=1)
    labels = trimesh.graph.connected_component_labels(edges, node_count=len(faces))
    return [faces[labels == k] for k in np.unique(labels)]


def _first_hit_distance(
    mesh: trimesh.Trimesh, origins: NDArray[np.float64], direction: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Distance to the first hit along ``direction`` from each origin (inf where nothing is hit)."""
    dirs = np.broadcast_to(direction, origins.shape)
    dist = np.full(len(origins), np.inf)
    locations, ray_idx, _ = mesh.ray.intersects_location(origins, dirs, multiple_hits=False)
    if len(ray_idx):
        dist[ray_idx] = np.einsum("ij,ij->i", locations - origins[ray_idx], dirs[ray_idx])
    return dist


def find_support_surfaces(
    mesh: trimesh.Trimesh,
    *,
    face_links: Sequence[str] | NDArray[np.str_] | None = None,
    min_area: float = SUPPORT_MIN_AREA,
    normal_cos: float = SUPPORT_NORMAL_COS,
    height_tol: float = SUPPORT_HEIGHT_TOL,
    rays: int = SUPPORT_RAYS,
    seed: int = 0,
) -> list[SupportSurface]:
    """Upward, horizontal regions of ``mesh`` (z up) large enough to put things on.

    Faces with ``normal.z > normal_cos`` are grouped by height (gaps > ``height_tol`` split) and
    by vertex connectivity; each group of at least ``min_area`` becomes a surface whose outline
    is the convex hull of its vertices. Rays cast from sample points give the free ``clearance``
    (10th percentile of upward hit distances; ``None`` when most rays escape) and ``enclosed``
    (blocked upwards and in all four horizontal directions). ``face_links`` names the link of
    every face so a surface knows which link carries it.
    """
    if len(mesh.faces) == 0:
        return []
    up = np.flatnonzero(mesh.face_normals[:, 2] > normal_cos)
    if len(up) == 0:
        return []
    rng = np.random.default_rng(seed)
    heights = mesh.triangles_center[up, 2]
    order = np.argsort(heights)
    split = np.flatnonzero(np.diff(heights[order]) > height_tol) + 1
    surfaces: list[SupportSurface] = []
    for group in np.split(up[order], split):
        if mesh.area_faces[group].sum() < min_area:
            continue
        for comp in _face_components(mesh, group):
            areas = mesh.area_faces[comp]
            total = float(areas.sum())
            if total < min_area:
                continue
            z = float(np.average(mesh.triangles_center[comp, 2], weights=areas))
            xy = mesh.vertices[mesh.faces[comp]].reshape(-1, 3)[:, :2]
            try:
                poly = xy[ConvexHull(xy).vertices]
            except (QhullError, ValueError):
                continue
            pick = rng.choice(comp, size=rays, p=areas / total)
            bary = rng.dirichlet(np.ones(3), size=rays)
            samples = np.einsum("ij,ijk->ik", bary, mesh.triangles[pick])
            eps = max(1e-4, 0.5 * height_tol)
            origins = samples + np.array([0.0, 0.0, eps])
            up_dist = _first_hit_distance(mesh, origins, np.array([0.0, 0.0, 1.0]))
            hit = np.isfinite(up_dist)
            clearance = float(np.percentile(up_dist[hit] + eps, 10)) if hit.mean() >= 0.5 else None
            probe_h = eps + 0.5 * min(clearance if clearance is not None else 0.1, 0.1)
            probe = samples + np.array([0.0, 0.0, probe_h])
            blocked = hit.copy()
            for direction in ((1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, -1.0, 0.0)):
                blocked &= np.isfinite(_first_hit_distance(mesh, probe, np.array(direction)))
            link = "body"
            if face_links is not None:
                names, counts = np.unique(np.asarray(face_links)[comp], return_counts=True)
                link = str(names[int(np.argmax(counts))])
            surfaces.append(
                SupportSurface(
                    height=z,
                    polygon=poly,
                    clearance=clearance,
                    link=link,
                    enclosed=bool(blocked.mean() >= ENCLOSED_FRACTION),
                )
            )
    return surfaces


def mesh_features(
    mesh: trimesh.Trimesh,
    *,
    face_links: Sequence[str] | NDArray[np.str_] | None = None,
    seed: int = 0,
    distance_threshold: float | None = None,
) -> ModelFeatures:
    """Box + RANSAC planes + support surfaces of a mesh given in a gravity-aligned canonical frame.

    The RANSAC threshold defaults to the paper's 3 cm, shrunk to 2 % of the box diagonal for small
    objects (a cup would otherwise be a single plane).
    """
    if len(mesh.faces) == 0:
        raise ValueError("cannot compute features of an empty mesh")
    lo, hi = mesh.bounds
    size = hi - lo
    thr = (
        distance_threshold
        if distance_threshold is not None
        else min(PLANE_DISTANCE, 0.02 * float(np.linalg.norm(size)))
    )
    planes = extract_planes(mesh, distance_threshold=thr, seed=seed)
    supports = find_support_surfaces(mesh, face_links=face_links, seed=seed)
    planes = merge_planes(planes + [s.plane for s in supports if not s.enclosed], offset_tol=thr)
    return ModelFeatures(
        box_center=0.5 * (lo + hi),
        box_size=size,
        planes=tuple(planes),
        support_surfaces=tuple(supports),
    )


def model_mesh_features(model: CadModel, *, seed: int = 0) -> ModelFeatures:
    """``mesh_features`` of a model at its closed configuration, attributing surfaces to links."""
    posed = model.posed_link_meshes()
    meshes = [(name, m) for name, m in posed.items() if len(m.faces)]
    if not meshes:
        raise ValueError(f"model {model.model_id!r} has no geometry")
    whole = trimesh.util.concatenate([m for _, m in meshes])
    face_links = np.concatenate([np.full(len(m.faces), name, dtype=object) for name, m in meshes])
    return mesh_features(whole, face_links=face_links, seed=seed)
