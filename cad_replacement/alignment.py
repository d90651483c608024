"""Optimisation-based CAD alignment (paper Sec. 4.3, Eqs. 11-14) and the Alignment Error (AE).

The transform of Eq. (11) is ``T = [alpha R | p]`` with ``R = Rot(z, theta)`` and the translation's
vertical component fixed by the support constraint ``p^g = -d^s + alpha s_y^g / 2``. Here the
scale is anisotropic (``diag(s)`` in the model frame; the paper's uniform alpha is the special case
used by ``method="paper"``), so a model point ``m`` lands at

    x = Rz(dtheta) R0 (s * (m - c_m)) + t,   t = (tx, ty, bottom_z + |R0[2]| . (s * size_m) / 2)

where ``R0`` is the discrete orientation from matching, ``c_m``/``size_m`` the model's box centre and
size, and ``t`` the position of the model box centre in the map (its bottom sits on the support).

Instead of the paper's box/plane residuals (Eqs. 12-14) the fit minimises dense distances with
Levenberg-Marquardt (``scipy.optimize.least_squares(method="lm")``) and an analytic Jacobian:

* observed point -> CAD surface: points are mapped into the canonical model frame (inverse
  translation, yaw and scale), the closest surface point is found with an Open3D
  ``RaycastingScene`` built once per model, mapped back, and the true map-frame distance (signed by
  the surface normal) is the residual;
* CAD surface -> observation (ours only): CAD samples that the observation could have seen (see
  ``visible_samples``) measure their distance to the nearest observed *surfel* (a disk of the
  observation's sampling radius around each point), so a model bigger than the object is pulled in
  instead of fitting the points equally well.

Ours passes the point residuals through a soft-L1 function (bounded influence of clutter) and
adds a weak prior towards isotropic scale. For articulated models (the paper exports them closed,
Sec. 4.3 fits ``T o y`` with ``y`` at rest) ours extends Eq. (11) to ``T o y(q)``:

* articulation envelope (``envelope_mesh``, screening): a point may also be explained, at the
  price ``envelope_margin``, by a moving part at any joint value, so an open door neither drags the
  body's yaw nor counts as clutter, and only static links measure missing data;
* joint refinement (``joints=``): the values of the open joints are LM parameters next to the
  pose, with analytic columns from the parts' motion about/along their axes;
* a point whose closest CAD face has the opposite normal (the back of a 5 cm door, the inside of a
  panel) costs at least ``robust_scale``: otherwise a model shifted by a door's thickness fits
  about as well as the right one (``point_normals``).

The CAD -> observation samples of the fits and of the AE count where the observation covers their
direction at about their offset (``FaceAreas``): shelves seen through an open fridge door make +z
"seen", but not the fridge's top above the camera.

AE (reported, and ours' selection criterion) is the RMS of both directions; the paper's AE (Sec.
4.3) is the RMS of the first one only, kept as ``ae_points``.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import open3d as o3d
import open3d.core as o3c
import trimesh
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from cad_replacement.cad.model import CadModel, Link, join_link_meshes
from recon_core.geometry.box import GravityBox
from recon_core.kinematic_tree import Joint

from .observation import ObjectObservation
from .replace_config import CadReplacementConfig

EPS = 1e-12
#: Offset (m) of visibility rays from the surface they start on.
RAY_OFFSET = 1e-3
#: Length of the mean observed normal above which an observation counts as seen from one side.
PARTIAL_MEAN_NORMAL = 0.3
#: Distance (m) of the virtual orthographic camera used for occlusion of partial observations.
VIEW_DISTANCE = 20.0
#: Thickness (m) of the offset slabs of ``FaceAreas``: a CAD face counts as seen when the
#: observation covers its direction within about one slab of its offset.
FACE_SLAB = 0.05
#: Articulation envelope: largest step (m) of a moving part's farthest point between two swept
#: copies, and largest angular step (rad) of a revolute sweep.
SWEEP_STEP = 0.08
SWEEP_MAX_ANGLE = np.radians(15.0)
#: Most swept copies of one joint's subtree in the envelope.
SWEEP_MAX_COPIES = 16


def rot_z(angle: float) -> NDArray[np.float64]:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _fibonacci_sphere(n: int) -> NDArray[np.float64]:
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.c_[r * np.cos(phi), r * np.sin(phi), z]


#: Direction bins used to summarise which sides of an object the observation covers.
DIRECTION_BINS = _fibonacci_sphere(64)
#: Angle (deg) within which a surface normal counts towards a direction bin in the coverage tests
#: (``visible_samples``). The bins are ~25 deg apart and the normals of a mapped surface scatter over
#: neighbouring ones: counted in its nearest bin only, the observed front of a 4 cm book covered 16 %
#: of the CAD front's area (below ``visible_min_coverage``), no CAD sample counted as seen and the
#: AE of most small mapped objects was one-sided. Both areas pool the same cone, so a clean face
#: keeps its ratio. 25 deg, about the bin spacing, pools each bin's direct neighbours (mapped suite
#: pose success 55.8 % at 20 deg, 60.2 % at 25 and 30 deg; at 30 a cup's handle yaw got worse).
BIN_REACH_DEG = 25.0
_BIN_REACH_COS = float(np.cos(np.radians(BIN_REACH_DEG)))
#: (B, K) bins within ``BIN_REACH_DEG`` of each bin (itself first), padded with -1.
_near = [np.flatnonzero(DIRECTION_BINS @ d >= _BIN_REACH_COS) for d in DIRECTION_BINS]
_near = [np.r_[b, nb[nb != b]] for b, nb in enumerate(_near)]
BIN_NEIGHBOURS = np.full((len(_near), max(len(nb) for nb in _near)), -1, dtype=np.int64)
for _b, _nb in enumerate(_near):
    BIN_NEIGHBOURS[_b, : len(_nb)] = _nb
del _near, _b, _nb


def raycasting_scene(mesh: trimesh.Trimesh) -> o3d.t.geometry.RaycastingScene:
    """An Open3D raycasting scene of a mesh (float32 copy of the vertices)."""
    scene = o3d.t.geometry.RaycastingScene()
    if len(mesh.faces):
        scene.add_triangles(
            o3c.Tensor(np.ascontiguousarray(mesh.vertices, dtype=np.float32)),
            o3c.Tensor(np.ascontiguousarray(mesh.faces, dtype=np.uint32)),
        )
    return scene


def closest_points(
    scene: o3d.t.geometry.RaycastingScene, points: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Closest surface points and their face normals (float64) for (N, 3) query points."""
    if len(points) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    res = scene.compute_closest_points(o3c.Tensor(np.ascontiguousarray(points, dtype=np.float32)))
    return res["points"].numpy().astype(np.float64), res["primitive_normals"].numpy().astype(np.float64)


def joint_subtree(model: CadModel, joint: Joint) -> list[str]:
    """Links moved by ``joint``: its child and everything hanging below it."""
    children: dict[str, list[str]] = {}
    for j in model.joints:
        children.setdefault(j.parent, []).append(j.child)
    out, stack = [], [joint.child]
    while stack:
        link = stack.pop()
        out.append(link)
        stack.extend(children.get(link, []))
    return out


def moving_links(model: CadModel) -> set[str]:
    """Links that move with at least one movable joint (the rest is the static body)."""
    out: set[str] = set()
    for j in model.movable_joints:
        out.update(joint_subtree(model, j))
    return out


def sweep_values(model: CadModel, joint: Joint, poses: Mapping[str, NDArray[np.float64]]) -> NDArray[np.float64]:
    """Joint values at which the envelope holds a copy of the joint's subtree (limits included).

    Consecutive copies are at most ``SWEEP_STEP`` apart at the subtree's farthest point from a
    revolute axis (and ``SWEEP_MAX_ANGLE`` apart), ``SWEEP_STEP`` apart along a prismatic axis.
    """
    lo, hi = (joint.lower, joint.upper) if joint.type != "continuous" else (-np.pi, np.pi)
    if joint.type == "prismatic":
        step = SWEEP_STEP
    else:
        frame = poses[joint.parent] @ joint.origin
        radius = 0.0
        for name in joint_subtree(model, joint):
            v = np.asarray(model.link(name).mesh.vertices, dtype=np.float64)
            if len(v) == 0:
                continue
            local = (v @ poses[name][:3, :3].T + poses[name][:3, 3] - frame[:3, 3]) @ frame[:3, :3]
            off = local - np.outer(local @ joint.axis, joint.axis)
            radius = max(radius, float(np.linalg.norm(off, axis=1).max()))
        step = min(SWEEP_MAX_ANGLE, SWEEP_STEP / max(radius, EPS))
    n = int(np.clip(np.ceil((hi - lo) / step) + 1, 2, SWEEP_MAX_COPIES))
    return np.linspace(lo, hi, n)


def envelope_mesh(model: CadModel) -> trimesh.Trimesh:
    """Every movable joint's subtree swept over the joint's range, closed copy excluded (model frame).

    With the closed model it forms the articulation envelope: a point on a door standing open by
    any angle, or on a drawer pulled out by any length, lies on (or within ``SWEEP_STEP`` of) one
    of the copies. Empty for a model without moving geometry.
    """
    poses = model.link_poses()
    zero = model.zero_configuration()
    vertices: list[NDArray[np.float64]] = []
    faces: list[NDArray[np.int64]] = []
    offset = 0
    # Vertices moved with trimesh's own transform (the same numbers as copying each link mesh and
    # calling ``apply_transform``), faces offset as ``trimesh.util.concatenate`` does: the copies,
    # their caches and the concatenation of ~20 meshes per model cost 10x the arithmetic.
    for joint in model.movable_joints:
        sub = [n for n in joint_subtree(model, joint) if len(model.link(n).mesh.faces)]
        if not sub:
            continue
        for q in sweep_values(model, joint, poses):
            if abs(q - joint.zero_value) < 1e-9:
                continue
            at = model.link_poses({**zero, joint.name: float(q)})
            for name in sub:
                mesh = model.link(name).mesh
                v = np.asarray(mesh.vertices, dtype=np.float64)
                f = np.asarray(mesh.faces, dtype=np.int64)
                matrix = np.asarray(at[name], dtype=np.float64)
                if not np.allclose(matrix, np.eye(4), rtol=0.0, atol=1e-8):
                    v = trimesh.transformations.transform_points(v, matrix)
                    if np.linalg.det(matrix[:3, :3]) < 0.0:  # a mirroring pose reverses the winding
                        f = f[:, ::-1]
                vertices.append(v)
                faces.append(f + offset)
                offset += len(v)
    if not vertices:
        return trimesh.Trimesh()
    return trimesh.Trimesh(vertices=np.concatenate(vertices), faces=np.concatenate(faces), process=False)


@dataclass(eq=False)
class ModelGeometry:
    """Everything alignment needs about one CAD model, built once and cached by model key.

    ``scene``: raycasting scene of the closed model in its canonical frame; ``samples``/``normals``:
    area-uniform surface samples (closed configuration, canonical frame); ``self_visible``: whether
    a ray leaving the sample along its normal escapes the model (inner faces, the inside of a closed
    cabinet, faces pressed against each other are never seen by a camera); ``sample_links`` and
    ``link_samples`` (the same samples in their link frames) let articulation re-pose them.

    Articulated models also carry ``envelope`` (raycasting scene of ``envelope_mesh``: the moving
    parts swept over their joint ranges) and ``static_samples`` (samples on links no joint moves);
    ``joint_values`` is the configuration the geometry was built at (see ``articulated``; the box
    ``center``/``size`` always refer to the closed configuration).
    """

    key: str
    #: The model, or a function that builds it: geometry restored from the disk store needs the
    #: full model (meshes, joints) only for the few candidates that reach the full fit.
    source: CadModel | Callable[[], CadModel]
    scene: o3d.t.geometry.RaycastingScene
    center: NDArray[np.float64]
    size: NDArray[np.float64]
    samples: NDArray[np.float64]
    normals: NDArray[np.float64]
    self_visible: NDArray[np.bool_]
    sample_links: NDArray[np.int64]
    link_samples: NDArray[np.float64]
    link_normals: NDArray[np.float64]
    link_names: tuple[str, ...]
    sample_area: float = 0.0  # model surface area (m^2) each sample stands for, closed configuration
    build_time_s: float = 0.0
    envelope: o3d.t.geometry.RaycastingScene | None = None
    static_samples: NDArray[np.bool_] | None = None
    joint_values: dict[str, float] = field(default_factory=dict)
    #: Whether the model has revolute/prismatic joints (known without building the model).
    articulated_model: bool = False
    #: The closed model's mesh and the swept envelope's, as built (kept for the disk store).
    mesh: trimesh.Trimesh | None = None
    swept: trimesh.Trimesh | None = None
    _bare: CadModel | None = None

    @property
    def model(self) -> CadModel:
        if not isinstance(self.source, CadModel):
            self.source = self.source()
        return self.source

    @property
    def bare_model(self) -> CadModel:
        """The model without collision shapes and inertials: meshes and kinematics only, so
        ``scaled`` copies for joint estimation and the AE cost a fraction of a full one."""
        if self._bare is None:
            links = tuple(Link(lk.name, lk.mesh, lk.color) for lk in self.model.links)
            self._bare = dataclasses.replace(self.model, links=links)
        return self._bare

    @property
    def static_mask(self) -> NDArray[np.bool_]:
        return self.static_samples if self.static_samples is not None else np.ones(len(self.samples), dtype=bool)

    def articulated(self, values: Mapping[str, float]) -> ModelGeometry:
        """This geometry at joint values ``values``: scene, samples, normals and self-visibility.

        The same surface samples (``link_samples``) are re-posed, so per-sample areas and link
        indices stay valid; ``center``/``size`` stay those of the closed model (the placement's
        parameters keep their meaning). No envelope: the configuration is given.
        """
        vals = {k: float(v) for k, v in values.items()}
        zero = self.model.zero_configuration()
        if all(abs(vals.get(k, z) - z) < 1e-9 for k, z in zero.items()):
            return self
        t0 = time.perf_counter()
        poses = self.model.link_poses(vals)
        rot = np.stack([poses[n][:3, :3] for n in self.link_names])[self.sample_links]
        trans = np.stack([poses[n][:3, 3] for n in self.link_names])[self.sample_links]
        pts = np.einsum("nij,nj->ni", rot, self.link_samples) + trans
        nrm = np.einsum("nij,nj->ni", rot, self.link_normals)
        scene = raycasting_scene(self.model.mesh(vals))
        rays = np.c_[pts + RAY_OFFSET * nrm, nrm].astype(np.float32)
        hit = scene.cast_rays(o3c.Tensor(rays))["t_hit"].numpy()
        return ModelGeometry(
            key=self.key,
            source=self.model,
            articulated_model=True,
            scene=scene,
            center=self.center,
            size=self.size,
            samples=pts,
            normals=nrm,
            self_visible=~np.isfinite(hit),
            sample_links=self.sample_links,
            link_samples=self.link_samples,
            link_normals=self.link_normals,
            link_names=self.link_names,
            sample_area=self.sample_area,
            build_time_s=time.perf_counter() - t0,
            joint_values=vals,
        )

    @classmethod
    def build(cls, key: str, model: CadModel, samples: int = 1200, seed: int = 0) -> ModelGeometry:
        t0 = time.perf_counter()
        posed = model.posed_link_meshes()
        poses = model.link_poses()
        names = tuple(lk.name for lk in model.links)
        whole = join_link_meshes(posed)  # ``model.mesh()`` without posing every link again
        if len(whole.faces) == 0:
            raise ValueError(f"model {model.model_id!r} has no geometry")
        scene = raycasting_scene(whole)
        areas = np.array([float(posed[n].area) if len(posed[n].faces) else 0.0 for n in names])
        counts = np.floor(samples * areas / max(float(areas.sum()), EPS)).astype(np.int64)
        rng = np.random.default_rng(seed)
        local_pts, local_nrm, link_idx = [], [], []
        for i, name in enumerate(names):
            mesh = model.link(name).mesh
            if counts[i] == 0 or len(mesh.faces) == 0:
                continue
            pts, fidx = trimesh.sample.sample_surface(mesh, int(counts[i]), seed=int(rng.integers(2**31)))
            local_pts.append(np.asarray(pts, dtype=np.float64))
            local_nrm.append(np.asarray(mesh.face_normals[fidx], dtype=np.float64))
            link_idx.append(np.full(len(pts), i))
        lp = np.concatenate(local_pts)
        ln = np.concatenate(local_nrm)
        li = np.concatenate(link_idx)
        rot = np.stack([poses[names[i]][:3, :3] for i in range(len(names))])
        trans = np.stack([poses[names[i]][:3, 3] for i in range(len(names))])
        pts = np.einsum("nij,nj->ni", rot[li], lp) + trans[li]
        nrm = np.einsum("nij,nj->ni", rot[li], ln)
        rays = np.c_[pts + RAY_OFFSET * nrm, nrm].astype(np.float32)
        hit = scene.cast_rays(o3c.Tensor(rays))["t_hit"].numpy()
        lo, hi = whole.bounds
        envelope, static = None, None
        swept = envelope_mesh(model) if model.movable_joints else trimesh.Trimesh()
        if len(swept.faces):
            envelope = raycasting_scene(swept)
            moving = moving_links(model)
            static = np.array([names[i] not in moving for i in range(len(names))])[li]
        return cls(
            key=key,
            source=model,
            articulated_model=bool(model.movable_joints),
            mesh=whole,
            swept=swept if envelope is not None else None,
            scene=scene,
            center=0.5 * (lo + hi),
            size=np.maximum(hi - lo, 1e-6),
            samples=pts,
            normals=nrm,
            self_visible=~np.isfinite(hit),
            sample_links=li,
            link_samples=lp,
            link_normals=ln,
            link_names=names,
            sample_area=float(areas.sum()) / max(len(pts), 1),
            build_time_s=time.perf_counter() - t0,
            envelope=envelope,
            static_samples=static,
            joint_values=model.zero_configuration(),
        )


# ---------------------------------------------------------------------------------------------------------
# prepared observation


@dataclass(eq=False)
class PreparedObservation:
    """Per-observation data shared by all candidates: subsamples, normals, KD-tree, seen directions."""

    obs: ObjectObservation
    points: NDArray[np.float64]  # AE subsample (observed -> CAD direction)
    normals: NDArray[np.float64]
    surfel_points: NDArray[np.float64]  # surfel centres (CAD -> observed direction), indexed by ``tree``
    surfel_normals: NDArray[np.float64]
    tree: cKDTree
    surfel_radius: float
    bin_area: NDArray[np.float64]  # (B,) observed surface area (m^2) per direction bin
    face_area: FaceAreas | None  # observed area per (direction bin, offset slab); None: no normals
    view_dir: NDArray[np.float64] | None  # main viewing direction of a partial observation (None: all around)
    fit_points: NDArray[np.float64]  # full-fit subsample
    screen_points: NDArray[np.float64]
    # Normals of the fit/screen subsamples when the observation came with normals (None otherwise:
    # estimated normals are oriented by a guess and would mislead the normal test of the fits).
    fit_normals: NDArray[np.float64] | None = None
    screen_normals: NDArray[np.float64] | None = None

    @classmethod
    def build(cls, obs: ObjectObservation, cfg: CadReplacementConfig) -> PreparedObservation:
        rng = np.random.default_rng(cfg.seed)
        pts = obs.points
        normals = obs.normals if obs.normals is not None else estimate_normals(pts, obs.gravity_box.center)
        if len(pts) > cfg.ae_points:
            keep = rng.choice(len(pts), cfg.ae_points, replace=False)
            pts_ae, nrm_ae = pts[keep], normals[keep]
        else:
            pts_ae, nrm_ae = pts, normals
        # Surfels: every observed point (capped) is a disk; for uniform sampling of density rho the
        # median nearest-neighbour spacing is m = sqrt(ln 2 / (pi rho)) and a disk radius of
        # sqrt(3 / (pi rho)) = 2.08 m covers 95 % of the sampled surface, so the CAD -> points term
        # measures missing data, not sampling gaps.
        if len(pts) > cfg.surfel_points:
            keep_s = rng.choice(len(pts), cfg.surfel_points, replace=False)
            pts_s, nrm_s = pts[keep_s], normals[keep_s]
        else:
            pts_s, nrm_s = pts, normals
        tree = cKDTree(pts_s)
        probe = pts_s[: min(len(pts_s), 1000)]
        dist, _ = tree.query(probe, k=2)
        spacing = float(np.median(dist[:, 1])) if len(pts_s) > 1 else 0.0
        radius = 2.08 * spacing
        # Area one surfel stands for at this density: 1 / rho = pi m^2 / ln 2.
        area_per_point = np.pi * spacing * spacing / np.log(2.0)
        surfel_area = area_per_point * len(pts) / max(len(pts_s), 1)
        seen = observed_area_per_bin(nrm_s, surfel_area)
        valid = np.linalg.norm(nrm_s, axis=1) > 0.5
        faces = FaceAreas.build(nrm_s[valid], pts_s[valid], surfel_area, obs.gravity_box.center) \
            if np.any(valid) else None
        n_fit = min(cfg.align_points, len(pts))
        i_fit = rng.choice(len(pts), n_fit, replace=False) if len(pts) > n_fit else np.arange(len(pts))
        fit = pts[i_fit]
        n_scr = min(cfg.screen_points, len(fit))
        i_scr = i_fit[rng.choice(len(fit), n_scr, replace=False)] if len(fit) > n_scr else i_fit
        scr = pts[i_scr]
        given = obs.normals is not None
        # A partial observation's normals lean towards where it was seen from; a scan from all
        # sides averages out. |mean normal| > 0.3 -> partial, seen along that direction.
        mean_n = nrm_s.mean(axis=0) if len(nrm_s) else np.zeros(3)
        mlen = float(np.linalg.norm(mean_n))
        view = mean_n / mlen if mlen > PARTIAL_MEAN_NORMAL else None
        return cls(
            obs, pts_ae, nrm_ae, pts_s, nrm_s, tree, radius, seen, faces, view, fit, scr,
            normals[i_fit] if given else None, normals[i_scr] if given else None,
        )


def estimate_normals(points: NDArray[np.float64], center: NDArray[np.float64], k: int = 16) -> NDArray[np.float64]:
    """PCA normals of a point cloud oriented away from ``center`` (observations without normals)."""
    # a copy: Open3D refuses read-only arrays, and observations hand theirs out read-only
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.array(points, dtype=np.float64)))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=min(k, max(3, len(points) - 1))))
    n = np.asarray(pcd.normals, dtype=np.float64)
    flip = np.einsum("ij,ij->i", n, points - center) < 0.0
    n[flip] *= -1.0
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(length > EPS, n / np.maximum(length, EPS), 0.0)


def direction_bin(normals: NDArray[np.float64]) -> NDArray[np.int64]:
    """Index of the nearest of the ``DIRECTION_BINS`` for each (unit) normal."""
    return np.argmax(normals @ DIRECTION_BINS.T, axis=1)


def pooled_bin_counts(normals: NDArray[np.float64]) -> NDArray[np.float64]:
    """How many of the (unit) normals lie within ``BIN_REACH_DEG`` of each direction bin."""
    if len(normals) == 0:
        return np.zeros(len(DIRECTION_BINS))
    return np.count_nonzero(normals @ DIRECTION_BINS.T >= _BIN_REACH_COS, axis=0).astype(np.float64)


def observed_area_per_bin(normals: NDArray[np.float64], area_per_point: float) -> NDArray[np.float64]:
    """Observed surface area (m^2) facing each direction bin (normals within ``BIN_REACH_DEG``);
    all inf without normals."""
    valid = np.linalg.norm(normals, axis=1) > 0.5
    if not np.any(valid):
        return np.full(len(DIRECTION_BINS), np.inf)  # nothing known: every side counts as seen
    return pooled_bin_counts(normals[valid]) * float(area_per_point)


def face_keys(normals: NDArray[np.float64], points: NDArray[np.float64],
              reference: NDArray[np.float64] | None = None) -> NDArray[np.int64]:
    """Key of the (direction bin, offset slab) of oriented points: which face of an object they are on.

    The offset is ``n . (p - reference)`` (the plane's distance from the reference point, the
    observed object's centre, along its own normal), cut into slabs of ``FACE_SLAB``; the top of a
    fridge and the shelves inside it share a direction but not an offset. Measured from the map
    origin instead, a mapped face 3 m away spread over 9 slabs (45 cm): its normals scatter by
    10-20 deg and the lever arm multiplied that, so no CAD face found its observed one.
    """
    b = direction_bin(normals).astype(np.int64)
    rel = points if reference is None else points - np.asarray(reference, dtype=np.float64)
    k = np.floor(np.einsum("ij,ij->i", normals, rel) / FACE_SLAB).astype(np.int64)
    return (b << 32) + (k + (1 << 31))


@dataclass(frozen=True)
class FaceAreas:
    """Surface area per face key (``face_keys``), summed over a key's offset neighbours on lookup."""

    keys: NDArray[np.int64]  # sorted, unique
    areas: NDArray[np.float64]
    #: The point offsets are measured from (``face_keys``): the same for the CAD faces compared.
    reference: NDArray[np.float64] | None = None

    @classmethod
    def build(cls, normals: NDArray[np.float64], points: NDArray[np.float64], area_per_point: float,
              reference: NDArray[np.float64] | None = None) -> FaceAreas:
        keys, counts = np.unique(face_keys(normals, points, reference), return_counts=True)
        return cls(keys, counts.astype(np.float64) * float(area_per_point), reference)

    def _at(self, q: NDArray[np.int64]) -> NDArray[np.float64]:
        if len(self.keys) == 0:
            return np.zeros(len(q))
        i = np.clip(np.searchsorted(self.keys, q), 0, len(self.keys) - 1)
        return np.where(self.keys[i] == q, self.areas[i], 0.0)

    def near(self, q: NDArray[np.int64], reach: int = 1) -> NDArray[np.float64]:
        """Area within ``reach`` slabs of each key's offset (faces straddle borders) whose direction
        bin lies within ``BIN_REACH_DEG`` of the key's (scattered normals, as ``pooled_bin_counts``)."""
        uq, inv = np.unique(np.asarray(q, dtype=np.int64), return_inverse=True)  # a face's samples share keys
        nb = BIN_NEIGHBOURS[uq >> 32]  # (U, K) neighbour bins of every key, -1 padded
        shifts = np.arange(-reach, reach + 1, dtype=np.int64)
        keys = ((np.maximum(nb, 0) << 32) + (uq & 0xFFFFFFFF)[:, None])[:, :, None] + shifts  # (U, K, S)
        areas = self._at(keys.reshape(-1)).reshape(keys.shape)
        out = np.where((nb >= 0)[:, :, None], areas, 0.0).sum(axis=(1, 2))
        return out[inv.reshape(-1)]


def visible_samples(
    normals_map: NDArray[np.float64],
    self_visible: NDArray[np.bool_],
    bin_area: NDArray[np.float64],
    sample_area: float,
    min_coverage: float,
    *,
    samples_map: NDArray[np.float64] | None = None,
    face_area: FaceAreas | None = None,
    face_reach: int = 1,
) -> NDArray[np.bool_]:
    """CAD samples the observation could have seen: not self-occluded and on a side it covers.

    This is how the CAD -> points half of the AE handles partial observations. Samples are grouped
    by the direction of their normal; a direction counts as seen when the observation holds at
    least ``min_coverage`` of the area the posed CAD surface shows in that direction
    (``bin_area`` vs. samples x ``sample_area``). The back of a cabinet seen from the front has
    no data and is skipped; its front is seen, so a model wider than the observed front is
    penalised; a few points on a handle's top do not make the whole top face "seen".

    With ``samples_map`` and ``face_area`` (the AE) the same test also holds per face, i.e. per
    direction and offset (``FaceAreas``): shelves seen through an open fridge door make the +z
    direction "seen" but not the fridge's top above the camera, and the inside wall of the
    carcass does not make the outside of the side panel "seen". A face within ``face_reach``
    slabs (AE: 1, i.e. 5-10 cm) of an observed face of its direction still counts, so a misplaced
    face is still penalised; fits, whose start poses are rougher, reach further.
    """
    bins = direction_bin(normals_map)
    cad_area = pooled_bin_counts(normals_map[self_visible]) * sample_area
    seen = bin_area >= min_coverage * cad_area
    out = self_visible & seen[bins]
    if face_area is not None and samples_map is not None and np.any(out):
        keys = face_keys(normals_map, samples_map, face_area.reference)
        cad_faces = FaceAreas.build(normals_map[self_visible], samples_map[self_visible], sample_area,
                                    face_area.reference)
        out &= face_area.near(keys, face_reach) >= min_coverage * cad_faces.near(keys, face_reach)
    return out


# ---------------------------------------------------------------------------------------------------------
# the least-squares problem


@dataclass(frozen=True)
class Placement:
    """A candidate's pose: ``x = rotation @ (scale * m) + translation`` for model points ``m``."""

    rotation: NDArray[np.float64]
    translation: NDArray[np.float64]
    scale: NDArray[np.float64]

    @property
    def pose(self) -> NDArray[np.float64]:
        """4x4 model frame -> map (float64); apply ``scale`` in the model frame first."""
        t = np.eye(4)
        t[:3, :3] = self.rotation
        t[:3, 3] = self.translation
        return t

    @property
    def yaw(self) -> float:
        return float(np.arctan2(self.rotation[1, 0], self.rotation[0, 0]))

    def apply(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        return (points * self.scale) @ self.rotation.T + self.translation

    def inverse(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        return ((points - self.translation) @ self.rotation) / self.scale


def soft_l1(r: NDArray[np.float64], tau: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Residuals whose squares are the soft-L1 cost 2 tau^2 (sqrt(1 + (r/tau)^2) - 1), and d/dr."""
    q = np.sqrt(1.0 + (r / tau) ** 2)
    rr = np.sign(r) * np.sqrt(2.0 * tau * tau * (q - 1.0))
    safe = np.abs(rr) > 1e-12
    deriv = np.where(safe, r / (np.where(safe, rr, 1.0) * q), 1.0)
    return rr, deriv


@dataclass
class _Configuration:
    """A model at some joint values (model frame): scene, link of every face, joint axes."""

    scene: o3d.t.geometry.RaycastingScene
    face_link: NDArray[np.int64]
    poses: NDArray[np.float64]  # (L, 4, 4) link poses
    axes: NDArray[np.float64]  # (K, 3) joint axes
    origins: NDArray[np.float64]  # (K, 3) points on the joint axes


class _Kinematics:
    """Link meshes as arrays, so a model at new joint values is one transform and one scene build."""

    def __init__(self, geom: ModelGeometry, joints: list[Joint]) -> None:
        model = geom.model
        self.model = model
        self.joints = joints
        self.names = geom.link_names
        index = {n: i for i, n in enumerate(self.names)}
        verts, faces, face_link = [], [], []
        offset = 0
        for i, n in enumerate(self.names):
            mesh = model.link(n).mesh
            if len(mesh.faces) == 0:
                continue
            verts.append(np.asarray(mesh.vertices, dtype=np.float64))
            faces.append(np.asarray(mesh.faces, dtype=np.int64) + offset)
            face_link.append(np.full(len(mesh.faces), i))
            offset += len(mesh.vertices)
        self.vert_link = np.concatenate([np.full(len(v), fl[0]) for v, fl in zip(verts, face_link, strict=True)])
        self.verts = np.concatenate(verts)
        self.faces = np.ascontiguousarray(np.concatenate(faces), dtype=np.uint32)
        self.face_link = np.concatenate(face_link)
        # (K, L): which links each joint moves.
        self.moves = np.zeros((len(joints), len(self.names)), dtype=bool)
        for k, j in enumerate(joints):
            self.moves[k, [index[n] for n in joint_subtree(model, j)]] = True
        self._last: tuple[tuple[float, ...], _Configuration] | None = None

    def at(self, values: dict[str, float]) -> _Configuration:
        key = tuple(values[j.name] for j in self.joints)
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        lp = self.model.link_poses(values)
        poses = np.stack([lp[n] for n in self.names])
        rot, trans = poses[self.vert_link, :3, :3], poses[self.vert_link, :3, 3]
        v = np.einsum("nij,nj->ni", rot, self.verts) + trans
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3c.Tensor(v.astype(np.float32)), o3c.Tensor(self.faces))
        frames = [lp[j.parent] @ j.origin for j in self.joints]
        axes = np.array([f[:3, :3] @ j.axis for f, j in zip(frames, self.joints, strict=True)])
        origins = np.array([f[:3, 3] for f in frames])
        conf = _Configuration(scene, self.face_link, poses, axes.reshape(-1, 3), origins.reshape(-1, 3))
        self._last = (key, conf)
        return conf


class AlignmentProblem:
    """Residuals and analytic Jacobian of the dense fit for one candidate (see module docstring).

    Parameters ``x``: ``(log sx, log sy, log sz, dyaw, tx, ty)`` or, with ``uniform_scale``,
    ``(log s, dyaw, tx, ty)``; ``(tx, ty)`` is the model box centre in the map. With ``joints``,
    one offset per joint (rad or m, from ``geom.joint_values``) follows: pose and joint values are
    then refined together.
    """

    def __init__(
        self,
        geom: ModelGeometry,
        base_rotation: NDArray[np.float64],
        bottom_z: float,
        points: NDArray[np.float64],
        cfg: CadReplacementConfig,
        *,
        prepared: PreparedObservation | None = None,
        uniform_scale: bool = False,
        robust: bool = True,
        two_sided: bool = True,
        anisotropy_weight: float = 0.0,
        model_samples: int = 300,
        height_target: float | None = None,
        height_weight: float = 0.0,
        round_weight: float = 0.0,
        envelope: bool = False,
        face_reach: int | None = None,
        point_normals: NDArray[np.float64] | None = None,
        joints: Sequence[Joint] = (),
    ) -> None:
        self.geom = geom
        # ``joints``: their values (offsets from ``geom.joint_values``) are parameters too. A point
        # whose closest face is on a part a joint moves gets d(residual)/dq from the part's motion
        # (rotation about / translation along the joint axis, in the model frame).
        self.joints = list(joints)
        self.n_base = 4 if uniform_scale else 6
        self.kin = _Kinematics(geom, self.joints) if self.joints else None
        if self.kin is not None and envelope:
            raise ValueError("joint refinement and the articulation envelope do not combine")
        # ``point_normals`` (observed normals of ``points``): a point whose closest CAD surface faces
        # the other way (the back of a thin door, the inside of a panel) is not explained by it; its
        # residual is at least ``robust_scale`` (``_point_terms``). Without this, a model shifted
        # by a door's thickness fits the points about as well as the right one.
        self.point_normals = point_normals
        # ``face_reach``: the CAD -> observed samples are chosen per face as in the AE, with this
        # reach in offset slabs (``visible_samples``); None: per direction only.
        self.face_reach = face_reach
        # ``envelope``: fit the body whatever the doors and drawers do. A point is explained by the
        # closed model or, at the price ``envelope_margin``, by a moving part at some other joint
        # value (``envelope_mesh``): an open door's points neither drag the body towards them nor
        # count as clutter, while points the body can explain still prefer the body. Only samples
        # of static links measure missing data (a closed door's front has no points when the door
        # stands open; the body's sides and top have them either way).
        self.envelope = envelope and geom.envelope is not None
        self.margin = cfg.envelope_margin
        self.r0 = np.asarray(base_rotation, dtype=np.float64)
        self.bottom_z = float(bottom_z)
        self.points = points
        self.cfg = cfg
        self.uniform = uniform_scale
        self.robust = robust
        self.tau = cfg.robust_scale
        self.aniso = anisotropy_weight * np.sqrt(max(len(points), 1))
        # Eq. (13), second component: the model's height should equal the observed box height
        # (support to top), which every view of a standing object shows.
        self.height_target = height_target
        self.height_w = height_weight * np.sqrt(max(len(points), 1))
        self.prepared = prepared if two_sided else None
        self.up_row = np.abs(self.r0[2])  # which model axis is vertical (|R0| row z)
        # A round object (a solid of revolution about the vertical) has one horizontal radius: its
        # two horizontal log-scales are tied, so fringe on one side of a small mapped object cannot
        # stretch it into an ellipse.
        self.round_w = round_weight * np.sqrt(max(len(points), 1))
        self.horizontal_axes = np.argsort(self.up_row)[:2]
        self._cache_x: NDArray[np.float64] | None = None
        self._cache: tuple[NDArray[np.float64], NDArray[np.float64] | None] | None = None
        self.samples = np.zeros((0, 3))
        self.sample_normals = np.zeros((0, 3))
        self.sample_idx = np.zeros(0, dtype=np.int64)
        # Model samples the CAD -> observed term draws from (their count sets the area per sample).
        pool = geom.self_visible & geom.static_mask if self.envelope else geom.self_visible
        # Each drawn sample stands for (pool area) / (drawn samples) in ``visible_samples``' test.
        self.pool_count = int(np.count_nonzero(pool))
        if self.prepared is not None:
            rng = np.random.default_rng(cfg.seed)
            idx = np.flatnonzero(pool)
            if len(idx) > model_samples:
                idx = rng.choice(idx, model_samples, replace=False)
            self.samples = geom.samples[idx]
            self.sample_normals = geom.normals[idx]
            self.sample_idx = idx
        self.sample_weight = np.sqrt(len(points) / max(len(self.samples), 1))
        self.visible_mask: NDArray[np.bool_] | None = None

    # ------------------------------------------------------------------ parameters
    def scales(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Per-axis scales of ``x``. Levenberg-Marquardt may try a wild step on a weakly constrained
        axis (a round object's radius, with no anisotropy prior): the log-scales are clipped to
        ``LOG_SCALE_GUARD`` so the trial pose stays finite (the solver then steps back) instead of
        overflowing into points no nearest-neighbour query can answer."""
        ls = np.full(3, x[0]) if self.uniform else x[:3]
        return np.exp(np.clip(ls, -LOG_SCALE_GUARD, LOG_SCALE_GUARD))

    def placement(self, x: NDArray[np.float64]) -> Placement:
        """The candidate's pose for parameters ``x`` (support constraint applied)."""
        s = self.scales(x)
        off = 1 if self.uniform else 3
        a = rot_z(x[off]) @ self.r0
        tz = self.bottom_z + 0.5 * float(self.up_row @ (s * self.geom.size))
        t_center = np.array([x[off + 1], x[off + 2], tz])
        return Placement(a, t_center - a @ (s * self.geom.center), s)

    def start(self, scale: NDArray[np.float64], center_xy: NDArray[np.float64]) -> NDArray[np.float64]:
        ls = np.log(np.clip(scale, self.cfg.min_scale, self.cfg.max_scale))
        head = np.array([float(np.mean(ls))]) if self.uniform else ls
        return np.r_[head, 0.0, center_xy[0], center_xy[1]]

    def joint_values(self, x: NDArray[np.float64]) -> dict[str, float]:
        """Joint values at parameters ``x`` (clipped into the limits); the geometry's own without joints."""
        values = dict(self.geom.joint_values)
        for k, j in enumerate(self.joints):
            values[j.name] = j.clip(values.get(j.name, j.zero_value) + float(x[self.n_base + k]))
        return values

    # ------------------------------------------------------------------ derivatives of a posed point
    def _dq(self, m_centered: NDArray[np.float64], q_rel: NDArray[np.float64], s: NDArray[np.float64],
            a: NDArray[np.float64], conf: _Configuration | None = None,
            links: NDArray[np.int64] | None = None) -> NDArray[np.float64]:
        """d(posed point)/d(params): (N, 3, P) for model points ``m - c_m`` and ``q - t_center``.

        With joints, ``conf`` and ``links`` (the link each point is on) give the joint columns: a
        point on a part joint k moves moves by ``axis x (m - origin)`` (revolute) or ``axis``
        (prismatic) per unit of joint value, in the model frame, then scaled and rotated.
        """
        n = len(m_centered)
        cols = []
        # d/d log s_j: A[:, j] s_j (m_j - c_j) + e_z |R0[2, j]| s_j size_j / 2 (support constraint).
        dls = a[None, :, :] * (s * m_centered)[:, None, :]  # (N, 3, 3): column j
        dls[:, 2, :] += 0.5 * self.up_row * s * self.geom.size
        if self.uniform:
            cols.append(dls.sum(axis=2)[:, :, None])
        else:
            cols.append(dls)
        dyaw = np.stack([-q_rel[:, 1], q_rel[:, 0], np.zeros(n)], axis=1)
        cols.append(dyaw[:, :, None])
        ex = np.zeros((n, 3, 2))
        ex[:, 0, 0] = 1.0
        ex[:, 1, 1] = 1.0
        cols.append(ex)
        if self.kin is not None:
            assert conf is not None and links is not None
            m = m_centered + self.geom.center
            dj = np.zeros((n, 3, len(self.joints)))
            for k, j in enumerate(self.joints):
                on = self.kin.moves[k, links]
                if not np.any(on):
                    continue
                if j.type == "prismatic":
                    dm = np.broadcast_to(conf.axes[k], (int(on.sum()), 3))
                else:
                    dm = np.cross(conf.axes[k], m[on] - conf.origins[k])
                dj[on, :, k] = (dm * s) @ a.T
            cols.append(dj)
        return np.concatenate(cols, axis=2)

    def _point_terms(
        self, scene: o3d.t.geometry.RaycastingScene, p_model: NDArray[np.float64], s: NDArray[np.float64],
        a: NDArray[np.float64], t: NDArray[np.float64], subset: NDArray[np.int64] | None = None,
        conf: _Configuration | None = None, with_jac: bool = True,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
        """Signed map-frame distances of the points (``subset`` of them) to a surface given in the
        model frame (``p_model``: those points in the model frame), and d/dx (None without ``with_jac``)."""
        c_m = self.geom.center
        links = None
        if conf is not None:
            res = scene.compute_closest_points(o3c.Tensor(np.ascontiguousarray(p_model, dtype=np.float32)))
            cp = res["points"].numpy().astype(np.float64)
            cn = res["primitive_normals"].numpy().astype(np.float64)
            links = conf.face_link[res["primitive_ids"].numpy().astype(np.int64)]
        else:
            cp, cn = closest_points(scene, p_model)
        mc = cp - c_m
        q = (mc * s) @ a.T + t
        nq = (cn / s) @ a.T
        nq /= np.maximum(np.linalg.norm(nq, axis=1, keepdims=True), EPS)
        points = self.points if subset is None else self.points[subset]
        normals = self.point_normals if subset is None or self.point_normals is None else self.point_normals[subset]
        diff = points - q
        d = np.linalg.norm(diff, axis=1)
        sign = np.where(np.einsum("ij,ij->i", diff, nq) < 0.0, -1.0, 1.0)
        v = np.where((d > 1e-9)[:, None], diff * (sign / np.maximum(d, EPS))[:, None], nq)
        r = sign * d
        jac = -np.einsum("ni,nip->np", v, self._dq(mc, q - t, s, a, conf, links)) if with_jac else None
        if normals is not None:
            # Opposite normals: residual sqrt(d^2 + tau^2) (smooth, >= tau), pulling only weakly.
            wrong = np.einsum("ij,ij->i", nq, normals) < 0.0
            if np.any(wrong):
                rf = np.sqrt(d * d + self.tau * self.tau)
                if jac is not None:
                    jac = np.where(wrong[:, None], jac * (r / rf)[:, None], jac)
                r = np.where(wrong, rf, r)
        return r, jac

    def _evaluate(self, x: NDArray[np.float64], with_jac: bool = True
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
        """Residuals and (``with_jac``) their Jacobian at ``x``; the last evaluation is cached, as
        MINPACK asks for the Jacobian at the point whose residuals it just had. Scoring a start
        needs no Jacobian, which is about half the cost of an evaluation."""
        if self._cache_x is not None and np.array_equal(x, self._cache_x):
            assert self._cache is not None
            if self._cache[1] is not None or not with_jac:
                return self._cache
        s = self.scales(x)
        off = 1 if self.uniform else 3
        a = rot_z(x[off]) @ self.r0
        tz = self.bottom_z + 0.5 * float(self.up_row @ (s * self.geom.size))
        t = np.array([x[off + 1], x[off + 2], tz])
        c_m = self.geom.center
        conf = self.kin.at(self.joint_values(x)) if self.kin is not None else None
        # point -> CAD: map into the canonical frame, closest point there, map back (true distance).
        p_model = ((self.points - t) @ a) / s + c_m
        r, jac = self._point_terms(self.geom.scene if conf is None else conf.scene, p_model, s, a, t, conf=conf,
                                   with_jac=with_jac)
        far = np.flatnonzero(np.abs(r) > self.margin) if self.envelope else np.zeros(0, dtype=np.int64)
        if len(far):
            assert self.geom.envelope is not None
            # Explained by a moving part at another joint value: sqrt(d^2 + margin^2) (smooth, > margin),
            # so only points farther than the margin from the closed model need the envelope.
            r_e, jac_e = self._point_terms(self.geom.envelope, p_model[far], s, a, t, far, with_jac=with_jac)
            r_m = np.sqrt(r_e * r_e + self.margin * self.margin)
            use = r_m < np.abs(r[far])
            r[far] = np.where(use, r_m, r[far])
            if jac is not None and jac_e is not None:
                jac[far] = np.where(use[:, None], jac_e * (r_e / r_m)[:, None], jac[far])
        if self.robust:
            r, dr = soft_l1(r, self.tau)
            if jac is not None:
                jac = jac * dr[:, None]
        res_parts: list[NDArray[np.float64]] = [r]
        jac_parts: list[NDArray[np.float64]] = [] if jac is None else [jac]
        # CAD -> observed surfels (ours): normal and tangential-excess residuals per visible sample.
        if self.prepared is not None and len(self.samples):
            prep = self.prepared
            samples, sample_normals, sample_links = self.samples, self.sample_normals, None
            if conf is not None:  # the samples move with their links
                sample_links = self.geom.sample_links[self.sample_idx]
                rot, trans = conf.poses[sample_links, :3, :3], conf.poses[sample_links, :3, 3]
                samples = np.einsum("nij,nj->ni", rot, self.geom.link_samples[self.sample_idx]) + trans
                sample_normals = np.einsum("nij,nj->ni", rot, self.geom.link_normals[self.sample_idx])
            ms = samples - c_m
            y = (ms * s) @ a.T + t
            ny = (sample_normals / s) @ a.T
            ny /= np.maximum(np.linalg.norm(ny, axis=1, keepdims=True), EPS)
            if self.visible_mask is None:  # fixed for one fit: keeps the residual vector's meaning
                area = self.geom.sample_area * self.pool_count / max(len(ny), 1) * float(np.prod(s)) ** (2 / 3)
                # model surface whose front no camera observed is unseen, not missing (``alignment_error``)
                seeable = prep.obs.observed_in_front(y, ny) & ~hidden_by_loads(prep, y, ny, self.cfg)
                self.visible_mask = visible_samples(
                    ny, seeable, prep.bin_area, area, self.cfg.visible_min_coverage,
                    samples_map=y if self.face_reach is not None else None, face_area=prep.face_area,
                    face_reach=self.face_reach or 1,
                )
            vis = self.visible_mask
            w = self.sample_weight
            if np.any(vis):
                ys = y[vis]
                nn = nearest_surfel(prep, ys, ny[vis], k=4)
                o = prep.surfel_points[nn]
                no = prep.surfel_normals[nn]
                e = o - ys
                en = np.einsum("ij,ij->i", e, no)
                et = e - en[:, None] * no
                etn = np.linalg.norm(et, axis=1)
                g = np.maximum(etn - prep.surfel_radius, 0.0)
                rn, rg = en, g
                if self.robust:
                    rn, dn = soft_l1(rn, self.tau)
                    rg, dg = soft_l1(rg, self.tau)
                res_parts += [w * rn, w * rg]
                if with_jac:
                    dy = self._dq(ms[vis], ys - t, s, a, conf, None if sample_links is None else sample_links[vis])
                    j_n = -np.einsum("ni,nip->np", no, dy)
                    tdir = et / np.maximum(etn, EPS)[:, None]
                    j_g = -np.einsum("ni,nip->np", tdir, dy) * (g > 0.0)[:, None]
                    if self.robust:
                        j_n, j_g = j_n * dn[:, None], j_g * dg[:, None]
                    jac_parts += [w * j_n, w * j_g]
            else:
                res_parts.append(np.zeros(2 * len(vis)))
                jac_parts.append(np.zeros((2 * len(vis), len(x))))
        if self.height_target is not None and self.height_w > 0.0:
            hs = self.up_row * s * self.geom.size
            res_parts.append(np.array([self.height_w * (hs.sum() - self.height_target)]))
            jh = np.zeros((1, len(x)))
            if self.uniform:
                jh[0, 0] = self.height_w * hs.sum()
            else:
                jh[0, :3] = self.height_w * hs
            jac_parts.append(jh)
        if self.round_w > 0.0 and not self.uniform:
            i, j = self.horizontal_axes
            res_parts.append(np.array([self.round_w * (x[i] - x[j])]))
            jr = np.zeros((1, len(x)))
            jr[0, i], jr[0, j] = self.round_w, -self.round_w
            jac_parts.append(jr)
        if self.aniso > 0.0 and not self.uniform:
            ls = x[:3]
            res_parts.append(self.aniso * (ls - ls.mean()))
            ja = np.zeros((3, len(x)))
            ja[:, :3] = self.aniso * (np.eye(3) - 1.0 / 3.0)
            jac_parts.append(ja)
        out = (np.concatenate(res_parts), np.concatenate(jac_parts, axis=0) if with_jac else None)
        self._cache_x = x.copy()
        self._cache = out
        return out

    def score(self, x: NDArray[np.float64]) -> float:
        """Two-sided robust RMS at ``x``, as the AE: over the points and the *visible* samples.

        Dividing by the visible samples only (not by all drawn ones) keeps a hypothesis that
        shows no face to the observed directions from looking good for having nothing to check.
        """
        r = self._evaluate(x, with_jac=False)[0]
        n = len(self.points)
        total = float(np.sum(r[:n] ** 2))
        count = n
        nv = int(np.count_nonzero(self.visible_mask)) if self.visible_mask is not None else 0
        if self.prepared is not None and nv > 0:
            total += float(np.sum(r[n : n + 2 * nv] ** 2)) / self.sample_weight**2
            count += nv
        return float(np.sqrt(total / max(count, 1)))

    def residuals(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        return self._evaluate(x)[0]

    def jacobian(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        jac = self._evaluate(x)[1]
        assert jac is not None
        return jac

    def solve(self, x0: NDArray[np.float64], max_nfev: int) -> tuple[NDArray[np.float64], float, int]:
        """Levenberg-Marquardt from ``x0``; returns parameters (scales clipped), cost and evaluations."""
        n_res = len(self.residuals(x0))
        if n_res < len(x0):  # MINPACK needs at least as many residuals as parameters
            return x0, float(0.5 * np.sum(self.residuals(x0) ** 2)), 1
        sol = least_squares(
            self.residuals, x0, jac=self.jacobian, method="lm", max_nfev=max(int(max_nfev), len(x0) + 1),
            x_scale="jac", ftol=self.cfg.fit_ftol,
        )
        x = sol.x.copy()
        k = 1 if self.uniform else 3
        lo, hi = np.log(self.cfg.min_scale), np.log(self.cfg.max_scale)
        x[:k] = np.clip(x[:k], lo, hi)
        if not np.all(np.isfinite(x)):
            x = x0.copy()
        return x, float(sol.cost), int(sol.nfev)


# ---------------------------------------------------------------------------------------------------------
# box start and alignment error


def box_start_scale(
    box: GravityBox, geom: ModelGeometry, box_rotation: NDArray[np.float64], bottom_z: float, clip: float = 1.5
) -> NDArray[np.float64]:
    """Feature-only start (box to box): per model axis, observed box extent / model extent.

    The vertical extent is measured from the support height (the bottom is often unseen); the
    horizontal ratios are clipped to ``clip`` times the vertical one either way, because a partial
    view shortens the unseen depth rather than revealing a model 3x too thin.
    """
    size_box = np.array([box.size[0], box.size[1], max(box.z_max - bottom_z, 1e-3)])
    obs_along_model = np.abs(box_rotation).T @ size_box
    ratio = obs_along_model / geom.size
    up_axis = int(np.argmax(np.abs(box_rotation[2])))
    s_up = ratio[up_axis]
    return np.clip(ratio, s_up / clip, s_up * clip)


def box_start(
    box: GravityBox, geom: ModelGeometry, box_rotation: NDArray[np.float64], bottom_z: float, clip: float = 1.5
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Start scale and model box centre (xy) of a candidate from the observed box.

    ``box_start_scale`` and the box centre, except for articulated models: their doors open and
    their drawers slide towards the model front (+x), so an open part inflates the observed box on
    that side only. There the depth ratio is capped at the larger of the lateral and vertical
    ratios (the model's own proportions) and the model is put against the box's back, whose side
    no moving part can move.
    """
    scale = box_start_scale(box, geom, box_rotation, bottom_z, clip)
    center = np.asarray(box.center[:2], dtype=np.float64).copy()
    if not geom.articulated_model:
        return scale, center
    k = int(np.argmax(np.abs(box_rotation[:, 0])))  # box axis the model front lies along
    if k == 2:  # lying on its back: the vertical extent is fixed by the support anyway
        return scale, center
    cap = max(float(scale[1]), float(scale[2]))
    if scale[0] <= cap:
        return scale, center
    shift = 0.5 * (scale[0] - cap) * float(geom.size[0])
    front = rot_z(box.yaw)[:2, k] * float(np.sign(box_rotation[k, 0]))
    scale = scale.copy()
    scale[0] = cap
    return scale, center - shift * front


@dataclass(frozen=True)
class AlignmentError:
    """AE terms (m): ``ae`` two-sided RMS, ``ae_points`` observed -> CAD (the paper's AE, Sec. 4.3),
    ``ae_model`` CAD -> observed; ``visible_fraction`` of the CAD samples counted in ``ae_model``.

    Coverage (``acceptance``): ``coverage`` is the share of the CAD samples counted in ``ae_model``
    that lie within ``cfg.coverage_distance`` of an observed surfel; ``view_coverage`` the same
    share of every CAD sample a camera along the observation's viewing direction would see (not
    only the sides the observation covers: an oversized model whose front is four times the
    observed front does not escape it). With an observed-space grid a sample in unknown space counts
    at a distance of at most ``cfg.unknown_surface_m`` (covered, at the default 1 cm);
    ``observed_share`` is the share of the samples in view that lie in observed space (1 without a
    grid). NaN when no sample counts."""

    ae: float
    ae_points: float
    ae_model: float
    visible_fraction: float
    coverage: float = float("nan")
    view_coverage: float = float("nan")
    observed_share: float = float("nan")


#: Log-scales beyond this (a factor of about 5e8) are clipped inside the fit (``AlignmentProblem.scales``).
LOG_SCALE_GUARD = 20.0
#: Where a nearest-surfel query puts a point that is not finite (m).
FAR_M = 1e9
#: Cosine above which an observed surfel's normal is compatible with a CAD sample's normal.
SURFEL_NORMAL_COS = 0.3


def _surfel_gap(
    prepared: PreparedObservation, y: NDArray[np.float64], nn: NDArray[np.int64]
) -> NDArray[np.float64]:
    """Distance of ``y`` (..., 3) to the surfels ``nn`` (...): normal offset and tangential excess."""
    e = prepared.surfel_points[nn] - y
    no = prepared.surfel_normals[nn]
    en = np.einsum("...j,...j->...", e, no)
    et = np.linalg.norm(e - en[..., None] * no, axis=-1)
    g = np.maximum(et - prepared.surfel_radius, 0.0)
    return np.sqrt(en * en + g * g)


def _surfel_neighbours(prepared: PreparedObservation, y: NDArray[np.float64], k: int) -> NDArray[np.int64]:
    """Indices of the ``k`` observed surfels nearest to each point of ``y`` (shape (n,) for k = 1, else (n, k)).

    A point far out (a wild trial step of the fit) may have no neighbour, which the tree answers with n (one
    past the end), and one that is not finite the tree refuses: such points are queried as far points and
    every index is clamped into the surfels."""
    _, nn = prepared.tree.query(np.nan_to_num(y, nan=FAR_M, posinf=FAR_M, neginf=-FAR_M), k=k)
    return np.minimum(np.asarray(nn, np.int64), len(prepared.surfel_points) - 1)


def nearest_surfel(
    prepared: PreparedObservation, y: NDArray[np.float64], normals: NDArray[np.float64], k: int = 4
) -> NDArray[np.int64]:
    """Index of the closest observed surfel among the ``k`` nearest points whose normal agrees.

    Plain nearest neighbours confuse the two faces of thin parts (a door's front sample finds a
    point on the door's back); requiring compatible normals removes that bias. Falls back to the
    nearest point when no neighbour is compatible.
    """
    k = max(1, min(k, len(prepared.surfel_points)))
    nn = _surfel_neighbours(prepared, y, k).reshape(len(y), k)
    gap = _surfel_gap(prepared, y[:, None, :], nn)
    compat = np.einsum("nkj,nj->nk", prepared.surfel_normals[nn], normals) > SURFEL_NORMAL_COS
    gap = np.where(compat, gap, np.inf)
    best = np.argmin(gap, axis=1)
    pick = nn[np.arange(len(y)), best]
    return np.where(np.isfinite(gap.min(axis=1)), pick, nn[:, 0])


def surfel_distance(
    prepared: PreparedObservation, y: NDArray[np.float64], normals: NDArray[np.float64] | None = None
) -> NDArray[np.float64]:
    """Distance of points ``y`` to the nearest compatible observed surfel (disk of the sampling radius)."""
    if len(y) == 0:
        return np.zeros(0)
    nn = nearest_surfel(prepared, y, normals, k=8) if normals is not None else _surfel_neighbours(prepared, y, 1)
    e = prepared.surfel_points[nn] - y
    no = prepared.surfel_normals[nn]
    en = np.einsum("ij,ij->i", e, no)
    et = np.linalg.norm(e - en[:, None] * no, axis=1)
    has_n = np.linalg.norm(no, axis=1) > 0.5
    g = np.maximum(et - prepared.surfel_radius, 0.0)
    d_surfel = np.sqrt(en * en + g * g)
    d_point = np.maximum(np.linalg.norm(e, axis=1) - prepared.surfel_radius, 0.0)
    return np.where(has_n, d_surfel, d_point)


def hidden_by_loads(prepared: PreparedObservation, samples_map: NDArray[np.float64], normals_map: NDArray[np.float64],
                    cfg: CadReplacementConfig) -> NDArray[np.bool_]:
    """Ours: CAD samples on a top hidden by what the object carries (``ObjectObservation.hidden_by_loads``):
    unseen, like the back of an object, so neither the fits nor the AE count them as missing."""
    if cfg.method != "ours":
        return np.zeros(len(samples_map), dtype=bool)
    return prepared.obs.hidden_by_loads(samples_map, normals_map, cfg.load_shadow_elevation_deg)


def alignment_error(
    prepared: PreparedObservation,
    scene: o3d.t.geometry.RaycastingScene,
    samples_map: NDArray[np.float64],
    normals_map: NDArray[np.float64],
    self_visible: NDArray[np.bool_],
    cfg: CadReplacementConfig,
    sample_area: float,
) -> AlignmentError:
    """AE of a posed CAD (``scene`` in the map frame, its samples/normals in the map frame).

    Observed -> CAD: distance of every AE point to the posed surface. CAD -> observed: distance of
    the CAD samples the observation could have seen (``visible_samples``) to the nearest observed
    surfel. AE is the RMS over both sets; never NaN (an empty direction contributes nothing).
    """
    pts = prepared.points
    self_visible = self_visible & ~hidden_by_loads(prepared, samples_map, normals_map, cfg)
    vis = visible_samples(
        normals_map, self_visible, prepared.bin_area, sample_area, cfg.visible_min_coverage,
        samples_map=samples_map, face_area=prepared.face_area,
    )
    # In view (coverage): every self-visible sample a camera along the viewing direction would see.
    in_view = self_visible.copy()
    if prepared.view_dir is not None and np.any(in_view):
        # Partial view: keep samples an orthographic camera along the viewing direction would see
        # (rays from far away towards the sample must reach it first), so occluded back legs or
        # a shelf's inside are not counted as missing data.
        v = prepared.view_dir
        idx = np.flatnonzero(in_view)
        facing = normals_map[idx] @ v > 0.0
        origins = samples_map[idx] + VIEW_DISTANCE * v
        rays = np.c_[origins, np.broadcast_to(-v, origins.shape)].astype(np.float32)
        t_hit = scene.cast_rays(o3c.Tensor(rays))["t_hit"].numpy()
        seen = facing & (t_hit >= VIEW_DISTANCE - 5e-3)
        in_view[idx[~seen]] = False
        vis = vis & in_view
    # Model surface in space no camera observed (an unseen far half, behind the object) is not missing
    # data: nothing says it is absent. It costs at most ``unknown_surface_m`` each, not its distance
    # to the observed surface, so of two models that explain the observation alike the one that puts
    # less surface where nobody looked still wins (``ObjectObservation.observed_space``). A sample is
    # judged by the space in front of it (``ObjectObservation.observed_in_front``).
    observed = prepared.obs.observed_in_front(samples_map[in_view], normals_map[in_view])
    known_share = float(np.mean(observed)) if len(observed) else float("nan")
    d_obs = scene.compute_distance(o3c.Tensor(pts.astype(np.float32))).numpy().astype(np.float64)
    d_view = surfel_distance(prepared, samples_map[in_view], normals_map[in_view])
    d_view = np.where(observed, d_view, np.minimum(d_view, cfg.unknown_surface_m))
    d_mod = d_view[vis[in_view]]
    both = np.concatenate([d_obs, d_mod])
    rms = lambda v: float(np.sqrt(np.mean(v * v))) if len(v) else 0.0  # noqa: E731
    near = lambda v: float(np.mean(v <= cfg.coverage_distance)) if len(v) else float("nan")  # noqa: E731
    return AlignmentError(rms(both), rms(d_obs), rms(d_mod), float(vis.mean()) if len(vis) else 0.0,
                          near(d_mod), near(d_view), known_share)


def posed_scene(mesh: trimesh.Trimesh, placement: Placement) -> o3d.t.geometry.RaycastingScene:
    """Raycasting scene of a model mesh (model frame) moved by a placement."""
    moved = trimesh.Trimesh(placement.apply(np.asarray(mesh.vertices, dtype=np.float64)), mesh.faces, process=False)
    return raycasting_scene(moved)


def map_normals(normals: NDArray[np.float64], placement: Placement) -> NDArray[np.float64]:
    """Normals of model-frame surfaces after the (anisotropic) placement: R (n / s), renormalised."""
    n = (normals / placement.scale) @ placement.rotation.T
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), EPS)


__all__ = [
    "AlignmentError",
    "AlignmentProblem",
    "FaceAreas",
    "ModelGeometry",
    "Placement",
    "PreparedObservation",
    "alignment_error",
    "box_start",
    "box_start_scale",
    "closest_points",
    "direction_bin",
    "estimate_normals",
    "face_keys",
    "map_normals",
    "nearest_surfel",
    "observed_area_per_bin",
    "posed_scene",
    "raycasting_scene",
    "rot_z",
    "soft_l1",
    "surfel_distance",
    "visible_samples",
]
