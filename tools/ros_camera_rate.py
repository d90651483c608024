#!/usr/bin/env python3
"""Issue 26's ROS check: does the mapper node keep up with a 30 Hz bag played at rate 1.0, the other three
nodes running? Frames published, received, integrated and dropped by the mapper node, per run.

    ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST ROS_DOMAIN_ID=61 .venv/bin/python tools/ros_camera_rate.py \
        --out out/ros_camera_rate [--scene bench-kitchen | --bag BAG] [--runs 1] [--rate 1.0] [--live-order]

The graph is the one `scene-recon ros-run --bag` and `launch/bag.launch.py` start (`recon_core.ros_graph`:
player, segmentation service with the oracle, mapper, contact graph, CAD replacer, each its own process),
with one change: the player does not wait for the mapper (`pace_topic` empty), so frames come at the
recorded 30 Hz whatever the mapper does, as from a live camera, and the oracle segmentation service keeps
the label images of the whole recording (`--label-buffer`; its default of 64 is sized for a paced player:
unpaced, a mapper behind asks for labels that left the buffer, and such a keyframe maps without them,
where the network the oracle stands in for would have segmented its colour image). By default the mapper
integrates in recorded order as it does for bags (`in_order`: a keyframe holds later frames until its labels
come; queue of 120 frames); `--live-order` gives the live-camera settings instead (keyframes integrate when
their labels come, queue of 30). After the player's last frame the tool waits until the mapper's queue is empty and no
keyframe waits for labels (at most `--drain-timeout` s), then reads the mapper's counters from its
`mapper_status` topic and stops the nodes.

Per run: frames in the recording, frames the mapper received (`received`: image pairs), integrated, dropped
because the queue was full (`dropped_backlog`), skipped for another reason (no pose, no camera info, a bad
image, an image whose partner was lost, a still camera), the largest queue seen, the seconds from the first frame
received to the first one integrated (`first_frame_to_first_integrated_s`: the start-up stall, within the mapper's
0.5 s status period; a lost TF sample or the gravity wait showed here, docs/ROS.md), the seconds from the first
frame to the queue drained after the last one, and each node's CPU seconds with the processes it started (the
mapper's depth segmentation worker), their sum, and the whole machine's CPU seconds over the run (other
work included) with the run's wall time; the load average before and after. Writes
OUT/results.json. The generated suite scenes (`scene_recon.synthetic.suite`) are 640x480 at 30 Hz.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

#: Mapper counters of frames it received but did not integrate, other than the backlog's drops.
SKIPPED = ("no_tf", "no_camera_info", "bad_image", "unpaired_depth", "unpaired_color", "static_frames",
           "integration_error")


class SessionCpu:
    """CPU seconds of each node with the processes it started (the mapper's depth segmentation worker):
    every node is started in a session of its own (`start_child`), so its processes are those of that
    session. A process's last seen time is kept after it exits (sampled every 0.1 s)."""

    def __init__(self) -> None:
        self.ticks = os.sysconf("SC_CLK_TCK")
        self.seen: dict[int, dict[int, tuple[str, float]]] = {}  # session -> pid -> (command, CPU s)

    def sample(self, sessions: set[int]) -> None:
        for stat_path in Path("/proc").glob("[0-9]*/stat"):
            try:
                head, rest = stat_path.read_text().rsplit(")", 1)
            except OSError:
                continue
            fields = rest.split()
            sid = int(fields[3])
            if sid in sessions:
                pid = int(stat_path.parent.name)
                self.seen.setdefault(sid, {})[pid] = (head.split("(", 1)[1],
                                                      (int(fields[11]) + int(fields[12])) / self.ticks)

    def node_cpu(self, sid: int) -> dict:
        procs = self.seen.get(sid, {})
        own = procs.get(sid, ("", 0.0))[1]
        others = sum(cpu for pid, (_cmd, cpu) in procs.items() if pid != sid)
        return {"cpu_s": round(own + others, 2), "children_cpu_s": round(others, 2), "processes": len(procs)}


def machine_cpu_s() -> float:
    """CPU seconds spent by the whole machine (all processes, ours and others') since boot (/proc/stat)."""
    fields = Path("/proc/stat").read_text().splitlines()[0].split()[1:]
    busy = sum(int(x) for i, x in enumerate(fields[:8]) if i not in (3, 4))  # all but idle and iowait
    return busy / os.sysconf("SC_CLK_TCK")


def frames_in(bag: str) -> int:
    from panoptic_mapping.dataio.registry import open_dataset

    with open_dataset(bag) as loader:
        return sum(1 for _ in loader)


def graph_ready(monitor, names: set[str]) -> bool:
    """Every node but the player is up: its name is in the ROS graph, the mapper reports its status, and the
    segmentation service is offered (the mapper's first keyframes would otherwise wait for it). Read from the
    ROS graph, not from the mapper's `segmentation_service` status field, so older mappers are timed alike."""
    if monitor.snapshot().status is None:
        return False
    services = {name for name, _types in monitor.node.get_service_names_and_types()}
    return "/segment_image" in services and names <= set(monitor.node.get_node_names())


def one_run(bag: str, out: Path, rate: float, live_order: bool, drain_timeout_s: float, quiet: bool,
            label_buffer: int = 0, start_together: bool = False, ready_timeout_s: float = 120.0) -> dict:
    from recon_core.ros_graph import GraphOptions, graph_nodes
    from scene_recon.ros_runner.monitor import GraphMonitor
    from scene_recon.ros_runner.processes import LogSink, start_child, stop_children

    opts = GraphOptions(bag=bag, rate=rate, out=str(out.resolve()), seeds_per_class=2)
    specs = graph_nodes(opts)
    for spec in specs:
        if spec.name == "rgbd_player":
            spec.parameters["pace_topic"] = ""  # the recorded timing, whatever the mapper does
        if spec.name == "segmentation_service" and label_buffer:
            spec.parameters["label_buffer"] = label_buffer
        if spec.name == "panoptic_mapper":
            spec.parameters["status_period_s"] = 0.5
            if live_order:
                spec.parameters.update(in_order=False, max_queue=30)
    run_dir = out / "ros"
    sink = LogSink(quiet=quiet)
    monitor = GraphMonitor(opts.map_frame)
    children = []
    load_before = os.getloadavg()
    t_start = t_end = time.monotonic()
    row: dict = {"bag": bag, "rate": rate, "in_order": not live_order}
    max_queue, first_frame_at, first_integrated_at, drained_at = 0, None, None, None
    cpu = SessionCpu()
    machine_at_start = machine_at_first = machine_at_end = machine_cpu_s()
    cpu_at_first: dict[str, float] = {}
    try:
        # The check is a bag played "with the other three nodes running": unless --start-together, the
        # player starts once they are up, so the nodes' start-up (imports, the oracle loading the ground truth)
        # is not counted as the mapper falling behind. (The mapper's own stall before its first integration is
        # counted either way: first_frame_to_first_integrated_s.)
        others = [spec for spec in specs if spec.name != "rgbd_player"]
        children = [start_child(spec, run_dir, sink) for spec in (specs if start_together else others)]
        if not start_together:
            waited_from = time.monotonic()
            names = {spec.name for spec in others}
            while not graph_ready(monitor, names):
                time.sleep(0.1)
                dead = [c.name for c in children if c.poll() is not None]
                if dead or time.monotonic() - waited_from > ready_timeout_s:
                    raise RuntimeError(f"nodes exited before the player started: {dead}" if dead else
                                       f"the graph was not ready {ready_timeout_s:.0f} s after its start")
            row["graph_ready_s"] = round(time.monotonic() - waited_from, 2)
            children.append(start_child(next(spec for spec in specs if spec.name == "rgbd_player"), run_dir, sink))
        player = next(c for c in children if c.name == "rgbd_player")
        played_at = None
        t0 = time.monotonic()
        while True:
            time.sleep(0.1)
            cpu.sample({c.proc.pid for c in children})
            dead = [c.name for c in children if c is not player and c.poll() is not None]
            if dead:
                row["error"] = f"nodes exited: {dead}"
                break
            status = monitor.snapshot().status or {}
            counters = status.get("counters", {})
            max_queue = max(max_queue, int(status.get("queue", 0)))
            if first_frame_at is None and counters.get("received", 0) > 0:
                first_frame_at = time.monotonic()
                cpu_at_first = {c.name: cpu.node_cpu(c.proc.pid)["cpu_s"] for c in children}
                machine_at_first = machine_cpu_s()
            if first_integrated_at is None and int(status.get("frames_integrated", 0)) > 0:
                first_integrated_at = time.monotonic()
            if played_at is None and player.poll() is not None:
                played_at = time.monotonic()
            if played_at is not None:
                fresh = monitor.snapshot().status_at > played_at + 0.6  # a status sent after the last frame
                # the frame taken off the queue is counted once integrated (or skipped): an empty queue alone
                # read one frame short while the last one was still being integrated
                accounted = sum(int(counters.get(k, 0)) for k in ("integrated", "dropped_backlog", *SKIPPED))
                if (fresh and status.get("queue", 1) == 0 and status.get("pending_segmentations", 1) == 0
                        and accounted >= int(counters.get("received", 0))):
                    drained_at = time.monotonic()
                    break
                if time.monotonic() - played_at > drain_timeout_s:
                    row["error"] = f"queue not drained {drain_timeout_s:.0f} s after the last frame"
                    break
            if time.monotonic() - t0 > 600:
                row["error"] = "no end after 600 s"
                break
        status = monitor.snapshot().status or {}
        cpu.sample({c.proc.pid for c in children})
        machine_at_end, t_end = machine_cpu_s(), time.monotonic()
    finally:
        monitor.close()
        codes = stop_children(list(reversed(children))) if children else {}
    c = status.get("counters", {})
    row.update({
        "received": c.get("received", 0), "integrated": c.get("integrated", 0),
        "dropped_backlog": c.get("dropped_backlog", 0), "skipped": {k: c[k] for k in SKIPPED if c.get(k)},
        "keyframes_labelled": f"{c.get('segmented_keyframes', 0)}/{c.get('segmentation_calls', 0)}",
        "segmented_ahead": c.get("segmented_ahead", 0),
        "max_queue": max_queue,
        "first_frame_to_first_integrated_s": round(first_integrated_at - first_frame_at, 2)
        if first_integrated_at and first_frame_at else None,
        "first_frame_to_drained_s": round(drained_at - first_frame_at, 2) if drained_at and first_frame_at else None,
        # per node with the processes it started; the graph's sum; the machine's (others' work included) over
        # the same span, against the cores' capacity in it
        "cpu_s": {c.name: cpu.node_cpu(c.proc.pid)["cpu_s"] for c in children},
        "children_cpu_s": {c.name: cpu.node_cpu(c.proc.pid)["children_cpu_s"] for c in children
                           if cpu.node_cpu(c.proc.pid)["children_cpu_s"]},
        "graph_cpu_s": round(sum(cpu.node_cpu(c.proc.pid)["cpu_s"] for c in children), 2),
        "machine_cpu_s": round(machine_at_end - machine_at_start, 2),
        "wall_s": round(t_end - t_start, 2), "cores": os.cpu_count(),
        # from the mapper's first frame on (the nodes' start-up, imports and model loading, left out)
        "cpu_s_from_first_frame": {c.name: round(cpu.node_cpu(c.proc.pid)["cpu_s"] - cpu_at_first.get(c.name, 0.0), 2)
                                   for c in children},
        "machine_cpu_s_from_first_frame": round(machine_at_end - machine_at_first, 2),
        "load_before": [round(x, 2) for x in load_before], "load_after": [round(x, 2) for x in os.getloadavg()],
        "exit_codes": codes,
    })
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--scene", default="bench-kitchen", help="generated suite scene (300 frames 640x480, 30 Hz)")
    ap.add_argument("--bag", default="", help="a bag instead (generated: its ground truth beside it)")
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--rate", type=float, default=1.0)
    ap.add_argument("--live-order", action="store_true", help="live-camera mapper settings (see above)")
    ap.add_argument("--drain-timeout", type=float, default=60.0)
    ap.add_argument("--quiet-nodes", action="store_true")
    ap.add_argument("--start-together", action="store_true",
                    help="start the player with the other nodes (their start-up inside the measurement) instead of "
                    "once they are up")
    ap.add_argument("--label-buffer", type=int, default=-1,
                    help="oracle's label images kept (-1: the recording's frames; 0: the node's default, 64)")
    args = ap.parse_args()
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if args.bag:
        bag = str(Path(args.bag).resolve())
    else:
        from scene_recon.synthetic.suite import suite_scene

        bag = str(suite_scene(args.scene, progress=False)[0])
    n = frames_in(bag)
    rows = []
    print(f"oracle label buffer: {n if args.label_buffer < 0 else args.label_buffer or 'default'}", flush=True)
    for i in range(args.runs):
        row = one_run(bag, args.out / f"run{i + 1}", args.rate, args.live_order, args.drain_timeout, args.quiet_nodes,
                      n if args.label_buffer < 0 else args.label_buffer, args.start_together)
        row["frames_in_recording"] = n
        row["label_buffer"] = n if args.label_buffer < 0 else args.label_buffer
        rows.append(row)
        print(f"run {i + 1}: {n} frames played at rate {args.rate}: received {row['received']}, integrated "
              f"{row['integrated']}, dropped (queue full) {row['dropped_backlog']}, skipped {row['skipped']}, "
              f"largest queue {row['max_queue']}, first frame to first integrated "
              f"{row['first_frame_to_first_integrated_s']} s, first frame to drained "
              f"{row['first_frame_to_drained_s']} s "
              f"(recording {n / 30:.1f} s), keyframes labelled {row['keyframes_labelled']}, segmented ahead "
              f"{row['segmented_ahead']}, CPU s {row['cpu_s']} (of which started processes "
              f"{row['children_cpu_s']}; graph {row['graph_cpu_s']}, machine {row['machine_cpu_s']} in "
              f"{row['wall_s']} s; from the first frame on {row['cpu_s_from_first_frame']}, machine "
              f"{row['machine_cpu_s_from_first_frame']}), "
              f"load {row['load_before'][0]} -> {row['load_after'][0]}" + (f"; {row['error']}" if "error" in row
                                                                            else ""),
              flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps({"runs": rows}, indent=1, default=str), encoding="utf-8")
    print(f"wrote {args.out / 'results.json'}")
    return 0 if all("error" not in r for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
