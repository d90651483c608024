"""Synthetic observations of CAD models for the stage-4 tests: a posed model as a camera in front sees it."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import trimesh

from cad_replacement.alignment import raycasting_scene
from cad_replacement.cad.model import CadModel
from cad_replacement.observation import ObjectObservation


def yaw_pose(yaw: float, xyz: tuple[float, float, float]) -> np.ndarray:
    """4x4 pose: rotation about z by ``yaw``, translation ``xyz``."""
    c, s = np.cos(yaw), np.sin(yaw)
    t = np.eye(4)
    t[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    t[:3, 3] = xyz
    return t


def observe_model(
    model: CadModel, pose: np.ndarray, values: dict[str, float] | None, rng: np.random.Generator, *, half: bool = True
) -> tuple[ObjectObservation, trimesh.Trimesh]:
    """Surface samples of the posed model, seen from a camera in front (camera-facing half), 5 mm noise."""
    mesh = model.mesh(values)
    mesh.apply_transform(pose)
    pts, fidx = trimesh.sample.sample_surface(mesh, 6000, seed=int(rng.integers(1000)))
    nrm = mesh.face_normals[fidx]
    front = pose[:3, 0]
    side = rng.uniform(-0.5, 0.5)
    c, s = np.cos(side), np.sin(side)
    view = np.array([c * front[0] - s * front[1], s * front[0] + c * front[1]])
    cam = pose[:3, 3] + np.r_[2.5 * view, 1.5]
    if half:  # what a camera there sees: facing it and not hidden behind other parts
        ray = pts - cam
        dist = np.linalg.norm(ray, axis=1)
        hit = raycasting_scene(mesh).cast_rays(
            o3d.core.Tensor(np.c_[np.broadcast_to(cam, pts.shape), ray / dist[:, None]].astype(np.float32))
        )["t_hit"].numpy()
        keep = (np.einsum("ij,ij->i", nrm, -ray) > 0.0) & (hit >= dist - 2e-3)
        pts, nrm = pts[keep], nrm[keep]
    pts = pts + rng.normal(0.0, 0.005, pts.shape)
    obs = ObjectObservation(1, "obj", model.class_name, pts, normals=nrm, support_z=float(pose[2, 3]), front_hint=view)
    return obs, mesh


def complete_observation(model: CadModel, pose: np.ndarray, values: dict[str, float] | None,
                         name: str = "obj") -> tuple[ObjectObservation, trimesh.Trimesh]:
    """The posed model's complete mesh sampled as the protocol's ground-truth entities are (no noise, every side),
    standing on z = 0 with its own front as the hint; and that mesh."""
    from cad_replacement.observation import MESH_SAMPLES
    from recon_core.geometry.plane_fit import sample_mesh

    mesh = model.mesh(values)
    mesh.apply_transform(pose)
    points, normals = sample_mesh(mesh, MESH_SAMPLES, 0)
    obs = ObjectObservation(1, name, model.class_name, points, normals=normals, support_z=0.0,
                            front_hint=pose[:2, 0].copy(), mesh=mesh)
    return obs, mesh
