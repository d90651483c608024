"""Mesh-based feature extraction, shared by CAD import and the reconstruction side.

* ``extract_planes``: iterative RANSAC plane detection with outward normals (paper Sec. 2.2 /
  4.1: 3 cm threshold, 200 iterations, keep extracting while a plane takes > 10 % of the cloud).
  Works on a mesh (area-uniform samples carry their face normals) or on a raw point cloud.
* ``gravity_aligned_box``: the minimal-area box around points whose vertical axis is gravity.
* ``find_support_surfaces``: upward horizontal regions of a mesh with outline and free clearance
  (real surfaces only: pieces at one height merged, slivers and sloped patches dropped).
* ``mesh_features``/``model_mesh_features``: the three above bundled into ``ModelFeatures``;
  ``scan_features``: the box and support levels of an object kept as its scan.

Procedural models get their features analytically (``assembly.py``); imported models and
reconstructed object meshes use these functions.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import trimesh
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError, cKDTree

from cad_replacement.cad.feature_types import ModelFeatures, SupportSurface
from cad_replacement.cad.model import CadModel, bounding_box_features
from recon_core.geometry.plane import SUPPORT_NORMAL_COS, merge_planes
from recon_core.geometry.plane_fit import PLANE_DISTANCE, extract_planes
from recon_core.geometry.polygon import polygon_area
from recon_core.geometry.transforms import as_mesh

#: Support surfaces: smallest area (m^2), height tolerance when grouping faces (m).
SUPPORT_MIN_AREA = 0.01
SUPPORT_HEIGHT_TOL = 0.01
#: Pieces of one height closer than this (m) are one surface: imported meshes split a board into
#: triangle soups, UV islands or planks that share no vertex indices.
SUPPORT_MERGE_GAP = 0.005
#: Narrowest usable surface (m): the top edges of panels, rims and frames hold nothing.
SUPPORT_MIN_WIDTH = 0.05
#: Largest height spread (m) inside one surface: a shelf is flat, a cushion or a dome is not.
SUPPORT_MAX_RELIEF = 0.03
#: Smallest share of its outline a surface must cover: the top edges of a carcass's side and back
#: panels join into a U whose hull spans the whole cabinet, yet nothing stands in its middle.
SUPPORT_MIN_FILL = 0.5
#: Rays per support surface for clearance/enclosure tests.
SUPPORT_RAYS = 32
#: Fraction of rays that must be blocked in every direction for a surface to count as enclosed.
ENCLOSED_FRACTION = 0.8


def _face_components(mesh: trimesh.Trimesh, faces: NDArray[np.int64], gap: float) -> list[NDArray[np.int64]]:
    """Groups of ``faces`` whose corners come within ``gap`` of each other (by position, not index).

    Positions rather than vertex indices, because imported meshes rarely share indices across a
    flat region (per-face normals, UV seams, separate planks); ``gap`` bridges hairline joints.
    """
    if len(faces) == 1:
        return [faces]
    corners = mesh.triangles[faces].reshape(-1, 3)
    owner = np.repeat(np.arange(len(faces)), 3)
    pairs = cKDTree(corners).query_pairs(max(gap, 1e-9), output_type="ndarray")
    edges = owner[pairs] if len(pairs) else np.zeros((0, 2), dtype=np.int64)
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(len(faces), len(faces)))
    _, labels = connected_components(graph, directed=False)
    return [faces[labels == k] for k in np.unique(labels)]


def _min_width(polygon: NDArray[np.float64]) -> float:
    """Smallest width of a convex polygon (rotating calipers: the widths across its edge normals)."""
    edges = np.roll(polygon, -1, axis=0) - polygon
    lengths = np.linalg.norm(edges, axis=1)
    keep = lengths > 1e-12
    if not np.any(keep):
        return 0.0
    normals = np.stack([-edges[keep, 1], edges[keep, 0]], axis=1) / lengths[keep, None]
    spans = polygon @ normals.T  # (vertices, edges)
    return float((spans.max(axis=0) - spans.min(axis=0)).min())


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
    merge_gap: float = SUPPORT_MERGE_GAP,
    min_width: float = SUPPORT_MIN_WIDTH,
    max_relief: float = SUPPORT_MAX_RELIEF,
    min_fill: float = SUPPORT_MIN_FILL,
    rays: int = SUPPORT_RAYS,
    seed: int = 0,
) -> list[SupportSurface]:
    """Upward, horizontal regions of ``mesh`` (z up) large enough to put things on.

    Faces with ``normal.z > normal_cos`` are grouped by height (gaps > ``height_tol`` split) and
    into pieces whose corners lie within ``merge_gap`` (so a board split into many small or
    disconnected triangles stays one surface). A piece becomes a surface when it covers at least
    ``min_area``, its outline (the convex hull of its vertices) is at least ``min_width`` across
    (panel edges are not shelves) and covered by the faces to at least ``min_fill`` (rims and
    frames are not shelves either), and its heights spread by at most ``max_relief`` (flat).
    Rays cast from sample points give the free ``clearance`` (10th percentile of upward hit
    distances; ``None`` when most rays escape) and ``enclosed`` (blocked upwards and in all four
    horizontal directions). ``face_links`` names the link of every face so a surface knows which
    link carries it.
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
        for comp in _face_components(mesh, group, merge_gap):
            areas = mesh.area_faces[comp]
            total = float(areas.sum())
            if total < min_area:
                continue
            corners = mesh.vertices[mesh.faces[comp]].reshape(-1, 3)
            if np.ptp(corners[:, 2]) > max_relief:
                continue
            z = float(np.average(mesh.triangles_center[comp, 2], weights=areas))
            xy = corners[:, :2]
            try:
                poly = xy[ConvexHull(xy).vertices]
            except (QhullError, ValueError):
                continue
            if _min_width(poly) < min_width or total < min_fill * polygon_area(poly):
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


#: A scan's surfaces within this (m) of its top are its top: the top face (the box's footprint) stands for them.
SCAN_TOP_BAND = 0.02


def scan_top_height(mesh: trimesh.Trimesh, highest: float) -> float:
    """Height of a scan's top: the highest level holding ``SUPPORT_MIN_AREA`` of upward faces within
    ``SCAN_TOP_BAND`` (``highest``, the scan's highest point, when no level does).

    A table's scan carries pieces of what stood on it (a microwave's foot, a book's edge) a few
    centimetres above its top; the highest point put everything on the table onto them."""
    up = mesh.face_normals[:, 2] > SUPPORT_NORMAL_COS
    if not np.any(up):
        return highest
    z = np.asarray(mesh.triangles_center[up, 2], np.float64)
    area = np.asarray(mesh.area_faces[up], np.float64)
    order = np.argsort(z)
    z, area = z[order], area[order]
    cum = np.r_[0.0, np.cumsum(area)]
    start = np.searchsorted(z, z - SCAN_TOP_BAND, side="left")  # faces within the band below each face
    held = cum[1:] - cum[start]
    levels = np.flatnonzero(held >= SUPPORT_MIN_AREA)
    return float(z[levels[-1]]) if len(levels) else highest


def scan_features(mesh: trimesh.Trimesh, *, seed: int = 0) -> ModelFeatures:
    """Box and support surfaces of an object kept as its scan (given with z up, origin at its bottom).

    An object no CAD model explains keeps its observed mesh, and what was seen inside it (a book on a
    cabinet's inner shelf, a cup on a fridge's shelf) must rest where it was seen, not on the scan's
    top (the snap lifted gen-5151's books 13-30 cm). The top is the box's footprint at its highest
    point, unbounded above, as before: a scan's top is rarely seen whole (a cup hides the table under
    it). Below it, ``find_support_surfaces`` finds the levels a camera saw (upward, flat, at least
    10 x 10 cm of surface); those within ``SCAN_TOP_BAND`` of the top are the top. No planes: a scan
    is not matched against anything.
    """
    box = bounding_box_features(mesh)
    if len(mesh.faces) == 0:
        return box
    lo, hi = box.box_center - 0.5 * box.box_size, box.box_center + 0.5 * box.box_size
    top_z = scan_top_height(mesh, float(hi[2]))
    top = SupportSurface(height=top_z, polygon=np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]],
                                                                [lo[0], hi[1]]]))
    inner = [s for s in find_support_surfaces(mesh, seed=seed) if s.height < top_z - SCAN_TOP_BAND]
    return dataclasses.replace(box, support_surfaces=(top, *sorted(inner, key=lambda s: -s.height)))


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
    whole = as_mesh(trimesh.util.concatenate([m for _, m in meshes]))
    face_links = np.concatenate([np.full(len(m.faces), name, dtype=object) for name, m in meshes])
    return mesh_features(whole, face_links=face_links, seed=seed)
