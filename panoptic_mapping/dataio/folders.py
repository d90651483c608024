"""Frame-folder loaders: TUM RGB-D layout and Microsoft 7-Scenes layout.

TUM (https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats):
    rgb.txt, depth.txt        "timestamp filename" lines (# comments)
    groundtruth.txt           "timestamp tx ty tz qx qy qz qw" (optional; camera-to-world)
    rgb/*.png, depth/*.png    8-bit color, 16-bit depth in 1/5000 m (0 = invalid)
7-Scenes:
    [seq-XX/]frame-000000.color.png, frame-000000.depth.png (16-bit mm, 65535 = invalid),
    frame-000000.pose.txt (4x4 camera-to-world)
Either may carry a `camera.yaml` (fx, fy, cx, cy[, depth_scale]) that overrides the dataset's
default intrinsics.
"""

from __future__ import annotations

import abc
import logging
import re
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from panoptic_mapping.dataio.config import DataInputConfig
from panoptic_mapping.dataio.transforms import make_transform, slerp
from recon_core.frame import CameraIntrinsics, DatasetError, RGBDFrame, sanitize_depth

log = logging.getLogger(__name__)

TUM_DEFAULT_INTRINSICS = (525.0, 525.0, 319.5, 239.5)  # TUM's "ROS default" calibration
SEVEN_SCENES_DEFAULT_INTRINSICS = (585.0, 585.0, 320.0, 240.0)


@dataclass
class FolderSkips:
    unpaired: int = 0
    unreadable: int = 0
    no_pose: int = 0
    non_monotonic: int = 0
    all_depth_invalid: int = 0
    reasons: Counter = field(default_factory=Counter)

    def as_dict(self) -> dict[str, int]:
        return {k: v for k, v in vars(self).items() if k != "reasons"}


def _read_image(path: Path, depth: bool) -> np.ndarray:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DatasetError(f"cannot read image {path}")
    if depth:
        if img.ndim != 2 or img.dtype != np.uint16:
            raise DatasetError(f"{path}: depth PNG must be single-channel 16-bit, got {img.dtype} {img.shape}")
        return img
    if img.ndim == 2:
        return np.repeat(img[:, :, None], 3, axis=2).astype(np.uint8)
    if img.dtype != np.uint8:
        raise DatasetError(f"{path}: color image must be 8-bit, got {img.dtype}")
    return np.ascontiguousarray(img[:, :, 2::-1])  # BGR(A) -> RGB


def _camera_yaml(root: Path) -> dict:
    f = root / "camera.yaml"
    if not f.is_file():
        return {}
    data = yaml.safe_load(f.read_text(encoding="utf-8")) or {}
    if not isinstance(data, dict):
        raise DatasetError(f"{f}: expected a mapping with fx, fy, cx, cy")
    return data


class _FolderLoader(abc.ABC):
    default_intrinsics: tuple[float, float, float, float] = TUM_DEFAULT_INTRINSICS
    default_depth_scale: float = 1000.0
    #: Raw depth value the dataset uses for "no reading" besides 0 (7-Scenes: 65535).
    invalid_raw_depth: int | None = None

    def __init__(self, path: str | Path, config: DataInputConfig | None = None):
        self.path = Path(path)
        self.config = config or DataInputConfig()
        self.skips = FolderSkips()
        cam = _camera_yaml(self.path)
        if self.config.intrinsics:
            if len(self.config.intrinsics) != 4:
                raise DatasetError("intrinsics override must be [fx, fy, cx, cy]")
            self._k = tuple(float(v) for v in self.config.intrinsics)
        elif cam:
            try:
                self._k = (float(cam["fx"]), float(cam["fy"]), float(cam["cx"]), float(cam["cy"]))
            except KeyError as exc:
                raise DatasetError(f"{self.path / 'camera.yaml'} lacks {exc}") from exc
        else:
            self._k = self.default_intrinsics
        self.depth_scale = float(self.config.depth_scale or cam.get("depth_scale", self.default_depth_scale))
        if self.depth_scale <= 0:
            raise DatasetError("depth_scale must be > 0")
        self.entries = self._entries()  # list of (stamp_ns, color_path, depth_path, pose | None)

    @abc.abstractmethod
    def _entries(self) -> list[tuple[int, Path, Path, np.ndarray | None]]:
        """(stamp_ns, color path, depth path, camera-to-world pose or None) for every frame."""

    def close(self) -> None:  # noqa: B027 - intentionally empty: folders hold no open handle
        """Nothing to release; present so every loader can be used the same way."""

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __len__(self) -> int:
        return len(self.entries)

    def __iter__(self) -> Iterator[RGBDFrame]:
        cfg = self.config
        emitted = 0
        selected = self.entries[cfg.start :: max(cfg.stride, 1)]
        for stamp, cpath, dpath, pose in selected:
            if pose is None:
                self.skips.no_pose += 1
                if cfg.require_pose:
                    continue
            try:
                color = _read_image(cpath, depth=False)
                raw = _read_image(dpath, depth=True)
                if self.invalid_raw_depth is not None:
                    raw = np.where(raw == self.invalid_raw_depth, 0, raw)
                depth, n_bad = sanitize_depth(raw.astype(np.float32) / np.float32(self.depth_scale))
                h, w = depth.shape
                frame = RGBDFrame(
                    color=color, depth=depth, intrinsics=CameraIntrinsics(*self._k[:4], width=w, height=h),  # type: ignore[misc, arg-type]
                    pose=pose, timestamp_ns=stamp, index=emitted, frame_id="camera", invalid_depth_pixels=n_bad,
                )
            except DatasetError as exc:
                self.skips.unreadable += 1
                self.skips.reasons[str(exc)[:120]] += 1
                log.error("skipping %s: %s", cpath.name, exc)
                continue
            if not np.any(depth > 0):
                self.skips.all_depth_invalid += 1
                continue
            yield frame
            emitted += 1
            if cfg.max_frames and emitted >= cfg.max_frames:
                return


def _read_list(path: Path) -> list[tuple[float, str]]:
    out = []
    for lineno, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        try:
            out.append((float(parts[0]), parts[1]))
        except (ValueError, IndexError) as exc:
            raise DatasetError(f"{path}:{lineno}: expected 'timestamp filename', got {line!r}") from exc
    return out


def is_tum(path: Path) -> bool:
    return path.is_dir() and (path / "rgb.txt").is_file() and (path / "depth.txt").is_file()


class TumLoader(_FolderLoader):
    """TUM RGB-D benchmark folder; color/depth associated by nearest timestamp (like associate.py)."""

    default_intrinsics = TUM_DEFAULT_INTRINSICS
    default_depth_scale = 5000.0

    def _entries(self):
        rgb = _read_list(self.path / "rgb.txt")
        depth = _read_list(self.path / "depth.txt")
        if not rgb or not depth:
            raise DatasetError(f"{self.path}: rgb.txt or depth.txt lists no frame")
        poses = self._groundtruth()
        rgb_t = np.array([t for t, _ in rgb])
        order = np.argsort(rgb_t, kind="stable")
        rgb_t = rgb_t[order]
        rgb = [rgb[i] for i in order]
        entries, used = [], set()
        last = -np.inf
        for t, dname in depth:
            if t <= last:
                self.skips.non_monotonic += 1
                continue
            last = t
            i = int(np.searchsorted(rgb_t, t))
            cands = [j for j in (i - 1, i) if 0 <= j < len(rgb_t)]
            j = min(cands, key=lambda k: abs(rgb_t[k] - t))
            if abs(rgb_t[j] - t) > self.config.sync_slop_s or j in used:
                self.skips.unpaired += 1
                continue
            used.add(j)
            stamp = round(t * 1e9)
            entries.append((stamp, self.path / rgb[j][1], self.path / dname, self._pose_at(poses, t)))
        return entries

    def _groundtruth(self):
        f = self.path / "groundtruth.txt"
        if not f.is_file():
            return None
        rows = []
        for lineno, line in enumerate(f.read_text(encoding="utf-8").splitlines(), 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            try:
                vals = [float(v) for v in line.split()]
            except ValueError as exc:
                raise DatasetError(f"{f}:{lineno}: non-numeric pose line {line!r}") from exc
            if len(vals) != 8 or not np.all(np.isfinite(vals)):
                raise DatasetError(f"{f}:{lineno}: expected 'timestamp tx ty tz qx qy qz qw'")
            rows.append(vals)
        if not rows:
            return None
        arr = np.array(rows)
        return arr[np.argsort(arr[:, 0], kind="stable")]

    def _pose_at(self, gt: np.ndarray | None, t: float) -> np.ndarray | None:
        if gt is None:
            return None
        i = int(np.searchsorted(gt[:, 0], t))
        tol = self.config.tf_max_extrapolation_s
        if i == 0 or i == len(gt):
            j = 0 if i == 0 else len(gt) - 1
            return make_transform(gt[j, 1:4], gt[j, 4:8]) if abs(gt[j, 0] - t) <= tol else None
        t0, t1 = gt[i - 1, 0], gt[i, 0]
        if t1 - t0 > self.config.tf_max_gap_s:
            return None
        u = (t - t0) / (t1 - t0)
        return make_transform(gt[i - 1, 1:4] + u * (gt[i, 1:4] - gt[i - 1, 1:4]), slerp(gt[i - 1, 4:8], gt[i, 4:8], u))


_FRAME_RE = re.compile(r"^frame-(\d+)\.color\.(png|jpg)$")


def _seven_scenes_dirs(path: Path) -> list[Path]:
    if not path.is_dir():
        return []
    if any(_FRAME_RE.match(p.name) for p in path.iterdir()):
        return [path]
    return sorted(p for p in path.iterdir() if p.is_dir() and p.name.startswith("seq-")
                  and any(_FRAME_RE.match(q.name) for q in p.iterdir()))


def is_seven_scenes(path: Path) -> bool:
    return bool(_seven_scenes_dirs(path))


class SevenScenesLoader(_FolderLoader):
    """7-Scenes sequence folder (or a scene folder holding seq-XX folders, read in order)."""

    default_intrinsics = SEVEN_SCENES_DEFAULT_INTRINSICS
    default_depth_scale = 1000.0
    invalid_raw_depth = 65535
    frame_period_ns = 33_333_333  # the dataset has no timestamps: 30 Hz is assumed

    def _entries(self):
        entries = []
        k = 0
        for seq in _seven_scenes_dirs(self.path):
            names = sorted((int(m.group(1)), p) for p in seq.iterdir() if (m := _FRAME_RE.match(p.name)))
            for num, cpath in names:
                dpath = seq / f"frame-{num:06d}.depth.png"
                ppath = seq / f"frame-{num:06d}.pose.txt"
                if not dpath.is_file():
                    self.skips.unpaired += 1
                    continue
                entries.append((k * self.frame_period_ns, cpath, dpath, self._pose(ppath)))
                k += 1
        if not entries:
            raise DatasetError(f"{self.path}: no frame-XXXXXX.color.png with a matching depth PNG")
        return entries

    def _pose(self, path: Path) -> np.ndarray | None:
        if not path.is_file():
            return None
        try:
            pose = np.loadtxt(path, dtype=np.float64)
        except ValueError as exc:
            self.skips.reasons[f"bad pose file {path.name}"] += 1
            log.warning("ignoring unreadable pose %s: %s", path, exc)
            return None
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            self.skips.reasons[f"bad pose file {path.name}"] += 1
            return None
        return pose
