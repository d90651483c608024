#!/usr/bin/env python3
"""Issue 24's done-when measurement: the ROS graph on a loaded machine gives the offline scene, N runs of N.

    ROS_DOMAIN_ID=42 .venv/bin/python tools/ros_under_load.py --out out/ros_under_load [--runs 5] \
        [--objects 8 --frames 60 --width 640 --height 480] [--busy 2] [--modes ros-run,launch]

1. `scene-recon generate` writes the bag (seed 0: 8 objects with a fridge and its two doors), `scene-recon run`
   gives the offline scene on it.
2. `--busy` busy loops (`python -c 'while 1: pass'`) load the machine; they are killed at the end.
3. `--runs` times each mode: `scene-recon ros-run --bag` (it exports the settled scene itself), and
   `ros2 launch scene_recon bag.launch.py` through the upstream tooling of ../shared/ros2-upstream
   (`build_prefix.sh` into OUT/upstream, or `--ros2-prefix`; this package in an ament prefix laid out as
   colcon installs it), settled by the runner's own rule, exported with
   `ros2 service call /export_scene std_srvs/srv/Trigger` and stopped with one SIGINT to its process group.
4. Prints one row per run: exit status, seconds, frames integrated, keyframes labelled, failed segmentation
   requests in the log, and whether the objects (name, class), CAD choices and the URDF's movable joints equal
   the offline scene's; writes OUT/results.json.

DDS stays on loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) on the caller's ROS_DOMAIN_ID (default 42).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
UPSTREAM = next((p for p in (ROOT.parent / "shared" / "ros2-upstream", Path("/work/shared/ros2-upstream"))
                 if (p / "build_prefix.sh").is_file()), ROOT.parent / "shared" / "ros2-upstream")
EXECUTABLES = ("rgbd_player", "segmentation_service", "panoptic_mapper", "contact_graph_node", "cad_replacer")
FAILED_LABELS = re.compile(r"no ground-truth label image|request failed|segmentation failed|segmentation call "
                           r"failed|without labels")
UNLABELLED = ("keyframes_unsegmented", "segmentation_timeout", "segmentation_failed")


def scene_of(folder: Path) -> tuple[dict[str, tuple], list[tuple]]:
    """An exported scene: name -> (class, CAD model) and the URDF's movable joints (name, type)."""
    detail = json.loads((folder / "replacement.json").read_text())["objects_detail"]
    joints = sorted(j for j in re.findall(r'<joint name="([^"]*)" type="([^"]*)"', (folder / "scene.urdf").read_text())
                    if j[1] != "fixed")
    return {r["name"]: (r["class_name"], r.get("cad_id")) for r in detail}, joints


def compare(folder: Path, offline: tuple[dict, list]) -> dict:
    if not (folder / "scene.urdf").is_file():
        return {"objects": False, "cad": False, "joints": False, "n_objects": 0, "n_joints": 0}
    objects, joints = scene_of(folder)
    return {"objects": {n: c for n, (c, _) in objects.items()} == {n: c for n, (c, _) in offline[0].items()},
            "cad": objects == offline[0], "joints": joints == offline[1], "n_objects": len(objects),
            "n_joints": len(joints)}


def counters_of(log: str) -> dict:
    """The mapper's last logged counters."""
    found = re.findall(r"counters (\{[^}]*\})", log)
    return json.loads(found[-1].replace("'", '"')) if found else {}


def labelled(counters: dict) -> str:
    return f"{counters.get('segmented_keyframes', 0)}/{counters.get('segmentation_calls', 0)}"


def run_ros_run(bag: str, out: Path, env: dict, seeds: str) -> dict:
    t0 = time.monotonic()
    run = subprocess.run([sys.executable, "-m", "scene_recon.cli", "ros-run", "--bag", bag, "--out", str(out),
                          "--seeds-per-class", seeds], env=env, capture_output=True, text=True, timeout=900,
                         cwd=out.parent)
    log = run.stdout + run.stderr
    (out.parent / f"{out.name}.log").write_text(log)
    frames = 0
    meta = out / "map" / "final" / "map.json"
    if meta.is_file():
        frames = json.loads(meta.read_text()).get("frames_integrated", 0)
    c = counters_of(log)
    return {"exit": run.returncode, "s": round(time.monotonic() - t0, 1), "frames": frames, "keyframes": labelled(c),
            "unlabelled": sum(c.get(k, 0) for k in UNLABELLED), "failed_requests": len(FAILED_LABELS.findall(log)),
            "clean_stop": "Traceback" not in log and "never retrieved" not in log and run.returncode == 0}


def ros2_prefix_env(dest: Path, pkg: Path, domain: str) -> dict:
    """Upstream prefix (built when missing) + this package in an ament prefix at `pkg`, sourced."""
    build = subprocess.run(["bash", str(UPSTREAM / "build_prefix.sh"), sys.prefix, str(dest)], capture_output=True,
                           text=True, timeout=900)
    if build.returncode != 0:
        raise SystemExit(f"build_prefix.sh failed:\n{build.stdout[-2000:]}{build.stderr[-2000:]}")
    shutil.rmtree(pkg, ignore_errors=True)
    (pkg / "share" / "ament_index" / "resource_index" / "packages").mkdir(parents=True)
    (pkg / "share" / "ament_index" / "resource_index" / "packages" / "scene_recon").touch()
    shutil.copytree(ROOT / "launch", pkg / "share" / "scene_recon" / "launch")
    shutil.copy(ROOT / "package.xml", pkg / "share" / "scene_recon" / "package.xml")
    (pkg / "lib" / "scene_recon").mkdir(parents=True)
    for exe in EXECUTABLES:
        (pkg / "lib" / "scene_recon" / exe).symlink_to(Path(sys.prefix) / "bin" / exe)
    sourced = subprocess.run(["bash", "-c", f". {dest / 'env.sh'} && env -0"], capture_output=True, check=True)
    env = dict(item.split("=", 1) for item in sourced.stdout.decode().split("\0") if "=" in item)
    env["AMENT_PREFIX_PATH"] = f"{pkg}:{env['AMENT_PREFIX_PATH']}"
    env.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=domain)
    return env


def run_launch(bag: str, out: Path, env: dict, seeds: str, frames: int, monitor_factory) -> dict:
    from scene_recon.ros_runner.processes import interrupt_group

    t0 = time.monotonic()
    proc = subprocess.Popen(["ros2", "launch", "scene_recon", "bag.launch.py", f"bag:={bag}", f"out:={out}",
                             f"seeds_per_class:={seeds}"], env=env, cwd=out.parent, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(proc.stdout.readline, "")), daemon=True)
    reader.start()
    monitor = monitor_factory()
    status: dict = {}
    exported = False
    try:
        deadline, played_at = time.monotonic() + 600, None
        while time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.5)
            if played_at is None and any(re.search(r"played \d+ frames", line) for line in lines):
                played_at = time.monotonic()
            if played_at is not None and monitor.settled(played_at, 3.0):
                break
        status = monitor.snapshot().status or {}
        if proc.poll() is None:
            call = subprocess.run(["ros2", "service", "call", "/export_scene", "std_srvs/srv/Trigger"], env=env,
                                  capture_output=True, text=True, timeout=300)
            exported = call.returncode == 0 and "success=True" in call.stdout
            lines.append(f"[export_scene call] {call.stdout}{call.stderr}")
    finally:
        monitor.close()
        code = interrupt_group(proc, 120)
        reader.join(timeout=10)
    log = "".join(lines)
    (out.parent / f"{out.name}.log").write_text(log)
    c = status.get("counters") or counters_of(log)
    clean = code == 0 and "Traceback" not in log and "never retrieved" not in log and all(
        re.search(rf"\[{name}-\d+\]: process has finished cleanly", log) for name in EXECUTABLES)
    return {"exit": code if exported else f"{code} (no export)", "s": round(time.monotonic() - t0, 1),
            "frames": status.get("frames_integrated", 0), "keyframes": labelled(c),
            "unlabelled": sum(c.get(k, 0) for k in UNLABELLED), "failed_requests": len(FAILED_LABELS.findall(log)),
            "clean_stop": clean, "expected_frames": frames}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=Path("out/ros_under_load"))
    p.add_argument("--runs", type=int, default=5)
    p.add_argument("--objects", type=int, default=8)
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--seeds-per-class", default="3", help="procedural CAD models per class (all runs alike)")
    p.add_argument("--busy", type=int, default=2, help="busy loops loading the machine during the ROS runs")
    p.add_argument("--modes", default="ros-run,launch")
    p.add_argument("--ros2-prefix", type=Path, help="a folder build_prefix.sh built before (default OUT/upstream)")
    args = p.parse_args()
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    domain = os.environ.get("ROS_DOMAIN_ID", "42")
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=domain)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    cli = [sys.executable, "-m", "scene_recon.cli"]
    rec = out / "rec"
    if not (rec / "metadata.yaml").is_file():
        shutil.rmtree(rec, ignore_errors=True)
        shutil.rmtree(out / "rec_groundtruth", ignore_errors=True)
        subprocess.run([*cli, "generate", "--out", str(rec), "--seed", str(args.seed), "--objects",
                        str(args.objects), "--frames", str(args.frames), "--width", str(args.width), "--height",
                        str(args.height)], env=env, check=True, capture_output=True)
    if not (out / "offline" / "scene" / "scene.urdf").is_file():
        subprocess.run([*cli, "run", str(rec), "--out", str(out / "offline"), "--seeds-per-class",
                        args.seeds_per_class], env=env, check=True, capture_output=True)
    offline = scene_of(out / "offline" / "scene")
    print(f"offline scene: {len(offline[0])} objects, movable joints {offline[1]}", flush=True)
    modes = args.modes.split(",")
    launch_env = None
    if "launch" in modes:
        launch_env = ros2_prefix_env(args.ros2_prefix or out / "upstream", out / "scene_recon_prefix", domain)
    from scene_recon.ros_runner.monitor import GraphMonitor

    busy = [subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(args.busy)]
    rows = []
    try:
        for mode in modes:
            for i in range(1, args.runs + 1):
                folder = out / f"{mode}_{i}"
                shutil.rmtree(folder, ignore_errors=True)
                folder.mkdir()
                if mode == "ros-run":
                    row = run_ros_run(str(rec), folder, env, args.seeds_per_class)
                else:
                    row = run_launch(str(rec), folder, launch_env, args.seeds_per_class, args.frames, GraphMonitor)
                row.update(mode=mode, run=i, **compare(folder / "scene", offline))
                row["same"] = bool(row["objects"] and row["cad"] and row["joints"] and row["frames"] == args.frames
                                   and row["failed_requests"] == 0 and row["clean_stop"])
                rows.append(row)
                print(f"{mode} {i}: {row}", flush=True)
    finally:
        for b in busy:
            b.kill()
            b.wait()
    (out / "results.json").write_text(json.dumps({"args": {k: str(v) for k, v in vars(args).items()},
                                                  "offline": {"objects": len(offline[0]), "joints": offline[1]},
                                                  "runs": rows}, indent=1))
    head = ("mode", "run", "exit", "s", "frames", "keyframes labelled", "failed req.", "objects", "CAD", "joints",
            "clean stop", "offline scene")
    print("\n| " + " | ".join(head) + " |\n|" + "---|" * len(head))
    for r in rows:
        cells = (r["mode"], r["run"], r["exit"], r["s"], f"{r['frames']}/{args.frames}", r["keyframes"],
                 r["failed_requests"], r["objects"], r["cad"], r["joints"], r["clean_stop"], r["same"])
        print("| " + " | ".join(str(c) for c in cells) + " |")
    for mode in modes:
        same = sum(r["same"] for r in rows if r["mode"] == mode)
        print(f"{mode}: {same} of {args.runs} runs gave the offline scene")
    return 0 if all(r["same"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
