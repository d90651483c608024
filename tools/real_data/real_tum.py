"""A public TUM-format RGB-D recording with a stock YOLOX-Nano: get it, make it readable, run, measure.

The second real-data check beside the 7-Scenes kitchen (``real_kitchen.py``, whose ``run`` and ``measure``
this script reuses); docs/REAL_DATA_TUM.md says which recording, from where, under which terms, and what
was measured. Nothing of the data or the weights is in this repository. Steps, each usable on its own:

``fetch``    extract a TUM-format folder (``rgb.txt``, ``depth.txt``, images) from a git snapshot of the
             public repository that carries it: ``git archive HEAD [PATH]`` into ``DEST``.
``prepare``  write a readable copy of the folder (images linked, not copied) into ``OUT``:
             * ``rgb.txt`` / ``depth.txt`` rewritten with stamps ``i / fps`` when the recording's own stamps
               do not increase (the loader keeps only the increasing ones and drops the rest), colour and
               depth paired by list order;
             * ``camera.yaml`` with the camera's ``fx fy cx cy`` and ``depth_scale`` (units per metre: a
               RealSense writes millimetres, the TUM default is 5000);
             * ``groundtruth.txt``: the recording's own when it has one, else camera-to-world poses from
               Open3D's RGB-D odometry (hybrid photometric + geometric term, each frame against the last
               keyframe, a new keyframe every 10 cm / 10 deg); ``prepare.json`` says which and how many
               frames the odometry could not place (those keep the previous pose and are listed).
             A folder with increasing stamps and its own ``groundtruth.txt`` (a real TUM benchmark
             sequence) keeps both; only ``camera.yaml`` is added when ``--intrinsics`` is given.
``check-poses``  a ground-truth-free check of the prepared poses: each frame's depth moved into a frame
             5, 20 and 60 frames later, median depth disagreement (a few mm when the poses are right).
``run``      ``scene-recon run OUT --out RUN --model MODEL --stride N [--preset P]`` (``real_kitchen.run``'s
             command; ``--preset accurate`` segments every frame instead of the keyframes only).
``measure``  the kitchen's ground-truth-free figures (per object: CAD model or observed mesh and why, the
             paper's AE and the two-sided AE, stillness in PyBullet and MuJoCo; ``real_kitchen.measure``)
             plus checks of the floor the graph derived (its height against the cameras', the share of
             the map's horizontal faces there that face up, the tilt of their RANSAC plane: ``floor_levelness``)
             and the map's gravity verdict; ``--picture FILE`` writes the run's
             ``scene/before_after.png`` (map entities | replaced scene) scaled to fit under 500 KB.

    PY=.venv/bin/python; R=/work/realdata/tum
    $PY tools/real_data/real_tum.py fetch --git GIT_DIR --dest $R/src
    $PY tools/real_data/real_tum.py prepare $R/src --out $R/prepared --intrinsics 615,615,320,240 --depth-scale 1000
    $PY tools/real_data/real_tum.py check-poses $R/prepared
    $PY tools/real_data/real_tum.py run --data $R/prepared --model /work/realdata/models/yolox_nano.onnx \\
        --out $R/run_s1 --stride 1 [--preset accurate]
    $PY tools/real_data/real_tum.py measure $R/run_s1 --data $R/prepared [--json FILE] \\
        [--picture docs/img/real_tum_scene.png]
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import real_kitchen  # the kitchen script beside this one: run, measure, _print

ROOT = real_kitchen.ROOT


# ----------------------------------------------------------------------------------------------- fetch
def fetch(git_dir: Path, dest: Path, path: str | None = None) -> Path:
    """Extract ``path`` (or the whole tree) of ``git_dir``'s HEAD into ``dest``; returns the TUM folder."""
    dest.mkdir(parents=True, exist_ok=True)
    cmd = ["git", f"--git-dir={git_dir}", "archive", "HEAD"] + ([path] if path else [])
    archive = subprocess.run(cmd, check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    folder = dest / path if path else dest
    commit = subprocess.run(["git", f"--git-dir={git_dir}", "rev-parse", "HEAD"], check=True,
                            capture_output=True, text=True).stdout.strip()
    print(f"{folder}: {len(_read_list(folder / 'rgb.txt'))} colour / {len(_read_list(folder / 'depth.txt'))} "
          f"depth images listed (commit {commit})")
    return folder


# --------------------------------------------------------------------------------------------- prepare
def _read_list(path: Path) -> list[tuple[str, str]]:
    """(stamp text, relative file) of a TUM list file, in file order."""
    out = []
    for line in path.read_text(encoding="utf-8").splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            parts = line.split()
            out.append((parts[0], parts[1]))
    return out


def _increasing(stamps: list[float]) -> bool:
    return all(b > a for a, b in itertools.pairwise(stamps))


def _quat_xyzw(r: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(r).as_quat()


def estimate_poses(pairs: list[tuple[Path, Path]], intrinsics: tuple[float, float, float, float],
                   depth_scale: float, max_depth: float = 3.0, key_translation: float = 0.10,
                   key_rotation_deg: float = 10.0) -> tuple[list[np.ndarray], list[int], dict[str, Any]]:
    """Camera-to-world poses (first frame = world) by Open3D RGB-D odometry against the last keyframe.

    Each frame is registered to the current keyframe, starting from the previous frame's pose (constant
    position); when that fails, to the previous frame; when both fail the frame keeps the previous pose
    and its index is returned in ``failed``. A frame more than ``key_translation`` / ``key_rotation_deg``
    from its keyframe becomes the next keyframe.
    """
    import cv2
    import open3d as o3d

    odo = o3d.pipelines.odometry
    fx, fy, cx, cy = intrinsics
    first = cv2.imread(str(pairs[0][1]), cv2.IMREAD_UNCHANGED)
    h, w = first.shape[:2]
    intr = o3d.camera.PinholeCameraIntrinsic(w, h, fx, fy, cx, cy)
    option = odo.OdometryOption(o3d.utility.IntVector([20, 10, 5]), 0.07, 0.2, max_depth)
    jac = odo.RGBDOdometryJacobianFromHybridTerm()

    def load(i: int):
        c = cv2.cvtColor(cv2.imread(str(pairs[i][0]), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        d = cv2.imread(str(pairs[i][1]), cv2.IMREAD_UNCHANGED)
        d = np.where(d == 65535, 0, d).astype(np.uint16)
        return o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(np.ascontiguousarray(c)), o3d.geometry.Image(d), depth_scale=depth_scale,
            depth_trunc=max_depth, convert_rgb_to_intensity=True)

    poses = [np.eye(4)]
    failed: list[int] = []
    key_i, key_img = 0, load(0)
    prev_img = key_img
    keyframes = 1
    for i in range(1, len(pairs)):
        img = load(i)
        key_pose = poses[key_i]
        init = np.linalg.inv(key_pose) @ poses[-1]  # current -> keyframe, guessed as the previous frame's
        ok, t_key, _ = odo.compute_rgbd_odometry(img, key_img, intr, init, jac, option)
        if ok:
            pose = key_pose @ t_key
        else:
            ok, t_prev, _ = odo.compute_rgbd_odometry(img, prev_img, intr, np.eye(4), jac, option)
            pose = poses[-1] @ t_prev if ok else poses[-1].copy()
            if not ok:
                failed.append(i)
        poses.append(pose)
        rel = np.linalg.inv(key_pose) @ pose
        angle = np.degrees(np.arccos(np.clip((np.trace(rel[:3, :3]) - 1) / 2, -1.0, 1.0)))
        if np.linalg.norm(rel[:3, 3]) > key_translation or angle > key_rotation_deg or not ok:
            key_i, key_img = i, img
            keyframes += 1
        prev_img = img
    path = sum(float(np.linalg.norm(b[:3, 3] - a[:3, 3])) for a, b in itertools.pairwise(poses))
    return poses, failed, {"keyframes": keyframes, "path_length_m": round(path, 3)}


def prepare(src: Path, out: Path, intrinsics: tuple[float, float, float, float] | None, depth_scale: float | None,
            fps: float = 30.0, max_frames: int | None = None, force_odometry: bool = False) -> dict[str, Any]:
    """A readable copy of the TUM-format folder ``src`` in ``out`` (see the module doc)."""
    src, out = src.resolve(), out.resolve()
    rgb, depth = _read_list(src / "rgb.txt"), _read_list(src / "depth.txt")
    report: dict[str, Any] = {"source": str(src), "rgb_listed": len(rgb), "depth_listed": len(depth)}
    rgb_t, depth_t = [float(s) for s, _ in rgb], [float(s) for s, _ in depth]
    stamps_ok = _increasing(rgb_t) and _increasing(depth_t)
    report["stamps_increasing"] = stamps_ok
    if stamps_ok:
        pairs_named = None  # keep the recording's own stamps; the loader associates by nearest stamp
    else:
        if len(rgb) != len(depth):
            raise SystemExit(f"{src}: stamps do not increase and rgb.txt ({len(rgb)}) / depth.txt ({len(depth)}) "
                             "differ in length: no safe pairing")
        bad = sum(1 for a, b in itertools.pairwise(depth_t) if b <= a)
        report["stamps_going_back"] = bad
        report["stamps_rewritten"] = f"i / {fps:g} s, colour and depth paired by list order"
        pairs_named = [(r, d) for (_, r), (_, d) in zip(rgb, depth, strict=True)]
        if max_frames:
            pairs_named = pairs_named[:max_frames]
    out.mkdir(parents=True, exist_ok=True)
    for sub in {Path(f).parts[0] for _, f in rgb + depth if len(Path(f).parts) > 1}:
        link = out / sub
        if link.is_symlink() or link.exists():
            link.unlink() if link.is_symlink() else None
        if not link.exists():
            os.symlink(src / sub, link)
    if pairs_named is not None:
        stamps = [f"{i / fps:.6f}" for i in range(len(pairs_named))]
        (out / "rgb.txt").write_text("# color images (stamps rewritten by real_tum.py prepare)\n# timestamp filename\n"
                                     + "".join(f"{s} {r}\n" for s, (r, _) in zip(stamps, pairs_named, strict=True)))
        (out / "depth.txt").write_text("# depth maps (stamps rewritten by real_tum.py prepare)\n# timestamp filename\n"
                                       + "".join(f"{s} {d}\n" for s, (_, d) in zip(stamps, pairs_named, strict=True)))
        pose_pairs = [(src / r, src / d) for r, d in pairs_named]
        pose_stamps = stamps
    else:
        for name in ("rgb.txt", "depth.txt"):
            (out / name).write_text((src / name).read_text(encoding="utf-8"))
        pose_pairs = [(src / r, src / d) for (_, r), (_, d) in zip(rgb, depth, strict=False)]
        pose_stamps = [s for s, _ in rgb][: len(pose_pairs)]
    if intrinsics is not None or depth_scale is not None:
        cam = {}
        if intrinsics is not None:
            cam.update(dict(zip(("fx", "fy", "cx", "cy"), intrinsics, strict=True)))
        if depth_scale is not None:
            cam["depth_scale"] = depth_scale
        if "fx" not in cam:
            raise SystemExit("--depth-scale needs --intrinsics too (camera.yaml holds both)")
        (out / "camera.yaml").write_text("".join(f"{k}: {v}\n" for k, v in cam.items()))
        report["camera"] = cam
    gt = src / "groundtruth.txt"
    if gt.is_file() and not force_odometry and pairs_named is None:
        (out / "groundtruth.txt").write_text(gt.read_text(encoding="utf-8"))
        report["poses"] = "the recording's groundtruth.txt"
    else:
        if intrinsics is None:
            raise SystemExit("estimating poses needs --intrinsics")
        scale = depth_scale if depth_scale is not None else 5000.0
        import time

        t0 = time.perf_counter()
        poses, failed, stats = estimate_poses(pose_pairs, intrinsics, scale)
        lines = ["# camera-to-world poses estimated by real_tum.py prepare (Open3D RGB-D odometry)",
                 "# timestamp tx ty tz qx qy qz qw"]
        for s, p in zip(pose_stamps, poses, strict=True):
            q = _quat_xyzw(p[:3, :3])
            lines.append(f"{s} " + " ".join(f"{v:.6f}" for v in (*p[:3, 3], *q)))
        (out / "groundtruth.txt").write_text("\n".join(lines) + "\n")
        report["poses"] = "estimated: Open3D RGB-D odometry (hybrid term) against the last keyframe"
        report["odometry"] = {**stats, "frames": len(poses), "failed_frames": failed,
                              "seconds": round(time.perf_counter() - t0, 1)}
    (out / "prepare.json").write_text(json.dumps(report, indent=1, allow_nan=False))
    print(json.dumps(report, indent=1))
    return report


def read_tum_poses(folder: Path) -> tuple[list[str], list[np.ndarray]]:
    """(depth file per pose, camera-to-world 4x4) of a prepared folder whose stamps match line by line."""
    from scipy.spatial.transform import Rotation

    depth = _read_list(folder / "depth.txt")
    poses = []
    for line in (folder / "groundtruth.txt").read_text(encoding="utf-8").splitlines():
        if line.strip() and not line.startswith("#"):
            v = [float(x) for x in line.split()[1:]]
            t = np.eye(4)
            t[:3, :3] = Rotation.from_quat(v[3:]).as_matrix()
            t[:3, 3] = v[:3]
            poses.append(t)
    return [f for _, f in depth][: len(poses)], poses


def depth_consistency(folder: Path, gaps: tuple[int, ...] = (5, 20, 60), every: int = 15,
                      max_depth: float = 3.0) -> dict[str, float]:
    """A ground-truth-free check of a prepared folder's poses: frame i's depth pixels (every 7th) moved
    into frame i + gap with the poses; the median |depth there - moved depth| over pixels seen in both,
    then the median over i (every ``every``-th frame). Good poses give a few mm (depth noise); drift or a
    wrong focal length shows as centimetres growing with the gap."""
    import cv2
    import yaml

    cam = yaml.safe_load((folder / "camera.yaml").read_text())
    fx, fy, cx, cy, scale = (float(cam[k]) for k in ("fx", "fy", "cx", "cy", "depth_scale"))
    files, poses = read_tum_poses(folder)

    def depth(i: int) -> np.ndarray:
        z = cv2.imread(str(folder / files[i]), cv2.IMREAD_UNCHANGED).astype(np.float64) / scale
        z[(z < 0.2) | (z > max_depth)] = 0
        return z

    out = {}
    for gap in gaps:
        meds = []
        for i in range(0, len(poses) - gap, every):
            zi, zj = depth(i), depth(i + gap)
            v, u = np.nonzero(zi)
            v, u = v[::7], u[::7]
            z = zi[v, u]
            p = np.stack([(u - cx) * z / fx, (v - cy) * z / fy, z, np.ones_like(z)], axis=1)
            q = (np.linalg.inv(poses[i + gap]) @ poses[i] @ p.T).T
            front = q[:, 2] > 0.2
            q = q[front]
            uu = np.round(q[:, 0] / q[:, 2] * fx + cx).astype(int)
            vv = np.round(q[:, 1] / q[:, 2] * fy + cy).astype(int)
            inside = (uu >= 0) & (uu < zj.shape[1]) & (vv >= 0) & (vv < zj.shape[0])
            seen = zj[vv[inside], uu[inside]]
            dz = np.abs(seen - q[inside, 2])[seen > 0]
            if len(dz):
                meds.append(float(np.median(dz)))
        out[f"gap_{gap}_median_m"] = round(float(np.median(meds)), 4) if meds else float("nan")
    return out


# --------------------------------------------------------------------------------------------- measure
def _map_faces(run_dir: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centroids, unit normals and areas of every map mesh's faces (map frame, +z up)."""
    import open3d as o3d

    cs, ns, areas = [], [], []
    for ply in sorted((run_dir / "map" / "meshes").glob("*.ply")):
        mesh = o3d.io.read_triangle_mesh(str(ply))
        if not len(mesh.triangles):
            continue
        mesh.compute_triangle_normals()
        v, f = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
        tri = v[f]
        cs.append(tri.mean(axis=1))
        ns.append(np.asarray(mesh.triangle_normals))
        areas.append(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1) / 2)
    if not cs:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)
    return np.concatenate(cs), np.concatenate(ns), np.concatenate(areas)


def camera_heights(data: Path, run_dir: Path) -> list[float]:
    """Heights of the recording's camera positions in the map frame (groundtruth.txt through the map's
    gravity alignment)."""
    align = np.array(json.loads((run_dir / "map" / "map.json").read_text())["gravity_alignment"])
    zs = []
    for line in (data / "groundtruth.txt").read_text(encoding="utf-8").splitlines():
        if line.strip() and not line.startswith("#"):
            t = [float(v) for v in line.split()[1:4]]
            zs.append(float((align @ np.array([*t, 1.0]))[2]))
    return zs


def floor_levelness(run_dir: Path, data: Path | None = None, distance: float = 0.02) -> dict[str, Any]:
    """Ground-truth-free checks of the floor the contact graph derived (its ``floor`` node):

    * ``plane_z_m``: the height of the node's largest plane; ``up_share``: of the map's horizontal faces
      within 5 cm of it, the area share whose normal points up (a TSDF surface faces the free space it was
      seen from: a floor faces up, a ceiling down);
    * ``tilt_deg``: the angle from +z of the RANSAC plane (2 cm) fitted to the map vertices within 5 cm
      of that height: how level the surface taken for the floor is in the gravity-aligned map;
    * ``cameras_z_m`` (with ``data``): the camera heights; a floor above the cameras cannot be one.
    """
    import open3d as o3d

    graph = json.loads((run_dir / "graph" / "contact_graph.json").read_text())
    node = next((n for n in graph.get("nodes", []) if n.get("class_name") == "floor"), None)
    if node is None:
        return {"ok": False, "reason": "the contact graph has no floor node"}
    planes = [pl for pl in node.get("planes") or [] if abs(pl["normal"][2]) > 0.99]
    if planes:
        best = max(planes, key=lambda pl: pl.get("area", 0.0))
        z = -best["d"] / best["normal"][2]
    else:
        z = node["box"]["center"][2] + node["box"]["size"][2] / 2
    c, n, a = _map_faces(run_dir)
    near = (np.abs(c[:, 2] - z) <= 0.05) & (np.abs(n[:, 2]) >= 0.9)
    out: dict[str, Any] = {"ok": True, "plane_z_m": round(float(z), 3),
                           "horizontal_area_m2": round(float(a[near].sum()), 3),
                           "up_share": round(float(a[near & (n[:, 2] > 0)].sum() / max(a[near].sum(), 1e-9)), 3),
                           "box_size_m": [round(float(v), 2) for v in node["box"]["size"]]}
    if near.sum() >= 50:
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(c[near]))
        model, inl = pcd.segment_plane(distance, 3, 1000)
        nrm = np.asarray(model[:3]) / np.linalg.norm(model[:3])
        out["tilt_deg"] = round(float(np.degrees(np.arccos(min(1.0, abs(nrm[2]))))), 2)
        out["tilt_inliers"] = len(inl)
    if data is not None and (data / "groundtruth.txt").is_file():
        zs = camera_heights(data, run_dir)
        out["cameras_z_m"] = [round(min(zs), 3), round(max(zs), 3)]
        out["floor_below_cameras"] = bool(z < min(zs))
    return out


def measure_run(run_dir: Path, physics: bool = True, data: Path | None = None) -> dict[str, Any]:
    out = real_kitchen.measure(run_dir / "scene", physics=physics)
    out["floor_levelness"] = floor_levelness(run_dir, data)
    summary = json.loads((run_dir / "map" / "summary.json").read_text())
    out["gravity"] = {k: summary.get("gravity", {}).get(k) for k in ("note", "applied", "rotation_deg")}
    out["gravity"]["estimate"] = summary.get("gravity", {}).get("estimate")
    out["map_run"] = {k: summary.get("run", {}).get(k) for k in ("frames", "keyframes", "wall_s", "skipped")}
    graph = json.loads((run_dir / "graph" / "contact_graph.json").read_text())
    nodes = graph.get("nodes", [])
    out["graph_nodes"] = [f"{n.get('name', n.get('id'))}:{n.get('class_name', n.get('class', ''))}" for n in nodes]
    return out


def picture(run_dir: Path, dest: Path, max_bytes: int = 500_000) -> None:
    """The run's before_after.png (map entities | replaced scene), shrunk until it is under ``max_bytes``."""
    real_kitchen.picture(run_dir / "scene", dest, max_bytes)


def _print(m: dict[str, Any]) -> None:
    real_kitchen._print(m)
    fl = m["floor_levelness"]
    if fl.get("ok"):
        print(f"  floor node: plane z = {fl['plane_z_m']} m, {fl['horizontal_area_m2']} m^2 of horizontal map "
              f"faces there, {100 * fl['up_share']:.0f} % facing up, tilt {fl.get('tilt_deg')} deg; cameras at "
              f"z = {fl.get('cameras_z_m')} m (floor below them: {fl.get('floor_below_cameras')})")
    else:
        print(f"  floor: {fl.get('reason')}")
    print(f"  gravity: {m['gravity'].get('note')}")
    print(f"  map: {m['map_run']}")
    print(f"  graph nodes: {', '.join(m['graph_nodes'])}")


def _floats(text: str, n: int) -> tuple[float, ...]:
    vals = tuple(float(v) for v in text.split(","))
    if len(vals) != n:
        raise argparse.ArgumentTypeError(f"expected {n} comma-separated numbers, got {text!r}")
    return vals


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    f = sub.add_parser("fetch")
    f.add_argument("--git", type=Path, required=True, help="git directory of the repository's snapshot")
    f.add_argument("--path", help="the TUM folder inside the repository (default: its root)")
    f.add_argument("--dest", type=Path, required=True)
    pr = sub.add_parser("prepare")
    pr.add_argument("src", type=Path)
    pr.add_argument("--out", type=Path, required=True)
    pr.add_argument("--intrinsics", type=lambda s: _floats(s, 4), help="fx,fy,cx,cy of the (registered) camera")
    pr.add_argument("--depth-scale", type=float, help="depth PNG units per metre (RealSense: 1000)")
    pr.add_argument("--fps", type=float, default=30.0, help="rate for rewritten stamps (default 30)")
    pr.add_argument("--max-frames", type=int)
    pr.add_argument("--odometry", action="store_true", help="estimate poses even when groundtruth.txt exists")
    r = sub.add_parser("run")
    r.add_argument("--data", type=Path, required=True)
    r.add_argument("--model", type=Path, required=True)
    r.add_argument("--out", type=Path, required=True)
    r.add_argument("--stride", type=int, default=2)
    r.add_argument("--preset", help="scene-recon preset (name or YAML), e.g. accurate")
    c = sub.add_parser("check-poses", help="depth consistency of a prepared folder's poses (no ground truth)")
    c.add_argument("folder", type=Path)
    m = sub.add_parser("measure")
    m.add_argument("runs", type=Path, nargs="+", help="scene-recon run output folders (map/, graph/, scene/)")
    m.add_argument("--no-physics", action="store_true")
    m.add_argument("--data", type=Path, help="the prepared folder (camera heights from its groundtruth.txt)")
    m.add_argument("--json", type=Path, help="write the figures here")
    m.add_argument("--picture", type=Path, help="copy the first run's before_after.png here (< 500 KB)")
    args = p.parse_args(argv)
    if args.cmd == "fetch":
        fetch(args.git, args.dest, args.path)
        return 0
    if args.cmd == "prepare":
        prepare(args.src, args.out, args.intrinsics, args.depth_scale, args.fps, args.max_frames, args.odometry)
        return 0
    if args.cmd == "check-poses":
        print(json.dumps(depth_consistency(args.folder)))
        return 0
    if args.cmd == "run":
        if not args.preset:
            return real_kitchen.run(args.data, args.model, args.out, args.stride)
        cmd = [sys.executable, "-m", "scene_recon.cli", "run", str(args.data), "--out", str(args.out), "--model",
               str(args.model), "--stride", str(args.stride), "--preset", args.preset]
        print("$", " ".join(cmd), flush=True)
        return subprocess.call(cmd, cwd=ROOT)
    results = [measure_run(run, physics=not args.no_physics, data=args.data) for run in args.runs]
    for res in results:
        _print(res)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1, allow_nan=False, default=str))
    if args.picture:
        picture(args.runs[0], args.picture)
    return 0


if __name__ == "__main__":
    sys.exit(main())
