"""Tiny RGB-D recordings in the layouts of real datasets, written into a test's tmp_path.

Colour encodes the viewing ray (red = x/z, green = y/z), so a test can check that colour resampled
onto another pixel grid lands on the right ray; depth is a fronto-parallel plane (optionally with
a far part, invalid markers, ...).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

#: Colour = 128 + RAY_GAIN * (x/z, y/z) of the pixel's ray.
RAY_GAIN = 150.0


def ray_color(k: tuple[float, float, float, float], w: int, h: int) -> np.ndarray:
    """(h, w, 3) uint8 RGB image whose red/green encode each pixel's ray direction under `k`."""
    fx, fy, cx, cy = k
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    r = 128 + RAY_GAIN * (u - cx) / fx
    g = 128 + RAY_GAIN * (v - cy) / fy
    return np.clip(np.round(np.dstack([r, g, np.full_like(r, 64)])), 0, 255).astype(np.uint8)


def ray_of_color(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of `ray_color`: (x/z, y/z) per pixel."""
    rgb = rgb.astype(np.float64)
    return (rgb[..., 0] - 128) / RAY_GAIN, (rgb[..., 1] - 128) / RAY_GAIN


def plane_mm(w: int, h: int, metres: float = 1.5) -> np.ndarray:
    return np.full((h, w), round(metres * 1000), np.uint16)


def write_png(path: Path, img: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if img.ndim == 3:
        img = img[:, :, ::-1]  # RGB -> BGR for OpenCV
    assert cv2.imwrite(str(path), img), path


def translation_pose(x: float, y: float, z: float) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = (x, y, z)
    return t


def write_matrix(path: Path, k: tuple[float, float, float, float], size: int = 3) -> None:
    """A camera matrix text file (3x3 like 3DMatch, 4x4 like ScanNet)."""
    fx, fy, cx, cy = k
    m = np.eye(size)
    m[0, 0], m[1, 1], m[0, 2], m[1, 2] = fx, fy, cx, cy
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, m, fmt="%.6f", delimiter="\t" if size == 3 else " ")


def seven_scenes(folder: Path, n: int, k: tuple[float, float, float, float], w: int = 40, h: int = 30,
                 depth: np.ndarray | None = None, poses: list[np.ndarray] | None = None) -> list[np.ndarray]:
    """frame-XXXXXX.{color,depth}.png + pose.txt in `folder`; returns the poses."""
    poses = poses or [translation_pose(0.02 * i, 0.0, 0.0) for i in range(n)]
    for i in range(n):
        write_png(folder / f"frame-{i:06d}.color.png", ray_color(k, w, h))
        write_png(folder / f"frame-{i:06d}.depth.png", plane_mm(w, h) if depth is None else depth)
        np.savetxt(folder / f"frame-{i:06d}.pose.txt", poses[i])
    return poses


def tum(folder: Path, n: int, color: np.ndarray, depth_raw: np.ndarray | list[np.ndarray],
        poses: list[np.ndarray] | None = None) -> None:
    """A TUM folder: rgb.txt, depth.txt, rgb/, depth/ and (with `poses`) groundtruth.txt."""
    from panoptic_mapping.dataio.transforms import matrix_to_quat

    rgb_lines, depth_lines, gt = [], [], []
    for i in range(n):
        t = 10.0 + i / 30.0
        write_png(folder / "rgb" / f"{i:03d}.png", color)
        write_png(folder / "depth" / f"{i:03d}.png", depth_raw[i] if isinstance(depth_raw, list) else depth_raw)
        rgb_lines.append(f"{t:.6f} rgb/{i:03d}.png")
        depth_lines.append(f"{t:.6f} depth/{i:03d}.png")
        if poses is not None:
            q = matrix_to_quat(poses[i][:3, :3])
            tx, ty, tz = poses[i][:3, 3]
            gt.append(f"{t:.6f} {tx:.9f} {ty:.9f} {tz:.9f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}")
    (folder / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (folder / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    if poses is not None:
        (folder / "groundtruth.txt").write_text("\n".join(gt) + "\n")


T0 = 7 * 10**9
PERIOD = 33_333_333


def rgbd_rawbag(n: int = 3, root: str = "map", color_wh: tuple[int, int] = (64, 48),
                depth_wh: tuple[int, int] = (64, 48),
                k_color: tuple[float, float, float, float] = (60.0, 60.0, 31.5, 23.5),
                k_depth: tuple[float, float, float, float] | None = None, depth_mm: np.ndarray | None = None,
                step_m: float = 0.01):
    """A RealSense-like recording (not yet written): TF `root` -> base_link (moving along x by `step_m`
    per frame) -> camera_link -> opt (static), ray-coloured images, a 1.5 m depth plane (16UC1) and,
    with `k_depth`, a camera info of its own beside the depth topic."""
    from testsupport.rawbag import RawBag, camera_info, image, tf_message

    q = np.array([0, 0, 0, 1.0])
    bag = RawBag()
    bag.add("/tf_static", tf_message([(0, "base_link", "camera_link", np.zeros(3), q),
                                      (0, "camera_link", "opt", np.zeros(3), q)]), log_time=0)
    (wc, hc), (wd, hd) = color_wh, depth_wh
    for i in range(n):
        t = T0 + i * PERIOD
        bag.add("/tf", tf_message([(t, root, "base_link", np.array([step_m * i, 0, 0]), q)]))
        bag.add("/camera/color/camera_info", camera_info(t, "opt", k_color, wc, hc))
        bag.add("/camera/color/image_raw", image(t, "opt", "rgb8", ray_color(k_color, wc, hc)))
        raw = depth_mm if depth_mm is not None else np.full((hd, wd), 1500, "<u2")
        bag.add("/camera/depth/image_rect_raw", image(t, "opt", "16UC1", raw.astype("<u2")))
        if k_depth is not None:
            bag.add("/camera/depth/camera_info", camera_info(t, "opt", k_depth, wd, hd))
    return bag


#: Intrinsics (fx, fy, cx, cy) of the toy-room TUM folders (160x120).
TOY_K = (131.25, 131.25, 79.5, 59.5)


def toy_room_tum(folder: Path, frames: int, sweep: float, transform: np.ndarray | None = None) -> None:
    """A TUM folder of the toy room (160x120, intrinsics in camera-intrinsics.txt): the camera at 1.4 m
    turns through `sweep` radians over `frames` frames; poses are given in `transform`'s frame (z up
    when None)."""
    from recon_core.frame import CameraIntrinsics
    from scene_recon.synthetic.geometry import look_at_pose
    from scene_recon.synthetic.sensor import RGBDSensorSimulator
    from scene_recon.synthetic.toy_scene import make_toy_scene

    sim = RGBDSensorSimulator(make_toy_scene(6, 1).items, CameraIntrinsics(*TOY_K, 160, 120))
    depths, poses = [], []
    for k in range(frames):
        yaw = sweep * k / frames
        pose = look_at_pose(np.array([0.0, 0.0, 1.4]), np.array([2 * np.cos(yaw), 2 * np.sin(yaw), 0.5]))
        depths.append(np.round(sim.render(pose, np.random.default_rng(k)).depth * 5000).astype(np.uint16))
        poses.append(pose if transform is None else transform @ pose)
    tum(folder, frames, np.full((120, 160, 3), 128, np.uint8), depths, poses)
    fx, fy, cx, cy = TOY_K
    np.savetxt(folder / "camera-intrinsics.txt", [[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
