"""Observed (partial) entity meshes: what a camera trajectory actually saw of the ground truth.

Ground-truth meshes are complete: the back of a cabinet against the wall, the floor under the
sofa, the underside of a table top are all there, which flatters box fitting and support
inference. To evaluate honestly without a mapper, every ground-truth mesh is cut down to the
faces the recording's camera hit: each mesh is subdivided to ``max_edge`` (so a wall is not one
all-or-nothing triangle), every ``frame_stride``-th camera pose of the bag is ray cast at a
reduced resolution within the sensor's range (paper: rays 0.1-4.0 m) and faces hit by at least
``min_hits`` rays are kept. Entities never seen are dropped (a mapper could not detect them).

``contact_band`` > 0 also models the one mapping effect that matters most for boxes: in a TSDF
(truncation 4 voxels, 4 cm in the paper) the lowest few centimetres of an object standing on a
surface fuse with that surface and take its label, so an object's mapped mesh ends above its
support (Fig. 3d's floating chair box). Faces lying entirely within the band above the object's
placement height are cut off. ``vertex_noise`` jitters the kept vertices (a crude stand-in for
depth noise). Not modelled: TSDF smoothing, thin parts vanishing, segmentation errors.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from recon_core.entity import Entity
from scene_recon.synthetic.scene import GroundTruthScene, entity_from_ground_truth


@dataclass
class ObservationConfig:
    max_edge: float = 0.05
    width: int = 160
    height: int = 120
    frame_stride: int = 2
    min_range: float = 0.1
    max_range: float = 4.0
    min_hits: int = 1
    #: Height (m) above an object's support surface whose faces fuse with the support (0: off).
    contact_band: float = 0.0
    #: Standard deviation (m) of Gaussian noise added to the kept vertices (0: exact geometry).
    vertex_noise: float = 0.0
    seed: int = 0


@dataclass(frozen=True)
class CameraView:
    """Camera-to-map pose of the optical frame (z forward) and its 3x3 intrinsics at (width, height)."""

    pose: np.ndarray
    k: np.ndarray
    width: int
    height: int


def camera_views(bag: str | Path, cfg: ObservationConfig | None = None) -> list[CameraView]:
    """Every ``frame_stride``-th posed frame of a recording, intrinsics scaled to the cast resolution."""
    from panoptic_mapping.dataio import DataInputConfig
    from panoptic_mapping.dataio.registry import open_dataset

    cfg = cfg or ObservationConfig()
    views = []
    data_cfg = DataInputConfig(require_pose=True, stride=max(cfg.frame_stride, 1))
    with open_dataset(bag, data_cfg) as loader:
        for f in loader:
            if f.pose is None:
                continue
            k = f.intrinsics.matrix.copy()
            sx, sy = cfg.width / f.intrinsics.width, cfg.height / f.intrinsics.height
            k[0] *= sx
            k[1] *= sy
            views.append(CameraView(np.asarray(f.pose, np.float64), k, cfg.width, cfg.height))
    return views


def _subdivided(mesh: trimesh.Trimesh, max_edge: float) -> tuple[np.ndarray, np.ndarray]:
    v, f = trimesh.remesh.subdivide_to_size(np.asarray(mesh.vertices, np.float64),
                                            np.asarray(mesh.faces, np.int64), max_edge, max_iter=12)
    return np.asarray(v, np.float64), np.asarray(f, np.int64)


def observed_entities(scene: GroundTruthScene, views: list[CameraView],
                      cfg: ObservationConfig | None = None) -> tuple[list[Entity], dict[str, float]]:
    """Entities reduced to the faces the views hit; the stats give the kept share of area per entity."""
    import open3d as o3d

    cfg = cfg or ObservationConfig()
    meshes = [_subdivided(e.mesh, cfg.max_edge) for e in scene.entities]
    rs = o3d.t.geometry.RaycastingScene()
    geom_ids = []
    for v, f in meshes:
        geom_ids.append(rs.add_triangles(o3d.core.Tensor(v.astype(np.float32)),
                                         o3d.core.Tensor(f.astype(np.uint32))))
    index = {int(g): k for k, g in enumerate(geom_ids)}
    hits = [np.zeros(len(f), np.int64) for _, f in meshes]
    for view in views:
        ext = o3d.core.Tensor(np.linalg.inv(view.pose), o3d.core.Dtype.Float64)
        kk = o3d.core.Tensor(view.k, o3d.core.Dtype.Float64)
        rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(kk, ext, view.width, view.height)
        ans = rs.cast_rays(rays)
        t = ans["t_hit"].numpy().ravel()
        dirs = rays.numpy().reshape(-1, 6)[:, 3:]
        dist = t * np.linalg.norm(dirs, axis=1)
        ok = np.isfinite(t) & (dist >= cfg.min_range) & (dist <= cfg.max_range)
        gid = ans["geometry_ids"].numpy().ravel()[ok]
        pid = ans["primitive_ids"].numpy().ravel()[ok]
        for g in np.unique(gid):
            k = index.get(int(g))
            if k is not None:
                np.add.at(hits[k], pid[gid == g], 1)
    out: list[Entity] = []
    stats: dict[str, float] = {}
    rng = np.random.default_rng(cfg.seed)
    for e, (v, f), h in zip(scene.entities, meshes, hits, strict=True):
        seen = h >= cfg.min_hits
        sub = trimesh.Trimesh(v, f[seen], process=False)
        if cfg.contact_band > 0.0 and e.category != "layout" and len(sub.faces):
            support_z = float(e.pose[2, 3])  # objects are placed with their model origin on the support
            sub = trimesh.intersections.slice_mesh_plane(sub, [0.0, 0.0, 1.0], [0.0, 0.0, support_z + cfg.contact_band])
        if len(sub.faces) == 0:
            stats[e.name] = 0.0
            continue
        sub.remove_unreferenced_vertices()
        full_area = float(trimesh.Trimesh(v, f, process=False).area)
        stats[e.name] = float(sub.area / full_area) if full_area > 0 else 0.0
        if cfg.vertex_noise > 0.0:
            sub = trimesh.Trimesh(sub.vertices + rng.normal(0.0, cfg.vertex_noise, sub.vertices.shape), sub.faces,
                                  process=False)
        out.append(entity_from_ground_truth(e, sub))
    return out, stats
