"""Surface planes Pi_i of a node (paper Sec. 2.1/2.2) and the regions that can carry other nodes.

Two detectors, merged:
* iterative RANSAC (the paper's: 3 cm, 200 iterations, keep extracting while a plane holds more
  than 10 % of the cloud) - reused from ``cad_replacement.cad.features.extract_planes``, which
  returns outward normals;
* height groups of upward faces: RANSAC's 10 % rule stops before small horizontal surfaces
  (a shelf level, a drawer bottom, a cabinet top hold a few percent of a piece of furniture's
  area), yet those are exactly the supporting planes Eq. (1) looks for. Upward faces are grouped
  around the modes of their area-weighted height histogram.

Every supporting plane (Eq. (1): n . g <= a_th) keeps its *region*: the mesh triangles lying on
it (or the points, for point input), projected to the floor plane, which Eq. (2) measures.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from recon_core.entity import Entity
from recon_core.geometry.gravity import UP
from recon_core.geometry.plane import Plane, SurfacePlane
from recon_core.geometry.plane_fit import extract_planes
from recon_core.geometry.polygon import EPS
from scene_graph.config import PlaneConfig


def _face_data(entity: Entity) -> tuple[NDArray, NDArray, NDArray]:
    """Triangles (F, 3, 3), unit normals (F, 3) and areas (F,) of the entity's faces."""
    tri = entity.vertices[entity.faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    normals = cross / np.maximum(norm, EPS)[:, None]
    return tri, normals, 0.5 * norm


def height_group_planes(entity: Entity, cfg: PlaneConfig, up_cos: float,
                        faces: tuple[NDArray, NDArray, NDArray] | None = None) -> list[Plane]:
    """Horizontal upward planes at the modes of the area-weighted height of upward faces."""
    if not entity.has_faces:
        return []
    tri, normals, areas = faces if faces is not None else _face_data(entity)
    up = (normals[:, 2] >= up_cos) & (areas > 0.0)
    if not np.any(up):
        return []
    z = tri[up, :, 2].mean(axis=1)
    w = areas[up]
    tol = max(cfg.height_tolerance, EPS)
    planes: list[Plane] = []
    remaining = np.ones(len(z), dtype=bool)
    while remaining.any() and len(planes) < cfg.max_height_groups:
        zr, wr = z[remaining], w[remaining]
        if wr.sum() < cfg.min_support_area:
            break
        # Mode of the area-weighted histogram (bins of the tolerance), refined by its weighted mean.
        lo = zr.min()
        bins = np.floor((zr - lo) / tol).astype(np.int64)
        mass = np.bincount(bins, weights=wr)
        best = int(np.argmax(mass))
        near = np.abs(bins - best) <= 1
        mode = float(np.average(zr[near], weights=wr[near]))
        member = np.abs(zr - mode) <= tol
        group_area = float(wr[member].sum())
        idx = np.flatnonzero(remaining)[member]
        remaining[idx] = False
        if group_area < cfg.min_support_area:  # the heaviest group is too small: so is every later one
            break
        height = float(np.average(zr[member], weights=wr[member]))
        planes.append(Plane(normal=UP, d=-height, area=group_area))
    return planes


def _support_region(entity: Entity, plane: Plane, cfg: PlaneConfig,
                    faces: tuple[NDArray, NDArray, NDArray] | None) -> tuple[NDArray, NDArray]:
    """The entity's triangles (or points) on ``plane``, projected to x-y."""
    if faces is not None:
        tri, normals, areas = faces
        dist = np.abs(tri @ plane.normal + plane.d)  # (F, 3)
        on = np.all(dist <= cfg.region_distance, axis=1) & (normals @ plane.normal >= cfg.region_normal_cos)
        on &= areas > 0.0
        return tri[on][:, :, :2].copy(), np.zeros((0, 2))
    dist = np.abs(entity.vertices @ plane.normal + plane.d)
    return np.zeros((0, 3, 2)), entity.vertices[dist <= cfg.region_distance, :2].copy()


def detect_planes(entity: Entity, cfg: PlaneConfig, a_th: float = -0.9,
                  box_diagonal: float | None = None) -> list[SurfacePlane]:
    """Surface planes of an entity: height-group support planes first, then RANSAC planes.

    RANSAC planes that duplicate a height-group plane (same normal, offset within the RANSAC
    distance) are dropped. Supporting planes (Eq. (1)) get their regions.
    """
    if len(entity.vertices) < 3:
        return []
    up_cos = -a_th
    diag = box_diagonal if box_diagonal is not None else float(np.linalg.norm(np.ptp(entity.vertices, axis=0)))
    thr = min(cfg.ransac_distance, cfg.ransac_relative_distance * diag) if diag > 0 else cfg.ransac_distance
    thr = max(thr, 1e-4)
    geometry: Any = entity.mesh() if entity.has_faces else entity.vertices
    try:
        ransac = extract_planes(geometry, distance_threshold=thr, iterations=cfg.ransac_iterations,
                                min_inlier_fraction=cfg.ransac_min_fraction, max_planes=cfg.max_planes,
                                sample_count=cfg.ransac_samples, seed=cfg.seed)
    except (ValueError, IndexError):  # degenerate meshes (zero area) cannot be sampled
        ransac = []
    faces = _face_data(entity) if entity.has_faces else None
    groups = height_group_planes(entity, cfg, up_cos, faces) if cfg.height_groups else []
    kept = [SurfacePlane(p, "height_group") for p in groups]
    for p in ransac:
        dup = any(float(p.normal @ q.plane.normal) > up_cos and abs(p.d - q.plane.d) < thr for q in kept)
        if not dup:
            kept.append(SurfacePlane(p, "ransac"))
    for sp in kept:
        if sp.is_support(a_th):
            sp.region_triangles, sp.region_points = _support_region(entity, sp.plane, cfg, faces)
    return kept
