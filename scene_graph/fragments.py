"""Stray fragments of mapped object meshes: small pieces far from the object's body are dropped.

A mapped entity's mesh (TSDF, 2 cm voxels, labels voted per voxel) carries a few faces that took
its label far away from the object: a sliver of the wall behind it, a patch of floor, the edge
of a neighbour. The paper fits the minimal box to the whole mesh (Sec. 2.2), which assumes a
clean mesh: a four-face fragment 30 cm from a cup makes its box five times too large, so the
node matches nothing and supports nothing. Before the box is fitted (not in the paper):

* the mesh's connected components (shared edges) are grouped by single linkage: two components
  whose axis-aligned bounds are at most ``max_gap`` apart belong together;
* the group with the largest area is the object's body; every other group is dropped when it
  holds less than ``max_share`` of the mesh area, or, when it lies more than ``far_gap`` from the
  body, less than ``far_share`` (a large separate piece is kept: an object whose middle is
  hidden behind a chair back is seen in two parts).

Complete ground-truth meshes are single pieces (or touching parts) and pass unchanged; so do
point-only entities.
"""

from __future__ import annotations

import logging

import numpy as np
import trimesh
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from recon_core.entity import Entity
from scene_graph.config import FragmentConfig
from scene_graph.layout import sub_entity

log = logging.getLogger(__name__)

#: Components per block of the pairwise gap computation.
GAP_BLOCK = 256


def face_components(entity: Entity) -> NDArray[np.int64]:
    """Connected-component label per face (faces sharing an edge are connected)."""
    mesh = trimesh.Trimesh(entity.vertices, entity.faces, process=False)
    n = len(entity.faces)
    adj = mesh.face_adjacency
    if len(adj) == 0:
        return np.arange(n)
    graph = coo_matrix((np.ones(len(adj)), (adj[:, 0], adj[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def body_faces(entity: Entity, cfg: FragmentConfig) -> NDArray[np.bool_] | None:
    """Mask of the faces to keep, or None when nothing is dropped."""
    if not cfg.enabled or len(entity.faces) < 2:
        return None
    label = face_components(entity)
    n_comp = int(label.max()) + 1
    if n_comp < 2:
        return None
    tri = entity.vertices[entity.faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    comp_area = np.bincount(label, weights=area, minlength=n_comp)
    lo = np.full((n_comp, 3), np.inf)
    hi = np.full((n_comp, 3), -np.inf)
    np.minimum.at(lo, label, tri.min(axis=1))
    np.maximum.at(hi, label, tri.max(axis=1))
    # Single linkage on the bounds' gap (0 where they overlap), in row blocks to bound memory.
    rows, cols = [], []
    for start in range(0, n_comp, GAP_BLOCK):
        blo, bhi = lo[start:start + GAP_BLOCK], hi[start:start + GAP_BLOCK]
        gap = np.maximum(np.maximum(blo[:, None] - hi[None], lo[None] - bhi[:, None]), 0.0).max(axis=2)
        r, c = np.nonzero(gap <= cfg.max_gap)
        rows.append(r + start)
        cols.append(c)
    r, c = np.concatenate(rows), np.concatenate(cols)
    near = coo_matrix((np.ones(len(r)), (r, c)), shape=(n_comp, n_comp))
    _, group = connected_components(near, directed=False)
    group_area = np.bincount(group, weights=comp_area)
    total = float(group_area.sum())
    if total <= 0.0:
        return None
    body = int(np.argmax(group_area))
    n_group = len(group_area)
    glo = np.full((n_group, 3), np.inf)
    ghi = np.full((n_group, 3), -np.inf)
    np.minimum.at(glo, group, lo)
    np.maximum.at(ghi, group, hi)
    body_gap = np.maximum(np.maximum(glo - ghi[body], glo[body] - ghi), 0.0).max(axis=1)
    share = group_area / total
    keep_group = np.where(body_gap <= cfg.far_gap, share >= cfg.max_share, share >= cfg.far_share)
    keep_group[body] = True
    if keep_group.all():
        return None
    return keep_group[group[label]]


def drop_fragments(entity: Entity, cfg: FragmentConfig) -> Entity:
    """The entity without its small stray fragments (itself when there are none)."""
    if not entity.has_faces:
        return entity
    keep = body_faces(entity, cfg)
    if keep is None:
        return entity
    log.debug("entity %s: %d fragment faces dropped", entity.id, int((~keep).sum()))
    return sub_entity(entity, keep)
