"""Frame-folder loaders: TUM RGB-D, Microsoft 7-Scenes / 3DMatch and ScanNet-export layouts.

TUM (https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats):
    rgb.txt, depth.txt        "timestamp filename" lines (# comments)
    groundtruth.txt           "timestamp tx ty tz qx qy qz qw" (optional; camera-to-world)
    rgb/*.png, depth/*.png    8-bit color, 16-bit depth in 1/5000 m (0 = invalid)
7-Scenes / 3DMatch:
    [seq-XX/ | rgbd-frames/]frame-000000.color.png, frame-000000.depth.png (16-bit mm),
    frame-000000.pose.txt (4x4 camera-to-world); 3DMatch adds camera-intrinsics.txt (3x3)
ScanNet export (SensReader):
    color/N.jpg, depth/N.png (16-bit mm), pose/N.txt (4x4 camera-to-world, -inf = lost tracking),
    intrinsic/intrinsic_color.txt, intrinsic/intrinsic_depth.txt (4x4); colour 1296x968 and depth
    640x480 are brought onto the depth grid (`panoptic_mapping.dataio.align`)

Intrinsics, first found wins: `intrinsics` / `intrinsics_file` of the data config (`--intrinsics`),
`camera.yaml` (fx, fy, cx, cy[, depth_scale]), `camera-intrinsics.txt` or `intrinsics.txt` (3x3
or 4x4 matrix) beside the frames, the dataset's own files (ScanNet), the dataset's default (logged
as a warning: a wrong focal length bends every wall).
Depth: 0 and 65535 (the 16-bit "no reading" / saturation marker) are invalid in every layout.
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

from panoptic_mapping.dataio.align import register_to_depth
from panoptic_mapping.dataio.config import DataInputConfig
from panoptic_mapping.dataio.intrinsics import (
    find_matrix_file,
    read_intrinsics_file,
    read_matrix_intrinsics,
    read_yaml_intrinsics,
)
from panoptic_mapping.dataio.transforms import make_transform, slerp
from recon_core.frame import DatasetError, RGBDFrame, sanitize_depth

log = logging.getLogger(__name__)

TUM_DEFAULT_INTRINSICS = (525.0, 525.0, 319.5, 239.5)  # TUM's "ROS default" calibration
SEVEN_SCENES_DEFAULT_INTRINSICS = (585.0, 585.0, 320.0, 240.0)
#: Raw 16-bit depth value meaning "no reading" besides 0 (Kinect / 7-Scenes saturation marker).
INVALID_RAW_DEPTH = 65535


@dataclass
class FolderSkips:
    unpaired: int = 0
    unreadable: int = 0
    no_pose: int = 0
    non_monotonic: int = 0
    all_depth_invalid: int = 0
    size_mismatch: int = 0
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


def raw_depth_to_metres(raw: np.ndarray, depth_scale: float) -> tuple[np.ndarray, int]:
    """16-bit depth PNG values -> float32 metres; 0 and 65535 become 0 (invalid)."""
    raw = np.where(raw == INVALID_RAW_DEPTH, 0, raw)
    return sanitize_depth(raw.astype(np.float32) / np.float32(depth_scale))


class _FolderLoader(abc.ABC):
    default_intrinsics: tuple[float, float, float, float] = TUM_DEFAULT_INTRINSICS
    default_depth_scale: float = 1000.0
    #: Frames are this far apart when the layout has no timestamps (30 Hz).
    frame_period_ns = 33_333_333

    def __init__(self, path: str | Path, config: DataInputConfig | None = None):
        self.path = Path(path)
        self.config = config or DataInputConfig()
        self.skips = FolderSkips()
        #: Notes on what the layout lacks (e.g. no pose file), used to explain skipped frames.
        self.notes: list[str] = []
        self.resampled_frames = 0
        self._k_depth: tuple[float, float, float, float] | None = None
        self._k, self.intrinsics_source, cam = self._resolve_intrinsics()
        self.depth_scale = float(self.config.depth_scale or cam.get("depth_scale", self.default_depth_scale))
        if self.depth_scale <= 0:
            raise DatasetError("depth_scale must be > 0")
        self.entries = self._entries()  # list of (stamp_ns, color_path, depth_path, pose | None)

    # ------------------------------------------------------------------ calibration
    def intrinsics_dirs(self) -> list[Path]:
        """Folders searched for camera.yaml / camera-intrinsics.txt / intrinsics.txt, in order."""
        return [self.path]

    def dataset_intrinsics(self) -> tuple[tuple[float, float, float, float], str] | None:
        """The layout's own calibration files (colour camera; may set `_k_depth`), or None."""
        return None

    def _resolve_intrinsics(self) -> tuple[tuple[float, float, float, float], str, dict]:
        cfg = self.config
        dirs = self.intrinsics_dirs()
        cam: dict = {}
        cam_file = next((d / "camera.yaml" for d in dirs if (d / "camera.yaml").is_file()), None)
        if cam_file is not None:
            k_yaml, cam = read_yaml_intrinsics(cam_file)
        if cfg.intrinsics:
            if len(cfg.intrinsics) != 4:
                raise DatasetError("intrinsics override must be [fx, fy, cx, cy]")
            fx, fy, cx, cy = (float(v) for v in cfg.intrinsics)
            return (fx, fy, cx, cy), "intrinsics option", cam
        if cfg.intrinsics_file:
            return read_intrinsics_file(cfg.intrinsics_file), str(cfg.intrinsics_file), cam
        if cam_file is not None:
            return k_yaml, str(cam_file), cam
        matrix = find_matrix_file(dirs)
        if matrix is not None:
            return read_matrix_intrinsics(matrix), str(matrix), cam
        own = self.dataset_intrinsics()
        if own is not None:
            return own[0], own[1], cam
        log.warning("%s: no camera calibration found (camera.yaml, camera-intrinsics.txt, intrinsics.txt); "
                    "using the dataset default fx=%g fy=%g cx=%g cy=%g - pass --intrinsics if it is another camera",
                    self.path, *self.default_intrinsics)
        return self.default_intrinsics, "dataset default", cam

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

    def read_frame(self, stamp: int, cpath: Path, dpath: Path, pose: np.ndarray | None, index: int) -> RGBDFrame:
        """Read and register one frame; raises DatasetError (unreadable or unusable images)."""
        color = _read_image(cpath, depth=False)
        raw = _read_image(dpath, depth=True)
        depth, n_bad = raw_depth_to_metres(raw, self.depth_scale)
        # with one matrix for images of two sizes, the image it fits (principal point) is the one it describes
        color, intr, _, resampled = register_to_depth(color, depth, self._k, self._k_depth, k_describes="auto")
        if resampled:
            if not self.resampled_frames:
                log.info("%s: colour %s resampled onto the depth grid %dx%d", self.path, cpath.name,
                         intr.width, intr.height)
            self.resampled_frames += 1
        return RGBDFrame(color=color, depth=depth, intrinsics=intr, pose=pose, timestamp_ns=stamp, index=index,
                         frame_id="camera", invalid_depth_pixels=n_bad)

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
                frame = self.read_frame(stamp, cpath, dpath, pose, emitted)
            except DatasetError as exc:
                if "differ in size" in str(exc):
                    self.skips.size_mismatch += 1
                else:
                    self.skips.unreadable += 1
                self.skips.reasons[str(exc)[:160]] += 1
                log.error("skipping %s: %s", cpath.name, exc)
                continue
            if not np.any(frame.depth > 0):
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
        if poses is None:
            self.notes.append(f"{self.path} has no groundtruth.txt (TUM camera poses come from it)")
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
        if poses is not None and entries and all(e[3] is None for e in entries):
            self.notes.append(f"groundtruth.txt covers {poses[0, 0]:.3f}-{poses[-1, 0]:.3f} s, the images "
                              f"{entries[0][0] * 1e-9:.3f}-{entries[-1][0] * 1e-9:.3f} s")
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


def _read_pose_file(path: Path, skips: FolderSkips) -> np.ndarray | None:
    """4x4 camera-to-world pose from a text file; None (counted) when missing, unreadable or not finite."""
    if not path.is_file():
        return None
    try:
        pose = np.loadtxt(path, dtype=np.float64)
    except ValueError as exc:
        skips.reasons[f"bad pose file {path.name}"] += 1
        log.warning("ignoring unreadable pose %s: %s", path, exc)
        return None
    if pose.shape != (4, 4):
        skips.reasons[f"bad pose file {path.name}"] += 1
        return None
    if not np.all(np.isfinite(pose)):  # ScanNet writes -inf where tracking was lost
        skips.reasons["pose not finite (tracking lost)"] += 1
        return None
    return pose


_FRAME_RE = re.compile(r"^frame-(\d+)\.color\.(png|jpg)$")


def _has_frames(path: Path) -> bool:
    return path.is_dir() and any(_FRAME_RE.match(p.name) for p in path.iterdir())


def _seven_scenes_dirs(path: Path) -> list[Path]:
    """Folders holding frame-XXXXXX.* files: the folder itself, its rgbd-frames/, or its seq-XX/ folders."""
    if not path.is_dir():
        return []
    if _has_frames(path):
        return [path]
    if _has_frames(path / "rgbd-frames"):
        return [path / "rgbd-frames"]
    return sorted(p for p in path.iterdir() if p.is_dir() and p.name.startswith("seq-") and _has_frames(p))


def is_seven_scenes(path: Path) -> bool:
    return bool(_seven_scenes_dirs(path))


class SevenScenesLoader(_FolderLoader):
    """7-Scenes / 3DMatch frames: a sequence folder, an `rgbd-frames/` folder or a scene of seq-XX folders."""

    default_intrinsics = SEVEN_SCENES_DEFAULT_INTRINSICS
    default_depth_scale = 1000.0

    def intrinsics_dirs(self) -> list[Path]:
        dirs = [self.path, *_seven_scenes_dirs(self.path)]
        if self.path.name == "rgbd-frames" or self.path.name.startswith("seq-"):
            dirs.append(self.path.parent)  # 3DMatch: camera-intrinsics.txt beside the seq-XX folders
        return list(dict.fromkeys(dirs))

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
                entries.append((k * self.frame_period_ns, cpath, dpath, _read_pose_file(ppath, self.skips)))
                k += 1
        if not entries:
            raise DatasetError(f"{self.path}: no frame-XXXXXX.color.png/.jpg with a matching depth PNG")
        if all(e[3] is None for e in entries):
            self.notes.append(f"{self.path}: no usable frame-XXXXXX.pose.txt beside the frames")
        return entries


_NUM_RE = re.compile(r"^(\d+)\.(jpg|jpeg|png)$", re.IGNORECASE)


def is_scannet(path: Path) -> bool:
    """ScanNet export: color/ + depth/ and pose/ or intrinsic/ (TUM uses rgb/ + rgb.txt instead)."""
    return (path.is_dir() and (path / "color").is_dir() and (path / "depth").is_dir()
            and ((path / "pose").is_dir() or (path / "intrinsic").is_dir()))


class ScanNetLoader(_FolderLoader):
    """ScanNet SensReader export: color/N.jpg, depth/N.png (mm), pose/N.txt, intrinsic/*.txt."""

    default_intrinsics = (1169.6, 1167.1, 646.3, 489.9)  # a typical ScanNet colour camera
    default_depth_scale = 1000.0

    def intrinsics_dirs(self) -> list[Path]:
        return [self.path]

    def dataset_intrinsics(self):
        folder = self.path / "intrinsic"
        kc, kd = folder / "intrinsic_color.txt", folder / "intrinsic_depth.txt"
        if kd.is_file():
            self._k_depth = read_matrix_intrinsics(kd)
        if kc.is_file():
            return read_matrix_intrinsics(kc), str(kc)
        if self._k_depth is not None:
            k, self._k_depth = self._k_depth, None
            return k, str(kd)
        return None

    def _entries(self):
        colors = {int(m.group(1)): p for p in (self.path / "color").iterdir() if (m := _NUM_RE.match(p.name))}
        depths = {int(m.group(1)): p for p in (self.path / "depth").iterdir()
                  if (m := _NUM_RE.match(p.name)) and p.suffix.lower() == ".png"}
        pose_dir = self.path / "pose"
        if not pose_dir.is_dir():
            self.notes.append(f"{self.path} has no pose/ folder (ScanNet camera poses: pose/N.txt)")
        entries = []
        for k, num in enumerate(sorted(colors)):
            if num not in depths:
                self.skips.unpaired += 1
                continue
            entries.append((k * self.frame_period_ns, colors[num], depths[num],
                            _read_pose_file(pose_dir / f"{num}.txt", self.skips)))
        self.skips.unpaired += len(set(depths) - set(colors))
        if not entries:
            raise DatasetError(f"{self.path}: no color/N.jpg with a matching depth/N.png")
        return entries
