"""Layout entities of a panoptic map -> the paper's layout nodes (Sec. 2.1: floor, ceiling, walls).

A panoptic map holds *one* entity per stuff class (Sec. 3: stuff has no instances), so all walls
the camera saw arrive as a single "wall" entity, while the contact graph wants each wall that
bounds the scene as a node of its own (a picture hangs on *that* wall; the ground truth has four).
Mapped layout meshes are also partial and noisy (2 cm TSDF voxels): a floor entity carries stray
faces where a chair leg's foot fused with it, a wall entity the rounded corners between walls.

``split_layout(entity, ...)`` prepares a layout entity before its node is initialised:

* walls (``wall_classes``): the entity is split into its large vertical planar parts. Vertical
  faces (|n_z| < ``vertical_max_nz``) are clustered greedily: the dominant horizontal normal
  direction (area-weighted histogram of the normal azimuth modulo 180 deg), then the dominant
  offset along it; faces parallel to it (within ``parallel_deg``) and within ``thickness`` of
  that plane form one wall (both faces of a thick wall included). Each plane is cut where its
  faces leave a gap of more than ``max_gap`` along the wall (two coplanar walls, not a door or a
  wardrobe in front of one). Parts smaller than ``min_area`` or shorter than ``min_length`` are
  not walls. Every other face joins the nearest part within ``thickness`` (corner and edge
  faces) or is dropped (stray faces);
* floors and ceilings (``floor_classes`` / ``ceiling_classes``): faces farther than
  ``thickness`` from the dominant horizontal plane (area-weighted mode of the height of
  horizontal faces) are dropped.

An entity that yields one part with nothing dropped is returned unchanged (ground-truth walls:
one per entity, a 10 cm slab whose two faces fall within ``thickness`` of each other; the
ground-truth floor slab), so ground-truth input builds exactly as before. Parts get provisional
ids equal to the source id and names ``<class>_<k>`` (largest first); the builder renumbers them
to ids no entity uses (``ContactGraphBuilder.build``).
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from recon_core.entity import Entity
from recon_core.geometry.polygon import EPS
from scene_graph.config import LayoutConfig

log = logging.getLogger(__name__)

#: Bins of the normal-azimuth histogram (degrees) and its circular smoothing half-width (bins).
AZIMUTH_BIN_DEG = 2.0
SMOOTH_BINS = 2
#: Bin of the offset / height histograms (m).
OFFSET_BIN = 0.02
#: Faces with |n_z| at least this are horizontal (the a_th of Eq. (1)).
HORIZONTAL_NZ = 0.9


def _faces(entity: Entity) -> tuple[NDArray, NDArray, NDArray]:
    """Centroids (F, 3), unit normals (F, 3), areas (F,) of the entity's faces."""
    tri = entity.vertices[entity.faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    return tri.mean(axis=1), cross / np.maximum(norm, EPS)[:, None], 0.5 * norm


def _smoothed_peak(values: NDArray, weights: NDArray, bin_size: float, circular_bins: int = 0) -> float:
    """Centre of the heaviest bin of a smoothed weighted histogram, refined by the local weighted mean.

    ``circular_bins`` > 0: values are in [0, circular_bins * bin_size) and wrap around.
    """
    if circular_bins:
        bins = np.floor(values / bin_size).astype(np.int64) % circular_bins
        mass = np.bincount(bins, weights=weights, minlength=circular_bins)
        kernel = sum(np.roll(mass, k) for k in range(-SMOOTH_BINS, SMOOTH_BINS + 1))
        best = int(np.argmax(kernel))
        period = circular_bins * bin_size
        centre = (best + 0.5) * bin_size
        delta = (values - centre + 0.5 * period) % period - 0.5 * period
        near = np.abs(delta) <= (SMOOTH_BINS + 0.5) * bin_size
        return float((centre + np.average(delta[near], weights=weights[near])) % period)
    lo = float(values.min())
    bins = np.floor((values - lo) / bin_size).astype(np.int64)
    smooth = np.convolve(np.bincount(bins, weights=weights), np.ones(2 * SMOOTH_BINS + 1), mode="same")
    best = int(np.argmax(smooth))
    centre = lo + (best + 0.5) * bin_size
    near = np.abs(values - centre) <= (SMOOTH_BINS + 0.5) * bin_size
    return float(np.average(values[near], weights=weights[near]))


def sub_entity(entity: Entity, face_mask: NDArray, **kw) -> Entity:
    """The entity restricted to some faces (vertices re-indexed), other fields replaced by ``kw``."""
    faces = entity.faces[face_mask]
    used, inverse = np.unique(faces.ravel(), return_inverse=True)
    if "core_vertices" not in kw and entity.core_vertices >= 0:  # the voted core stays first (``used`` is sorted)
        kw["core_vertices"] = int(np.count_nonzero(used < entity.core_vertices))
    return replace(entity, vertices=entity.vertices[used], faces=inverse.reshape(-1, 3), **kw)


def wall_parts(entity: Entity, cfg: LayoutConfig) -> tuple[list[NDArray], NDArray]:
    """Face masks of the wall parts (largest first) and the mask of dropped faces."""
    centroid, normal, area = _faces(entity)
    n_faces = len(area)
    vertical = (np.abs(normal[:, 2]) < cfg.vertical_max_nz) & (area > 0.0)
    azimuth = np.degrees(np.arctan2(normal[:, 1], normal[:, 0])) % 180.0
    parallel_cos = float(np.cos(np.radians(cfg.parallel_deg)))
    remaining = vertical.copy()
    planes: list[tuple[NDArray, float, NDArray]] = []  # (unit normal u, offset s0, member mask)
    for _ in range(4 * cfg.max_parts):
        if len(planes) >= cfg.max_parts or area[remaining].sum() < cfg.min_area:
            break
        idx = np.flatnonzero(remaining)
        theta = np.radians(_smoothed_peak(azimuth[idx], area[idx], AZIMUTH_BIN_DEG, int(180 / AZIMUTH_BIN_DEG)))
        u = np.array([np.cos(theta), np.sin(theta), 0.0])
        par = remaining & (np.abs(normal @ u) >= parallel_cos)
        if not par.any():  # the peak came from smoothing over non-parallel faces
            remaining[idx[np.argmax(area[idx])]] = False
            continue
        offset = centroid @ u
        pidx = np.flatnonzero(par)
        s0 = _smoothed_peak(offset[pidx], area[pidx], OFFSET_BIN)
        members = par & (np.abs(offset - s0) <= cfg.thickness)
        if not members.any():
            members = par
        remaining &= ~members
        if area[members].sum() >= cfg.min_area:
            planes.append((u, s0, members))
    # Cut every plane where its faces leave a gap along the wall; keep the parts that are walls.
    parts: list[tuple[NDArray, NDArray, float, float, float]] = []  # (mask, u, s0, t_lo, t_hi)
    for u, s0, members in planes:
        along = np.array([-u[1], u[0], 0.0])
        idx = np.flatnonzero(members)
        tri = entity.vertices[entity.faces[idx]] @ along  # (k, 3) positions along the wall
        t_lo, t_hi = tri.min(axis=1), tri.max(axis=1)
        order = np.argsort(t_lo, kind="stable")
        reach = np.maximum.accumulate(t_hi[order])
        cuts = np.flatnonzero(t_lo[order][1:] - reach[:-1] > cfg.max_gap) + 1
        for piece in np.split(order, cuts):
            lo, hi = float(t_lo[piece].min()), float(t_hi[piece].max())
            if area[idx[piece]].sum() < cfg.min_area or hi - lo < cfg.min_length:
                continue
            mask = np.zeros(n_faces, dtype=bool)
            mask[idx[piece]] = True
            parts.append((mask, u, s0, lo, hi))
    if not parts:
        return [], np.zeros(n_faces, dtype=bool)
    claimed = np.zeros(n_faces, dtype=bool)
    for p in parts:
        claimed |= p[0]
    # Every other face joins the nearest part (distance to its vertical rectangle in x-y) or is dropped.
    rest = np.flatnonzero(~claimed)
    dist = np.full((len(parts), len(rest)), np.inf)
    for k, (_, u, s0, lo, hi) in enumerate(parts):
        c = centroid[rest]
        t = c @ np.array([-u[1], u[0], 0.0])
        dist[k] = np.hypot(c @ u - s0, np.maximum(0.0, np.maximum(lo - t, t - hi)))
    nearest = np.argmin(dist, axis=0) if len(rest) else np.zeros(0, np.int64)
    close = dist[nearest, np.arange(len(rest))] <= cfg.thickness if len(rest) else np.zeros(0, bool)
    masks = [p[0].copy() for p in parts]
    for k in range(len(parts)):
        masks[k][rest[close & (nearest == k)]] = True
    dropped = np.zeros(n_faces, dtype=bool)
    dropped[rest[~close]] = True
    masks.sort(key=lambda m: -float(area[m].sum()))
    return masks, dropped


def horizontal_inliers(entity: Entity, cfg: LayoutConfig) -> NDArray | None:
    """Faces within ``thickness`` of the dominant horizontal plane (None: no horizontal faces)."""
    centroid, normal, area = _faces(entity)
    flat = (np.abs(normal[:, 2]) >= HORIZONTAL_NZ) & (area > 0.0)
    if not flat.any() or area[flat].sum() <= 0.0:
        return None
    z0 = _smoothed_peak(centroid[flat, 2], area[flat], OFFSET_BIN)
    return np.abs(centroid[:, 2] - z0) <= cfg.thickness


def split_layout(entity: Entity, cfg: LayoutConfig, wall_classes: list[str],
                 horizontal_classes: list[str]) -> list[Entity]:
    """The entity's layout parts (see module doc); ``[entity]`` itself when there is nothing to do."""
    if not cfg.enabled or not entity.has_faces:
        return [entity]
    if entity.class_name in wall_classes:
        masks, dropped = wall_parts(entity, cfg)
        if len(masks) <= 1 and not dropped.any():
            return [entity]
        if not masks:
            return [entity]
        if dropped.any():
            log.info("layout entity %s: %d stray faces dropped", entity.id, int(dropped.sum()))
        if len(masks) == 1:
            return [sub_entity(entity, masks[0])]
        return [sub_entity(entity, m, name=f"{entity.class_name}_{k}") for k, m in enumerate(masks, start=1)]
    if entity.class_name in horizontal_classes:
        keep = horizontal_inliers(entity, cfg)
        if keep is None or keep.all() or not keep.any():
            return [entity]
        log.info("layout entity %s: %d stray faces dropped", entity.id, int((~keep).sum()))
        return [sub_entity(entity, keep)]
    return [entity]
