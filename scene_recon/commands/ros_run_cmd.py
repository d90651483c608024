"""`scene-recon ros-run --bag PATH | --live --out DIR`: the four ROS 2 nodes (+ the player) as processes.

The same nodes with the same parameters as `launch/bag.launch.py` and `launch/reconstruct.launch.py`
(both read `recon_core.ros_graph`), for this project's own environment where `ros2 launch` does not
exist. Playing a bag, the runner waits until the recording has been played and the scene has
settled, exports it into OUT/scene and stops (`--keep-running`: stays up for planners until Ctrl-C);
live, it runs until Ctrl-C / SIGTERM, then exports and stops. Either way the nodes shut down in
order and the scene folder stays behind.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from pathlib import Path

from recon_core.ros_graph import BACKENDS, GraphOptions, graph_nodes
from scene_recon.commands.common import add_preset_option

#: Exit status when the graph ran but produced no scene to export.
EXIT_NO_SCENE = 3
#: Where (under the mapper's data root OUT/map) the final map is saved.
FINAL_MAP = "final"
#: How long (s) saving the map and exporting the scene may take each (a stuck node must not hold up Ctrl-C).
EXPORT_TIMEOUT_S = 30.0
#: The player lets reliable subscribers drain this long (s) after its last frame before it exits.
PLAYER_DRAIN_S = 0.5


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "ros-run",
        help="the whole pipeline as ROS 2 nodes (separate processes) on a bag or a live camera",
        description="Start the segmentation service, panoptic mapper, contact graph and CAD replacer nodes "
        "(and, with --bag, the player publishing /clock) as separate processes with the launch files' "
        "parameters; their logs are forwarded with a [node] prefix. With --bag: exports the scene into "
        "OUT/scene once the recording is played and the scene has settled, then stops. With --live: runs "
        "until Ctrl-C, exports, stops. ROS_DOMAIN_ID / ROS_AUTOMATIC_DISCOVERY_RANGE are taken from your "
        "environment as they are.",
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--bag", metavar="PATH", help="ROS 2 bag (.mcap/.db3/folder) or frame folder to play")
    src.add_argument("--live", action="store_true", help="a camera driver publishes the topics (see --color-topic)")
    p.add_argument("--out", required=True, help="output folder: OUT/scene (URDF, MJCF, GLB), OUT/map (checkpoints), "
                   "OUT/ros (parameter files, node logs)")
    p.add_argument("--rate", type=float, default=1.0, help="bag: playback speed factor")
    p.add_argument("--loop", action="store_true", help="bag: play in a loop (runs until Ctrl-C)")
    p.add_argument("--start-offset", type=float, default=0.0, metavar="S", help="bag: skip the first S seconds")
    p.add_argument("--segmenter", choices=BACKENDS, default="auto",
                   help="auto (default): onnx with --model/--model-config, the oracle when the bag has ground "
                   "truth beside it, else none")
    p.add_argument("--model", metavar="ONNX", default="", help="exported detector/segmenter (onnx)")
    p.add_argument("--model-config", default="", help="ONNX model config YAML")
    p.add_argument("--classes", metavar="YAML", default="", help="class table (default config/classes.yaml)")
    p.add_argument("--ground-truth", default="", help="oracle: ground-truth folder (default: beside the bag)")
    p.add_argument("--noise", default="default", help="oracle noise level: clean | default | hard")
    p.add_argument("--config-dir", default="", metavar="DIR",
                   help="folder with mapper.yaml, segmentation.yaml, scene_graph.yaml (default: the package's)")
    p.add_argument("--color-topic", default=GraphOptions.color_topic)
    p.add_argument("--depth-topic", default=GraphOptions.depth_topic)
    p.add_argument("--camera-info-topic", default=GraphOptions.camera_info_topic)
    p.add_argument("--map-frame", default=GraphOptions.map_frame)
    p.add_argument("--camera-frame", default=GraphOptions.camera_frame, help="bag: frame id of images and poses")
    p.add_argument("--sim-time", choices=("auto", "true", "false"), default="auto",
                   help="use_sim_time of the nodes (auto: true with --bag, the player publishing /clock)")
    p.add_argument("--method", choices=("ours", "paper"), default="ours", help="CAD replacement method")
    p.add_argument("--seeds-per-class", type=int, default=10, metavar="N",
                   help="procedural CAD models per class (articulated classes and shelves: 2x, to cover their layouts)")
    p.add_argument("--keep-running", action="store_true",
                   help="bag: after exporting the scene, keep the nodes up (for planners) until Ctrl-C")
    p.add_argument("--settle", type=float, default=3.0, metavar="S",
                   help="bag: the scene is final once graph and URDF did not change for S seconds")
    p.add_argument("--settle-timeout", type=float, default=300.0, metavar="S",
                   help="bag: export anyway this long after the recording ended")
    p.add_argument("--respawn", type=int, default=3, metavar="N",
                   help="restart a node that dies up to N times (the mapper resumes from its newest checkpoint; "
                   "the others rejoin from the latched topics); 0: a dying node stops the run")
    p.add_argument("--quiet-nodes", action="store_true", help="do not forward the nodes' logs (still in OUT/ros/logs)")
    add_preset_option(p)  # the launch files' `preset:=NAME`: the same parameters (recon_core.ros_graph)
    p.set_defaults(func=run)


def graph_options(args: argparse.Namespace) -> GraphOptions:
    """The GraphOptions of a command line (the launch files build theirs from launch arguments; `auto`
    and the ground truth beside a bag are resolved by the shared description, the same for both)."""
    return GraphOptions(
        bag=str(Path(args.bag).resolve()) if args.bag else "", rate=args.rate, loop=args.loop,
        start_offset_s=args.start_offset, color_topic=args.color_topic, depth_topic=args.depth_topic,
        camera_info_topic=args.camera_info_topic, map_frame=args.map_frame, camera_frame=args.camera_frame,
        backend=args.segmenter, model=args.model, model_config=args.model_config, classes=args.classes,
        ground_truth=args.ground_truth, noise_level=args.noise, config_dir=args.config_dir,
        use_sim_time=None if args.sim_time == "auto" else args.sim_time == "true",
        out=str(Path(args.out).resolve()), seeds_per_class=args.seeds_per_class, method=args.method,
        preset=args.preset or "",
    )


def run(args: argparse.Namespace) -> int:
    from scene_recon.ros_runner.monitor import GraphMonitor
    from scene_recon.ros_runner.processes import LogSink, start_child, stop_children, usage

    opts = graph_options(args)
    out = Path(opts.out)
    run_dir = out / "ros"
    specs = graph_nodes(opts)
    stop = threading.Event()
    stop_reason: list[str] = []

    def on_signal(signum: int, _frame: object) -> None:
        stop_reason.append(signal.Signals(signum).name)
        stop.set()

    old = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    sink = LogSink(quiet=args.quiet_nodes)
    sink.width = max(len(s.name) for s in specs)
    say = _say
    say(f"{'bag ' + opts.bag if opts.bag else 'live'}: segmentation {opts.resolved_backend()}, preset "
        f"{opts.preset or 'none'}, sim time "
        f"{opts.sim_time()}, output {out}; nodes: {', '.join(s.name for s in specs)}")
    t_start = time.monotonic()
    monitor = GraphMonitor(opts.map_frame)
    children = []
    code = 0
    exported: str | None = None
    report: dict = {"options": vars(opts), "nodes": {}}
    try:
        for spec in specs:
            children.append(start_child(spec, run_dir, sink))
        player = next((c for c in children if c.name == "rgbd_player"), None)
        played_at: float | None = None
        respawns: dict[str, int] = {}
        last_line, last_print = "", 0.0
        last_usage: dict[str, dict] = {}
        report["usage"] = last_usage
        while not stop.is_set():
            time.sleep(0.2)
            for c in children:  # sampled while running: a node that exits (the player) keeps its last figures
                last_usage[c.name] = usage(c) or last_usage.get(c.name, {})
            failed = [c for c in children if c is not player and c.poll() is not None]
            for c in [c for c in failed if respawns.get(c.name, 0) < args.respawn]:
                respawns[c.name] = respawns.get(c.name, 0) + 1
                say(f"node {c.name} exited with code {c.poll()}; restarting it ({respawns[c.name]}/{args.respawn})"
                    + (f" with {c.spec.respawn_parameters}" if c.spec.respawn_parameters else ""))
                children[children.index(c)] = start_child(c.spec.respawned(), run_dir, sink,
                                                          attempt=respawns[c.name])
                failed.remove(c)
            if failed:
                for c in failed:
                    say(f"node {c.name} exited with code {c.poll()}; last lines:\n  " + "\n  ".join(c.lines[-15:]))
                code = 1
                break
            if player is not None and played_at is None and player.poll() is not None:
                if player.poll() != 0:
                    say(f"the player failed (exit code {player.poll()}): see {player.log_path}")
                    code = 1
                    break
                played_at = time.monotonic()
                report["played_s"] = round(played_at - t_start, 2)
                say(f"recording played in {played_at - t_start:.1f} s; waiting for the scene to settle")
            line = monitor.snapshot().line()
            if line != last_line or time.monotonic() - last_print > 10:
                say(line)
                last_line, last_print = line, time.monotonic()
            if played_at is not None and exported is None:
                settled = monitor.settled(played_at, args.settle)
                if settled or time.monotonic() - played_at > args.settle_timeout:
                    if not settled:
                        say(f"the scene did not settle within {args.settle_timeout:.0f} s; exporting it as it is")
                    exported = _export(monitor, say)
                    if exported is None:
                        code = EXIT_NO_SCENE
                    _measure(report, monitor, children, t_start, played_at, usage)
                    say(f"end to end: {report['exported_s']:.1f} s from start; the last URDF came "
                        f"{report['last_frame_to_urdf_s']:.1f} s after the last frame; per node (CPU s, peak MiB): "
                        + ", ".join(f"{n} {u.get('cpu_s', '?')}/{u.get('peak_rss_mib', '?')}"
                                    for n, u in report["nodes"].items()))
                    if not args.keep_running:
                        break
                    say("nodes stay up for planners (--keep-running); Ctrl-C stops them")
        if stop.is_set():
            say(f"{stop_reason[0] if stop_reason else 'stop'}: exporting the scene, then stopping the nodes")
            if all(c.poll() is None for c in children if c is not player):
                result = _export(monitor, say)
                exported = result or exported
                if exported is None and code == 0:
                    code = EXIT_NO_SCENE
    finally:
        if not report["nodes"]:
            report["nodes"] = {c.name: usage(c) or report.get("usage", {}).get(c.name, {}) for c in children}
        report.pop("usage", None)
        monitor.close()
        codes = stop_children(list(reversed(children)))
        report["exit_codes"] = codes
        if run_dir.is_dir():
            (run_dir / "run.json").write_text(json.dumps(report, indent=1, default=str), encoding="utf-8")
        for sig, handler in old.items():
            signal.signal(sig, handler)
    bad = {n: c for n, c in codes.items() if c != 0}
    if bad:
        say(f"nodes that did not exit cleanly: {bad} (logs in {run_dir / 'logs'})")
        code = code or 1
    say(f"scene folder: {out / 'scene'}" if exported else f"no scene exported (logs in {run_dir / 'logs'})")
    return code


def _measure(report: dict, monitor, children, t_start: float, played_at: float, usage) -> None:
    """Timing and per-node resources into `report` (written to OUT/ros/run.json).

    The player exits `PLAYER_DRAIN_S` after its last frame, so that is when the last frame went out."""
    p = monitor.snapshot()
    last_frame = played_at - PLAYER_DRAIN_S
    report.update(exported_s=round(time.monotonic() - t_start, 2), revision=p.revision,
                  last_frame_to_urdf_s=round(p.description_at - last_frame, 2),
                  frames_integrated=(p.status or {}).get("frames_integrated", 0),
                  dropped_frames=(p.status or {}).get("dropped_frames", 0),
                  nodes={c.name: usage(c) or report["usage"].get(c.name, {}) for c in children})


def _export(monitor, say) -> str | None:
    """The mapper's map into OUT/map/final (map.npz, entities.json), the scene into OUT/scene."""
    t0 = time.monotonic()
    ok, message = monitor.save_map(FINAL_MAP, timeout_s=EXPORT_TIMEOUT_S)
    say(f"map saved: {message}" if ok else f"map not saved: {message}")
    ok, message = monitor.export(timeout_s=EXPORT_TIMEOUT_S)
    if ok:
        say(f"scene exported: {message} ({time.monotonic() - t0:.1f} s)")
        return message
    say(f"no scene exported: {message}")
    return None


def _say(text: str) -> None:
    print(f"ros-run: {text}", flush=True)
    sys.stdout.flush()
