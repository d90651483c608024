"""Rigid transforms and a ROS-free TF buffer (static + time-stamped edges, multi-hop chains).

The bag loaders feed every `/tf` and `/tf_static` transform into a `TransformBuffer`, then ask for
camera-to-map poses at image timestamps. Lookups interpolate between the two neighbouring samples
of each dynamic edge (linear translation, quaternion slerp), like tf2, and refuse to extrapolate
beyond a configurable tolerance.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np

from recon_core.errors import TransformLookupError

_EPS = 1e-12


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions (x, y, z, w) -> (..., 3, 3) rotation matrices (normalized first)."""
    q = np.asarray(q, dtype=np.float64)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(norm < _EPS) or not np.all(np.isfinite(q)):
        raise ValueError("quaternion with zero norm or non-finite entries")
    x, y, z, w = np.moveaxis(q / norm, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_to_quat(r: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions (x, y, z, w), w >= 0."""
    r = np.asarray(r, dtype=np.float64)
    m = r.reshape(-1, 3, 3)
    tr = np.trace(m, axis1=1, axis2=2)
    # Shepperd's method: pick the largest of 4 candidate denominators for stability.
    cand = np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    k = np.argmax(cand, axis=1)
    q = np.empty((m.shape[0], 4))
    for case in range(4):
        sel = k == case
        if not np.any(sel):
            continue
        s = m[sel]
        if case == 0:
            t = np.sqrt(np.maximum(1.0 + tr[sel], _EPS)) * 2
            q[sel] = np.stack(
                [(s[:, 2, 1] - s[:, 1, 2]) / t, (s[:, 0, 2] - s[:, 2, 0]) / t,
                 (s[:, 1, 0] - s[:, 0, 1]) / t, 0.25 * t], axis=1)
        elif case == 1:
            t = np.sqrt(np.maximum(1.0 + s[:, 0, 0] - s[:, 1, 1] - s[:, 2, 2], _EPS)) * 2
            q[sel] = np.stack(
                [0.25 * t, (s[:, 0, 1] + s[:, 1, 0]) / t, (s[:, 0, 2] + s[:, 2, 0]) / t,
                 (s[:, 2, 1] - s[:, 1, 2]) / t], axis=1)
        elif case == 2:
            t = np.sqrt(np.maximum(1.0 + s[:, 1, 1] - s[:, 0, 0] - s[:, 2, 2], _EPS)) * 2
            q[sel] = np.stack(
                [(s[:, 0, 1] + s[:, 1, 0]) / t, 0.25 * t, (s[:, 1, 2] + s[:, 2, 1]) / t,
                 (s[:, 0, 2] - s[:, 2, 0]) / t], axis=1)
        else:
            t = np.sqrt(np.maximum(1.0 + s[:, 2, 2] - s[:, 0, 0] - s[:, 1, 1], _EPS)) * 2
            q[sel] = np.stack(
                [(s[:, 0, 2] + s[:, 2, 0]) / t, (s[:, 1, 2] + s[:, 2, 1]) / t, 0.25 * t,
                 (s[:, 1, 0] - s[:, 0, 1]) / t], axis=1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 3] < 0] *= -1
    return q.reshape((*r.shape[:-2], 4))


def make_transform(translation: np.ndarray, quat_xyzw: np.ndarray) -> np.ndarray:
    """4x4 float64 homogeneous transform from a translation and a quaternion (x, y, z, w)."""
    t = np.eye(4)
    t[:3, :3] = quat_to_matrix(quat_xyzw)
    t[:3, 3] = np.asarray(translation, dtype=np.float64)
    return t


def invert_transform(t: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform (uses R^T, exact for rotations)."""
    inv = np.eye(4)
    r = t[:3, :3]
    inv[:3, :3] = r.T
    inv[:3, 3] = -r.T @ t[:3, 3]
    return inv


def slerp(q0: np.ndarray, q1: np.ndarray, u: float) -> np.ndarray:
    """Spherical interpolation between unit quaternions (shortest path)."""
    q0 = q0 / np.linalg.norm(q0)
    q1 = q1 / np.linalg.norm(q1)
    dot = float(np.dot(q0, q1))
    if dot < 0:
        q1, dot = -q1, -dot
    if dot > 1.0 - 1e-12:  # (nearly) identical: sin(theta) would vanish; nlerp is exact to ~1e-12 here
        q = q0 + u * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    return (np.sin((1 - u) * theta) * q0 + np.sin(u * theta) * q1) / np.sin(theta)


@dataclass
class _DynamicEdge:
    stamps: list[int] = field(default_factory=list)
    translations: list[np.ndarray] = field(default_factory=list)
    quats: list[np.ndarray] = field(default_factory=list)
    _sorted: bool = True
    _arrays: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def add(self, stamp_ns: int, translation: np.ndarray, quat: np.ndarray, max_samples: int = 0) -> None:
        if self.stamps and stamp_ns < self.stamps[-1]:
            self._sorted = False
        self.stamps.append(stamp_ns)
        self.translations.append(translation)
        self.quats.append(quat)
        self._arrays = None
        if max_samples and len(self.stamps) > max_samples:  # a live stream keeps the recent history only
            keep = max_samples // 2
            if not self._sorted:
                stamps, trans, quats = self.arrays()
                self.stamps, self.translations, self.quats = list(stamps), list(trans), list(quats)
                self._sorted = True
            del self.stamps[:-keep], self.translations[:-keep], self.quats[:-keep]
            self._arrays = None

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self._arrays is None:
            stamps = np.asarray(self.stamps, dtype=np.int64)
            trans = np.asarray(self.translations, dtype=np.float64).reshape(-1, 3)
            quats = np.asarray(self.quats, dtype=np.float64).reshape(-1, 4)
            if not self._sorted:
                order = np.argsort(stamps, kind="stable")
                stamps, trans, quats = stamps[order], trans[order], quats[order]
            self._arrays = (stamps, trans, quats)
        return self._arrays


class TransformBuffer:
    """A tf2-like buffer over a whole recording.

    Each child frame has one parent (a tree, as in tf2). Static edges hold one transform; dynamic
    edges hold a time series. `lookup(target, source, t)` returns T_target_source (maps points in
    `source` coordinates to `target` coordinates) at time t.
    """

    def __init__(self, max_extrapolation_ns: int = 50_000_000, max_gap_ns: int = 1_000_000_000,
                 max_samples_per_edge: int = 0):
        self.max_extrapolation_ns = max_extrapolation_ns
        self.max_gap_ns = max_gap_ns
        #: 0 = keep everything (recordings); live nodes bound the history per dynamic edge.
        self.max_samples_per_edge = max_samples_per_edge
        self._parent: dict[str, str] = {}
        self._static: dict[str, np.ndarray] = {}
        self._dynamic: dict[str, _DynamicEdge] = defaultdict(_DynamicEdge)
        self.conflicts = 0  # transforms that tried to give a frame a second parent (ignored)

    @property
    def frames(self) -> set[str]:
        return set(self._parent) | set(self._parent.values())

    def add(
        self, parent: str, child: str, stamp_ns: int, translation: np.ndarray, quat_xyzw: np.ndarray,
        static: bool = False,
    ) -> bool:
        """Record one transform; returns False (and counts a conflict) for a re-parented frame."""
        parent, child = parent.lstrip("/"), child.lstrip("/")
        if not parent or not child or parent == child:
            self.conflicts += 1
            return False
        known = self._parent.get(child)
        if known is not None and known != parent:
            self.conflicts += 1
            return False
        translation = np.asarray(translation, dtype=np.float64)
        quat = np.asarray(quat_xyzw, dtype=np.float64)
        if not (np.all(np.isfinite(translation)) and np.all(np.isfinite(quat))) or np.linalg.norm(quat) < 1e-9:
            self.conflicts += 1
            return False
        self._parent[child] = parent
        if static:
            self._static[child] = make_transform(translation, quat)
        else:
            self._dynamic[child].add(int(stamp_ns), translation, quat / np.linalg.norm(quat),
                                     self.max_samples_per_edge)
        return True

    def _edge(self, child: str, stamp_ns: int) -> np.ndarray:
        """T_parent_child at stamp_ns."""
        if child in self._static:
            return self._static[child]
        stamps, trans, quats = self._dynamic[child].arrays()
        if stamps.size == 0:
            raise TransformLookupError(f"no transform recorded for frame {child!r}")
        i = int(np.searchsorted(stamps, stamp_ns))
        if i < stamps.size and stamps[i] == stamp_ns:
            return make_transform(trans[i], quats[i])
        if i == 0 or i == stamps.size:
            j = 0 if i == 0 else stamps.size - 1
            if abs(int(stamps[j]) - stamp_ns) > self.max_extrapolation_ns:
                raise TransformLookupError(
                    f"transform {self._parent[child]!r} -> {child!r} is not available at t={stamp_ns * 1e-9:.3f} s "
                    f"(recorded from {stamps[0] * 1e-9:.3f} s to {stamps[-1] * 1e-9:.3f} s)"
                )
            return make_transform(trans[j], quats[j])
        t0, t1 = int(stamps[i - 1]), int(stamps[i])
        if t1 - t0 > self.max_gap_ns:
            raise TransformLookupError(
                f"transform {self._parent[child]!r} -> {child!r} has a {(t1 - t0) * 1e-9:.2f} s gap "
                f"around t={stamp_ns * 1e-9:.3f} s; refusing to interpolate"
            )
        u = (stamp_ns - t0) / (t1 - t0)
        return make_transform(trans[i - 1] + u * (trans[i] - trans[i - 1]), slerp(quats[i - 1], quats[i], u))

    def _path_to_root(self, frame: str) -> list[str]:
        path = [frame]
        seen = {frame}
        while path[-1] in self._parent:
            nxt = self._parent[path[-1]]
            if nxt in seen:
                raise TransformLookupError(f"TF frames form a loop through {nxt!r}")
            seen.add(nxt)
            path.append(nxt)
        return path

    def roots(self) -> list[str]:
        """Frames without a parent (the top of each TF tree), sorted."""
        return sorted(f for f in self.frames if f not in self._parent)

    def root_of(self, frame: str) -> str:
        """Top of the TF tree `frame` belongs to (`frame` itself when it has no parent)."""
        return self._path_to_root(frame.lstrip("/"))[-1]

    def can_connect(self, target: str, source: str) -> bool:
        target, source = target.lstrip("/"), source.lstrip("/")
        return bool(set(self._path_to_root(target)) & set(self._path_to_root(source)))

    def lookup(self, target: str, source: str, stamp_ns: int) -> np.ndarray:
        """T_target_source at `stamp_ns` (4x4 float64)."""
        target, source = target.lstrip("/"), source.lstrip("/")
        if target == source:
            return np.eye(4)
        up_source = self._path_to_root(source)
        up_target = self._path_to_root(target)
        common = next((f for f in up_source if f in set(up_target)), None)
        if common is None:
            known = ", ".join(sorted(self.frames)) or "none"
            raise TransformLookupError(
                f"no TF chain connects {target!r} and {source!r} (known frames: {known})"
            )
        t_common_source = np.eye(4)
        for child in up_source[: up_source.index(common)]:
            t_common_source = self._edge(child, stamp_ns) @ t_common_source
        t_common_target = np.eye(4)
        for child in up_target[: up_target.index(common)]:
            t_common_target = self._edge(child, stamp_ns) @ t_common_target
        return invert_transform(t_common_target) @ t_common_source

    def time_range(self, frame: str, target: str) -> tuple[int, int] | None:
        """Interval in which every dynamic edge between `frame` and `target` has data (None: static)."""
        frames = set(self._path_to_root(frame)) ^ set(self._path_to_root(target))
        lo, hi = None, None
        for child in frames:
            if child in self._dynamic and child not in self._static:
                stamps = self._dynamic[child].arrays()[0]
                if stamps.size == 0:
                    continue
                lo = stamps[0] if lo is None else max(lo, stamps[0])
                hi = stamps[-1] if hi is None else min(hi, stamps[-1])
        return None if lo is None or hi is None else (int(lo), int(hi))
