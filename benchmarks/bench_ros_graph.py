"""The ROS 2 graph end to end: a generated bag played through the four node processes (`scene-recon ros-run`).

Reports the latency from the bag's last frame to the last published URDF, the time to the exported
scene, and per node the CPU time and peak memory (from /proc, start-up included); and, on the same bag,
the wall time of the offline `scene-recon run` and whether both scenes agree (objects, classes, CAD
choices). DDS stays on loopback; the domain is ROS_DOMAIN_ID if set (else 77, as `make bench`).

    .venv/bin/python benchmarks/bench_ros_graph.py [--frames 60] [--objects 6] [--width 320]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.common import write_result  # noqa: E402
from scene_recon.synthetic.generate import GenerateConfig, generate_recording  # noqa: E402


def _objects(scene: Path) -> dict[str, tuple]:
    detail = json.loads((scene / "replacement.json").read_text())["objects_detail"]
    return {r["name"]: (r["class_name"], r.get("cad_id")) for r in detail}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--objects", type=int, default=6)
    ap.add_argument("--width", type=int, default=320, help="image width (height 3/4 of it)")
    ap.add_argument("--seed", type=int, default=3)
    args = ap.parse_args()
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_DOMAIN_ID=os.environ.get("ROS_DOMAIN_ID", "77"),
               PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        cfg = GenerateConfig(objects=args.objects, frames=args.frames, seed=args.seed)
        cam = cfg.sensor.camera
        scale = args.width / cam.width
        cam.width, cam.height = args.width, round(cam.height * scale)
        cam.fx, cam.fy, cam.cx, cam.cy = cam.fx * scale, cam.fy * scale, (cam.width - 1) / 2, (cam.height - 1) / 2
        rec = generate_recording(tmp_path / "rec", cfg, progress=False)
        cli = [sys.executable, "-m", "scene_recon.cli"]
        t0 = time.perf_counter()
        offline = subprocess.run([*cli, "run", rec["bag"], "--out", str(tmp_path / "offline")], env=env,
                                 capture_output=True, text=True)
        offline_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        ros = subprocess.run([*cli, "ros-run", "--bag", rec["bag"], "--out", str(tmp_path / "ros"), "--quiet-nodes"],
                             env=env, capture_output=True, text=True)
        ros_s = time.perf_counter() - t0
        if offline.returncode or ros.returncode:
            print(offline.stdout[-2000:], offline.stderr[-2000:], ros.stdout[-3000:], ros.stderr[-2000:])
            return 1
        run = json.loads((tmp_path / "ros" / "ros" / "run.json").read_text())
        same = _objects(tmp_path / "ros" / "scene") == _objects(tmp_path / "offline" / "scene")
        objects = len(_objects(tmp_path / "ros" / "scene"))
    recording_s = args.frames / cfg.fps
    print(f"{args.frames} frames {cam.width}x{cam.height} ({recording_s:.1f} s of recording), {objects} objects")
    print(f"scene-recon run (offline):         {offline_s:6.1f} s")
    print(f"scene-recon ros-run (4 nodes):     {ros_s:6.1f} s in all, scene exported {run['exported_s']:.1f} s "
          f"after the start; frames integrated {run['frames_integrated']}, dropped {run['dropped_frames']}")
    print(f"last bag frame -> last URDF:       {run['last_frame_to_urdf_s']:6.1f} s (scene revision {run['revision']})")
    for name, u in run["nodes"].items():
        cpu, rss = u.get("cpu_s", float("nan")), u.get("peak_rss_mib", float("nan"))
        print(f"  {name:<22} CPU {cpu:6.2f} s   peak RSS {rss:7.1f} MiB")
    print(f"same scene as the offline run: {same}")
    path = write_result("ros_graph", {
        "frames": args.frames, "resolution": [cam.width, cam.height], "objects": objects, "offline_s": offline_s,
        "ros_run_s": ros_s, "exported_s": run["exported_s"], "last_frame_to_urdf_s": run["last_frame_to_urdf_s"],
        "frames_integrated": run["frames_integrated"], "dropped_frames": run["dropped_frames"],
        "nodes": run["nodes"], "same_scene_as_offline": same})
    print(f"wrote {path}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
