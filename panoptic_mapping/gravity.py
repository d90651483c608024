"""Gravity from depth: which way is up in a recording's world frame, and the rotation that aligns it.

Every stage assumes a gravity-aligned map frame with z up (``recon_core.geometry.gravity``), but
real recordings often are not: the 7-Scenes kitchen frames of andyzeng/tsdf-fusion-python have their
"up" 116.8 deg from +z (docs/REAL_DATA.md). This
module estimates up from the depth images themselves (ROS-free, numpy + OpenCV):

1. per frame, surface normals of the depth image (box-smoothed central differences, kept only
   where the surface is locally planar), rotated into the world frame by the camera pose and
   weighted by the surface area a sample stands for (~ depth^2);
2. the dominant normal directions (area-weighted modes on the sphere, ``_modes``): the floor,
   table tops and the ceiling give one or two horizontal directions, walls the vertical ones;
3. candidates for up: a horizontal mode (normals face the camera, so a floor's normal *is* up and
   a ceiling's is down) or the cross product of two wall directions, each within ``max_tilt_deg``
   of the cameras' mean image "up" (-y of the optical frame: cameras are held roughly upright), or
   within ``max_pitch_deg`` of it when every camera's image x axis is horizontal to it (no roll:
   a camera looking steeply down at a desk); a lone plane is only trusted as a floor;
   each candidate is scored by the area of the modes it explains (parallel or perpendicular to
   it: a Manhattan room), the best one wins;
4. a least-squares refinement: up is the direction most parallel to the horizontal normals and
   most perpendicular to the vertical ones (smallest eigenvector, ``_refine``).

Nothing horizontal and fewer than two wall directions (one wall filling the view, a close-up of
an object) give no estimate: ``GravityEstimate.ok`` is False, the caller keeps the input's +z and
warns. ``alignment_from_estimate`` turns an estimate into the 4x4 transform world -> gravity
aligned map frame (the smallest rotation taking up to +z, so yaw is kept), or the identity when
up is within ``min_correction_deg`` of +z: generated scenes (exactly z up) are never rotated by
estimation noise.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from panoptic_mapping.depth_segmentation import backproject, estimate_normals
from panoptic_mapping.image_ops import downsample_depth
from recon_core.config import Settings, setting
from recon_core.errors import InputError
from recon_core.frame import CameraIntrinsics

log = logging.getLogger(__name__)

Z_UP = np.array([0.0, 0.0, 1.0])
#: Image "up" of the optical frame (x right, y down, z forward).
IMAGE_UP = np.array([0.0, -1.0, 0.0])
GRAVITY_MODES = ("auto", "z")


@dataclass
class GravityConfig(Settings):
    """How the map frame's up is found (`scene-recon map --gravity`)."""

    #: auto: estimate up from the depth data; z: trust the input (its +z is up); else the path of a
    #: text file holding a 4x4 (or 3x3) transform from the input's world frame to a z-up frame.
    mode: str = "auto"
    #: auto: frames read for the estimate: at most this many posed frames, every `stride`-th one
    #: from the start of the recording (on top of the data input's own start/stride).
    window_frames: int = setting(30, min=1)
    stride: int = setting(5, min=1)
    #: Depth images are block-averaged by this factor before the normals (speed, noise).
    downsample: int = setting(2, min=1)
    #: Normal samples kept per frame (random, seeded).
    samples_per_frame: int = setting(3000, min=100)
    #: Readings beyond this depth (m) are too noisy for normals.
    max_depth_m: float = setting(5.0, min=0.0, min_exclusive=True)
    #: Half-angle (deg) of a normal mode; modes lighter than min_mode_share of all area are noise.
    mode_cone_deg: float = setting(8.0, min=1.0, max=30.0)
    min_mode_share: float = setting(0.03, min=0.0, max=1.0)
    #: A horizontal plane (floor, ceiling, table tops) or each of two walls must hold this share.
    min_plane_share: float = setting(0.05, min=0.0, max=1.0)
    #: Up is at most this far (deg) from the cameras' mean image up (-y).
    max_tilt_deg: float = setting(60.0, min=5.0, max=89.0)
    #: ... or, for cameras pitched steeply down (a desk seen from above), at most max_pitch_deg from it
    #: when the cameras' image x axes stay within max_roll_deg (rms) of horizontal (no roll).
    max_pitch_deg: float = setting(80.0, min=5.0, max=89.0)
    max_roll_deg: float = setting(20.0, min=1.0, max=60.0)
    #: Modes within this angle (deg) of parallel / perpendicular to up count as explained by it.
    manhattan_tol_deg: float = setting(10.0, min=1.0, max=30.0)
    #: An estimate within this angle (deg) of +z is not applied: the input is taken as z up.
    min_correction_deg: float = setting(1.0, min=0.0, max=90.0)
    #: Warn when the input's up is farther than this (deg) from +z.
    warn_deg: float = setting(5.0, min=0.0, max=180.0)
    #: auto, refined as the map grows: every `refine_every_n`-th frame integrated after the window
    #: adds its normals to the window's (0: off). The map cannot turn under way (its voxels are laid
    #: out in the frame chosen first), so the whole recording's estimate is a check: written to
    #: map.json (gravity.refined), and when it differs from the applied up by more than
    #: `refine_warn_deg` a warning and OUT/gravity_refined.txt (pass it with --gravity to map again).
    refine_every_n: int = setting(30, min=0)
    #: z: still estimate up from the window and warn past `warn_deg` (the input is not rotated).
    check_z: bool = True
    refine_warn_deg: float = setting(2.0, min=0.0, max=180.0)
    #: IMU check (the mapper node's `imu_topic`): accelerometer readings averaged for the estimate,
    #: how far (m/s^2) their mean may be from standard gravity (farther: the platform accelerated, or
    #: the units are not m/s^2), and the median angle (deg) of single readings from the mean beyond
    #: which the platform was shaking too much to tell up.
    imu_samples: int = setting(100, min=1)
    imu_max_g_error: float = setting(1.0, min=0.0, min_exclusive=True)
    imu_max_spread_deg: float = setting(10.0, min=0.0, min_exclusive=True, max=90.0)
    seed: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.mode:
            self.mode = "auto"


@dataclass
class GravityEstimate:
    """Up of the input's world frame as estimated from depth (``ok`` False: no estimate)."""

    up: np.ndarray
    ok: bool
    #: floor (a horizontal plane facing up), ceiling (facing down) or walls (two wall directions).
    method: str
    #: Why there is no estimate (``ok`` False), else "".
    reason: str = ""
    #: Area-weighted share of the normals the chosen up explains (parallel or perpendicular to it).
    support: float = 0.0
    #: The cameras' mean image up (-y of the optical frame) in the world frame.
    camera_up: np.ndarray = field(default_factory=lambda: Z_UP.copy())
    frames: int = 0
    samples: int = 0
    modes: list[tuple[list[float], float]] = field(default_factory=list)

    @property
    def angle_deg(self) -> float:
        """Angle between the estimated up and the input's +z."""
        return angle_deg(self.up, Z_UP)

    def as_dict(self) -> dict[str, Any]:
        return {"ok": self.ok, "method": self.method, "reason": self.reason,
                "up_in_input": [round(float(v), 6) for v in self.up], "angle_from_z_deg": round(self.angle_deg, 3),
                "support": round(self.support, 3), "frames": self.frames, "samples": self.samples,
                "camera_up_in_input": [round(float(v), 4) for v in self.camera_up]}


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    c = float(a @ b / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-12))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def rotation_to_z(up: np.ndarray) -> np.ndarray:
    """The smallest rotation (3x3) taking the unit vector ``up`` to +z (Rodrigues)."""
    v = np.asarray(up, float).reshape(3)
    n = float(np.linalg.norm(v))
    if not np.isfinite(n) or n < 1e-12:  # a zero or non-finite up has no direction: refuse, never NaN
        raise ValueError(f"up must be a finite non-zero 3-vector, got {v.tolist()}")
    u = v / n
    axis = np.cross(u, Z_UP)
    s, c = float(np.linalg.norm(axis)), float(u @ Z_UP)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = axis / s
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * kx + (1 - c) * kx @ kx


def frame_normals(depth: np.ndarray, intrinsics: CameraIntrinsics, cfg: GravityConfig,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame unit normals (facing the camera) of a depth image's locally planar pixels and
    the surface area (m^2) each sample stands for; at most ``cfg.samples_per_frame`` samples."""
    ds = cfg.downsample
    d = np.asarray(downsample_depth(np.asarray(depth, np.float32), ds), np.float32)
    d = np.where((d > 0) & (d <= cfg.max_depth_m) & np.isfinite(d), d, 0.0).astype(np.float32)
    intr = intrinsics if ds == 1 else intrinsics.scaled(1.0 / ds)
    valid = d > 0
    if valid.sum() < 50:
        return np.zeros((0, 3)), np.zeros(0)
    pts = backproject(d, intr)
    normals = estimate_normals(pts, valid, step=2, smoothing=2)
    ok = np.linalg.norm(normals, axis=2) > 0.5
    # locally planar: the normal agrees with its neighbours' 4 px away (rejects edges and corners)
    for dy, dx in ((4, 0), (0, 4)):
        a = normals[dy:, dx:] if dy or dx else normals
        b = normals[: normals.shape[0] - dy, : normals.shape[1] - dx]
        agree = np.einsum("ijk,ijk->ij", a, b) > np.cos(np.radians(5.0))
        sub = np.zeros_like(ok)
        sub[: ok.shape[0] - dy, : ok.shape[1] - dx] = agree
        ok &= sub
    ys, xs = np.nonzero(ok)
    if len(ys) == 0:
        return np.zeros((0, 3)), np.zeros(0)
    if len(ys) > cfg.samples_per_frame:
        pick = rng.choice(len(ys), cfg.samples_per_frame, replace=False)
        ys, xs = ys[pick], xs[pick]
        scale = ok.sum() / cfg.samples_per_frame
    else:
        scale = 1.0
    n = normals[ys, xs].astype(np.float64)
    z = d[ys, xs].astype(np.float64)
    area = z * z / (intr.fx * intr.fy) * scale
    return n, area


def _modes(normals: np.ndarray, weights: np.ndarray, cone_deg: float, min_share: float, max_modes: int = 10,
           seed: int = 0) -> list[tuple[np.ndarray, float]]:
    """Dominant directions: (unit direction, area) of the heaviest area-weighted cones, heaviest first."""
    total = float(weights.sum())
    if total <= 0 or len(normals) == 0:
        return []
    rng = np.random.default_rng(seed)
    cos_in = np.cos(np.radians(cone_deg))
    cos_out = np.cos(np.radians(2 * cone_deg))
    nf = normals.astype(np.float32)
    remaining = np.ones(len(normals), bool)
    out: list[tuple[np.ndarray, float]] = []
    for _ in range(max_modes):
        idx = np.flatnonzero(remaining)
        w = weights[idx]
        if w.sum() < min_share * total or len(idx) == 0:
            break
        k = min(128, len(idx))
        cand = idx[rng.choice(len(idx), k, replace=False, p=w / w.sum())]
        scores = ((nf[idx] @ nf[cand].T) > cos_in).T.astype(np.float32) @ w.astype(np.float32)
        d = normals[cand[int(np.argmax(scores))]].copy()
        for _it in range(6):  # mean shift on the sphere
            near = idx[normals[idx] @ d > cos_in]
            m = (normals[near] * weights[near, None]).sum(axis=0)
            if np.linalg.norm(m) < 1e-12:
                break
            d = m / np.linalg.norm(m)
        inside = normals[idx] @ d > cos_in
        area = float(w[inside].sum())
        remaining[idx[normals[idx] @ d > cos_out]] = False
        if area < min_share * total:
            continue
        out.append((d, area))
    out.sort(key=lambda m: -m[1])
    return out


def _refine(up: np.ndarray, normals: np.ndarray, weights: np.ndarray, tol_deg: float) -> np.ndarray:
    """Least squares: the unit u most parallel to the near-horizontal-plane normals (|n.u| ~ 1) and
    most perpendicular to the near-vertical ones (n.u ~ 0): the smallest eigenvector of
    sum_v w n n^T - sum_h w n n^T. Three rounds (the sets are re-chosen around each new u)."""
    u = up.copy()
    cos_tol, sin_tol = np.cos(np.radians(tol_deg)), np.sin(np.radians(tol_deg))
    for _ in range(3):
        c = normals @ u
        horiz, vert = np.abs(c) > cos_tol, np.abs(c) < sin_tol
        if not horiz.any():
            break
        m = (normals[vert] * weights[vert, None]).T @ normals[vert]
        m -= (normals[horiz] * weights[horiz, None]).T @ normals[horiz]
        _vals, vecs = np.linalg.eigh(m)
        v = vecs[:, 0]
        v = v if v @ u > 0 else -v
        if angle_deg(v, up) > tol_deg:  # refinement must not jump to another direction
            break
        u = v
    return u


class GravityEstimator:
    """Accumulate posed depth frames (``add_frame``), then ``estimate()`` the world's up."""

    def __init__(self, cfg: GravityConfig | None = None) -> None:
        self.cfg = cfg or GravityConfig()
        self._rng = np.random.default_rng(self.cfg.seed)
        self._normals: list[np.ndarray] = []
        self._weights: list[np.ndarray] = []
        self._camera_up = np.zeros(3)
        self._camera_x: list[np.ndarray] = []
        self.frames = 0

    def add_frame(self, depth: np.ndarray, intrinsics: CameraIntrinsics, pose: np.ndarray) -> int:
        """Add one frame (camera-to-world ``pose``); returns the normal samples it gave."""
        rot = np.asarray(pose, float)[:3, :3]
        n, w = frame_normals(depth, intrinsics, self.cfg, self._rng)
        self._camera_up += rot @ IMAGE_UP
        self._camera_x.append(rot[:, 0])
        self.frames += 1
        if len(n):
            self._normals.append(n @ rot.T)
            self._weights.append(w)
        return len(n)

    def estimate(self) -> GravityEstimate:
        cfg = self.cfg
        norm = float(np.linalg.norm(self._camera_up))
        cam_up = self._camera_up / norm if self.frames and norm > 1e-12 else Z_UP.copy()
        if not self._normals:
            return GravityEstimate(Z_UP.copy(), False, "none", "no valid depth in the frames read", 0.0, cam_up,
                                   self.frames)
        normals = np.concatenate(self._normals)
        weights = np.concatenate(self._weights)
        total = float(weights.sum())
        modes = _modes(normals, weights, cfg.mode_cone_deg, cfg.min_mode_share, seed=cfg.seed)
        info = [([round(float(v), 4) for v in d], round(a / total, 4)) for d, a in modes]
        base = GravityEstimate(Z_UP.copy(), False, "none", "", 0.0, cam_up, self.frames, len(normals), info)
        cos_tilt, cos_pitch = np.cos(np.radians(cfg.max_tilt_deg)), np.cos(np.radians(cfg.max_pitch_deg))
        xs = np.asarray(self._camera_x).reshape(-1, 3)
        sin_roll = np.sin(np.radians(cfg.max_roll_deg))

        def upright(u: np.ndarray) -> bool:
            """u is up for cameras held upright: near their image up, or pitched but not rolled."""
            c = float(u @ cam_up)
            return c >= cos_tilt or (c >= cos_pitch and float(np.sqrt(np.mean((xs @ u) ** 2))) < sin_roll)

        min_area = cfg.min_plane_share * total
        candidates: list[tuple[float, float, np.ndarray, str]] = []  # (score, -angle to hint, up, method)
        for d, a in modes:
            if a < min_area:
                continue
            for sign, method in ((1.0, "floor"), (-1.0, "ceiling")):
                u = sign * d
                score = self._explained(u, modes)
                # a lone plane is trusted as a floor only: a wall ahead of a camera pitched down looks
                # like a ceiling, a floor under it never like anything else
                if method == "ceiling" and score <= a * (1 + 1e-9):
                    continue
                if upright(u):
                    candidates.append((score, -angle_deg(u, cam_up), u, method))
        for i, (di, ai) in enumerate(modes):
            for dj, aj in modes[i + 1:]:
                if min(ai, aj) < min_area:
                    continue
                c = np.cross(di, dj)
                if np.linalg.norm(c) < np.sin(np.radians(30.0)):  # (anti)parallel walls give no up
                    continue
                u = c / np.linalg.norm(c)
                u = u if u @ cam_up > 0 else -u
                if upright(u):
                    candidates.append((self._explained(u, modes), -angle_deg(u, cam_up), u, "walls"))
        if not candidates:
            base.reason = ("no horizontal plane (floor, table, ceiling) and fewer than two wall directions seen "
                           f"within {cfg.max_tilt_deg:.0f} deg of the cameras' image up (or {cfg.max_pitch_deg:.0f} "
                           "deg for cameras without roll)")
            return base
        # most area explained (to 1 % of all area) first; then a floor over a ceiling over two walls (the
        # refinement below uses every plane anyway), then the candidate nearest the cameras' image up
        pref = {"floor": 2, "ceiling": 1, "walls": 0}
        candidates.sort(key=lambda c: (round(c[0] / total, 2), pref[c[3]], c[1]), reverse=True)
        _score, _neg, up, method = candidates[0]
        up = _refine(up, normals, weights, cfg.manhattan_tol_deg)
        c = normals @ up
        tol = np.radians(cfg.manhattan_tol_deg)
        explained = (np.abs(c) > np.cos(tol)) | (np.abs(c) < np.sin(tol))
        base.up, base.ok, base.method = up, True, method
        base.support = float(weights[explained].sum() / total)
        return base

    def _explained(self, u: np.ndarray, modes: list[tuple[np.ndarray, float]]) -> float:
        """Area of the modes parallel or perpendicular to ``u`` (within the Manhattan tolerance)."""
        tol = np.radians(self.cfg.manhattan_tol_deg)
        return float(sum(a for d, a in modes if abs(d @ u) > np.cos(tol) or abs(d @ u) < np.sin(tol)))


def estimate_up(frames: list[tuple[np.ndarray, CameraIntrinsics, np.ndarray]],
                cfg: GravityConfig | None = None) -> GravityEstimate:
    """Up of the world frame from (depth, intrinsics, camera-to-world pose) triples."""
    est = GravityEstimator(cfg)
    for depth, intr, pose in frames:
        est.add_frame(depth, intr, pose)
    return est.estimate()


class GravityMonitor:
    """Up of a live stream's fixed frame from its first frames, for mappers that cannot rotate their
    input (the ROS mapper node trusts its TF `map` frame): every ``cfg.stride``-th posed frame
    ``feed`` gets is added until ``cfg.window_frames`` are in, then the estimate is returned once
    (``None`` before and after). What it says goes into the map's ``gravity`` record; ``warning`` is
    set when the frame's +z is more than ``cfg.warn_deg`` from the estimated up."""

    def __init__(self, cfg: GravityConfig | None = None) -> None:
        self.cfg = cfg or GravityConfig()
        self.estimator: GravityEstimator | None = GravityEstimator(self.cfg)
        self.seen = 0
        self.result: GravityEstimate | None = None
        self.warning = ""

    @property
    def done(self) -> bool:
        return self.estimator is None

    def feed(self, depth: np.ndarray, intrinsics: CameraIntrinsics, pose: np.ndarray | None) -> GravityEstimate | None:
        est = self.estimator
        if est is None or pose is None:
            return None
        self.seen += 1
        if (self.seen - 1) % self.cfg.stride:
            return None
        est.add_frame(depth, intrinsics, pose)
        if est.frames < self.cfg.window_frames:
            return None
        return self.finish()

    def finish(self) -> GravityEstimate | None:
        """End the window now (a short stream, a stream that paused): the estimate from the frames read
        so far becomes the verdict. ``None`` when it was already given or no posed frame was read."""
        est = self.estimator
        if est is None or est.frames == 0:
            return None
        self.result = est.estimate()
        self.estimator = None
        self.warning = self._warning_for(self.result)
        return self.result

    def record(self) -> dict[str, Any]:
        """The map's ``gravity`` record: the frame is trusted (nothing applied), the check's estimate.

        Asked before the window is full (a save or an extraction early in the stream, a short bag, or
        frames lost under load) it reports a provisional estimate from the frames read so far and
        keeps collecting: a map saved from a short stream still says whether its +z is up."""
        out: dict[str, Any] = {"mode": "tf", "applied": False, "rotation_deg": 0.0, "input_up": [0.0, 0.0, 1.0]}
        result, provisional = self.result, False
        if result is None and self.estimator is not None:
            if self.estimator.frames == 0:
                out["note"] = "gravity check: no posed frame read yet"
                return out
            result, provisional = self.estimator.estimate(), True
        if result is not None:
            out["estimate"] = result.as_dict()
            out["provisional"] = provisional
            warning = self.warning or self._warning_for(result)
            out["note"] = (warning or (f"gravity check: the fixed frame's +z is up (estimate "
                                       f"{result.angle_deg:.1f} deg from it)" if result.ok
                                       else f"gravity check: no estimate ({result.reason})"))
            if provisional:
                out["note"] += f" [provisional: {result.frames} of {self.cfg.window_frames} frames read]"
        return out

    def _warning_for(self, result: GravityEstimate) -> str:
        if not (result.ok and result.angle_deg > self.cfg.warn_deg):
            return ""
        return (f"the fixed frame's up is {result.angle_deg:.1f} deg from its +z (estimated from "
                f"the {result.method} over {result.frames} frames): the map, its boxes, "
                "planes and supports assume +z up; make the fixed frame gravity aligned (TF from an "
                "IMU or a corrected map frame)")


#: Standard gravity (m/s^2): what an accelerometer at rest reads, pointing up (the specific force).
STANDARD_GRAVITY = 9.80665


class AccelerometerCheck:
    """Up of a fixed frame from IMU accelerometer readings rotated into it.

    An accelerometer measures the specific force: at rest +g pointing up, plus whatever the platform
    accelerates by, which averages out over a window of a smoothly moving robot. ``add`` takes (N, 3)
    readings already expressed in the fixed frame (m/s^2; the caller rotates them with TF); the
    estimate is made once ``cfg.imu_samples`` readings are in, and refused (``ok`` False, with the
    reason) when their mean is not about g or single readings scatter too much. Non-finite readings
    are dropped (a driver's NaN must not reach the record)."""

    def __init__(self, cfg: GravityConfig | None = None) -> None:
        self.cfg = cfg or GravityConfig()
        self._sum = np.zeros(3)
        self._readings: list[np.ndarray] = []
        self.count = 0
        self.dropped = 0
        self.result: GravityEstimate | None = None

    @property
    def done(self) -> bool:
        return self.result is not None

    def add(self, readings: np.ndarray) -> GravityEstimate | None:
        """Add readings; returns the estimate when this call completes the window (else None)."""
        if self.result is not None:
            return None
        r = np.asarray(readings, np.float64).reshape(-1, 3)
        good = np.all(np.isfinite(r), axis=1)
        self.dropped += int((~good).sum())
        r = r[good]
        if len(r):
            self._readings.append(r)
            self.count += len(r)
        if self.count < self.cfg.imu_samples:
            return None
        self.result = self.estimate()
        self._readings = []
        return self.result

    def estimate(self) -> GravityEstimate:
        """The estimate from the readings so far (also before the window is full)."""
        if self.result is not None:
            return self.result
        if not self._readings:
            return GravityEstimate(Z_UP.copy(), False, "imu", "no finite accelerometer reading")
        r = np.concatenate(self._readings)
        mean = r.mean(axis=0)
        g = float(np.linalg.norm(mean))
        if abs(g - STANDARD_GRAVITY) > self.cfg.imu_max_g_error:
            return GravityEstimate(Z_UP.copy(), False, "imu", f"the mean reading is {g:.2f} m/s^2, not about "
                                   f"{STANDARD_GRAVITY:.2f}: the platform accelerated or the units are not m/s^2",
                                   samples=len(r))
        up = mean / g
        norms = np.maximum(np.linalg.norm(r, axis=1), 1e-12)
        spread = float(np.degrees(np.median(np.arccos(np.clip(r @ up / norms, -1.0, 1.0)))))
        if spread > self.cfg.imu_max_spread_deg:
            return GravityEstimate(Z_UP.copy(), False, "imu", f"single readings scatter {spread:.1f} deg (median) "
                                   "around their mean: the platform was shaking", samples=len(r))
        return GravityEstimate(up, True, "imu", support=1.0, samples=len(r))

    def record(self) -> dict[str, Any]:
        """The ``imu`` part of the map's gravity record: the estimate and a one-line verdict."""
        est = self.estimate()
        out: dict[str, Any] = {**est.as_dict(), "provisional": not self.done, "dropped_non_finite": self.dropped}
        if not est.ok:
            out["note"] = f"IMU gravity check: no estimate ({est.reason})"
        elif est.angle_deg > self.cfg.warn_deg:
            out["note"] = (f"the fixed frame's up is {est.angle_deg:.1f} deg from its +z by the IMU ({est.samples} "
                           "readings): the map, its boxes, planes and supports assume +z up; make the fixed frame "
                           "gravity aligned")
        else:
            out["note"] = f"IMU gravity check: the fixed frame's +z is up ({est.angle_deg:.1f} deg from it)"
        return out


def load_alignment(path: str | Path) -> np.ndarray:
    """A 4x4 (or 3x3) transform input world -> z-up frame from a text (or .npy) file; its rotation
    must be proper (orthonormal, det +1)."""
    p = Path(path)
    try:
        m = np.load(p) if p.suffix == ".npy" else np.loadtxt(p, comments="#", delimiter=None, ndmin=2)
    except (OSError, ValueError) as exc:
        raise InputError(f"--gravity {path}: cannot read a 4x4 transform: {exc}") from exc
    m = np.asarray(m, float)
    if m.shape == (3, 3):
        m = np.block([[m, np.zeros((3, 1))], [np.zeros((1, 3)), np.ones((1, 1))]])
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise InputError(f"--gravity {path}: expected a 4x4 (or 3x3) matrix of numbers, got shape {m.shape}")
    r = m[:3, :3]
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-4) or np.linalg.det(r) < 0:
        raise InputError(f"--gravity {path}: the rotation part is not a proper rotation (orthonormal, det +1)")
    if not np.allclose(m[3], [0, 0, 0, 1]):
        raise InputError(f"--gravity {path}: the last row must be 0 0 0 1")
    return m


def alignment_from_estimate(est: GravityEstimate, cfg: GravityConfig) -> tuple[np.ndarray, str]:
    """4x4 world -> gravity-aligned transform for an estimate, and a one-line note saying what was done."""
    if not est.ok:
        return np.eye(4), f"gravity auto: no estimate ({est.reason}); the input's +z is taken as up"
    ang = est.angle_deg
    if ang < cfg.min_correction_deg:
        return np.eye(4), (f"gravity auto: the input is z up (estimated up {ang:.2f} deg from +z, below "
                           f"{cfg.min_correction_deg:g} deg: not rotated)")
    t = np.eye(4)
    t[:3, :3] = rotation_to_z(est.up)
    return t, f"gravity auto: up estimated from the {est.method}, {ang:.1f} deg from the input's +z: map rotated"


def rotation_angle_deg(transform: np.ndarray) -> float:
    """Angle (deg) of the rotation part of a 4x4 / 3x3 transform."""
    r = np.asarray(transform, float)[:3, :3]
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1.0, 1.0))))


def up_of_alignment(transform: np.ndarray) -> np.ndarray:
    """The input-frame direction an alignment maps to +z (the input's up)."""
    return np.asarray(transform, float)[:3, :3].T @ Z_UP


__all__ = ["GRAVITY_MODES", "GravityConfig", "GravityEstimate", "GravityEstimator", "GravityMonitor",
           "alignment_from_estimate",
           "angle_deg", "estimate_up", "frame_normals", "load_alignment", "rotation_to_z"]
