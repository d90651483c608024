"""Panoptic mapping on the benchmark suite: accuracy (3D PQ/SQ/RQ, mAP) against run time.

For every suite scene, the same frames go through:
  full/default        the paper's method (+ our extensions), oracle segmentation at `default` noise
  baseline/default    Voxblox++-style fusion, same frames, same noise, same seed
  full/clean          the method with perfect 2D segmentation (what the method itself loses)
  full/default/all-frames  keyframe gating off: every frame segmented (the gating's cost in PQ)
  full/default/label-all-frames      every non-keyframe also propagates labels (default: every 3rd)
  full/default/label-keyframes-only  non-keyframes integrate geometry only (fastest)
and, on the same frames, Open3D's depth-only VoxelBlockGrid integration (the speed baseline).
Segmentation time is excluded from the mapper's frames/s (it is reported separately).

Cost model (issue 26, `--cost-model`): in one process, on the same frames, the full mapper (oracle,
default preset, the mapper's own loop as `map` times it), the geometry-only mapper (`--segmenter none`)
and Open3D's depth-only integration; per mapper step: the frames it runs on, ms per call, ms per input
frame, ns per processed pixel, and its cost against Open3D's integration of a frame. `--compare-root DIR`
runs the same model on another checkout (e.g. a `git worktree` of an older commit) in alternating
subprocesses, `--rounds` times, and reports the best round of each and their ratios.

    .venv/bin/python benchmarks/bench_mapping.py [--scenes bench-small bench-kitchen] [--frames N]
    .venv/bin/python benchmarks/bench_mapping.py --cost-model [--bag GENERATED_BAG] [--frames 120]
    .venv/bin/python benchmarks/bench_mapping.py --cost-model --compare-root /work/wt_base --rounds 3
    .venv/bin/python benchmarks/bench_mapping.py --digest [--scenes bench-small bench-kitchen] [--frames 120]
    .venv/bin/python benchmarks/bench_mapping.py --digest --compare-root /work/wt_base   # before/after identical?
    .venv/bin/python benchmarks/bench_mapping.py --cost-model --segment-ahead 0   # no second process

`--digest`: the sha256 of each scene's map state after mapping (oracle at `default` noise, default preset:
every voxel attribute, the counts, the merge votes, the keyframe state) and of its extracted entities;
equal digests before and after a change mean the change left the maps bit-identical.
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

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import RESULTS_DIR, write_result

CONFIGS = {
    "full/default": {"mode": "full", "noise": "default", "keyframes": True},
    "baseline/default": {"mode": "baseline", "noise": "default", "keyframes": True},
    "full/clean": {"mode": "full", "noise": "clean", "keyframes": True},
    "full/default/all-frames": {"mode": "full", "noise": "default", "keyframes": False},
    "full/default/label-all-frames": {"mode": "full", "noise": "default", "keyframes": True,
                                      "overrides": {"keyframes.label_every_n_frames": 1}},
    "full/default/label-keyframes-only": {"mode": "full", "noise": "default", "keyframes": True,
                                          "overrides": {"keyframes.label_every_n_frames": 0}},
}


def open3d_integration_s(bag: Path, frames: int, downsample: int, voxel: float, cpu: list | None = None) -> float:
    """Depth-only TSDF integration of the same frames with Open3D's VoxelBlockGrid (timed part only);
    `cpu`: a list that receives each frame's process CPU seconds."""
    import open3d as o3d
    import open3d.core as o3c

    from panoptic_mapping.dataio.registry import open_dataset
    from panoptic_mapping.image_ops import downsample_depth

    vbg = o3d.t.geometry.VoxelBlockGrid(("tsdf", "weight"), (o3c.float32, o3c.float32), ((1), (1)), voxel, 8, 20000,
                                        o3c.Device("CPU:0"))
    total = 0.0
    with open_dataset(bag) as loader:
        for i, f in enumerate(loader):
            if frames and i >= frames:
                break
            depth = downsample_depth(f.depth, downsample)
            intr = f.intrinsics if downsample == 1 else f.intrinsics.scaled(1 / downsample)
            t0, c0 = time.perf_counter(), time.process_time()
            dt = o3d.t.geometry.Image(o3c.Tensor(depth))
            k = o3c.Tensor(intr.matrix)
            e = o3c.Tensor(np.linalg.inv(f.pose))
            blocks = vbg.compute_unique_block_coordinates(dt, k, e, 1.0, 4.0, 4.0)
            vbg.integrate(blocks, dt, k, e, 1.0, 4.0, 4.0)
            total += time.perf_counter() - t0
            if cpu is not None:
                cpu.append(time.process_time() - c0)
    return total


def run_one(bag: Path, gt: Path, spec: dict, frames: int, out: Path) -> dict:
    from panoptic_mapping.config import MapperConfig
    from panoptic_mapping.dataio import DataInputConfig
    from panoptic_mapping.pipeline import map_recording, write_map_outputs
    from panoptic_mapping.segmentation.config import SegmentationConfig
    from panoptic_mapping.segmentation.factory import make_segmenter
    from recon_core.config import CONFIG_DIR, load_config
    from scene_recon.evaluation.map_metrics import evaluate_panoptic_map
    from scene_recon.synthetic.scene import GroundTruthScene

    cfg = load_config(MapperConfig, CONFIG_DIR / "mapper.yaml", {"mode": spec["mode"],
                                                                 "keyframes.enabled": spec["keyframes"],
                                                                 **spec.get("overrides", {})})
    seg_cfg = SegmentationConfig(backend="oracle")
    seg_cfg.oracle.ground_truth, seg_cfg.oracle.level, seg_cfg.oracle.seed = str(gt), spec["noise"], 0
    data = DataInputConfig(max_frames=frames)
    data.topics.labels = "/ground_truth/panoptic_labels"
    mapper, run = map_recording(bag, make_segmenter(seg_cfg), cfg, data, progress=False)
    ents, summary = write_map_outputs(out, mapper, run)  # no picture: that is the CLI's
    scene = GroundTruthScene.load(gt)
    m = evaluate_panoptic_map(ents, scene.entities)
    return {
        "pq": round(m.pq, 2), "sq": round(m.sq, 2), "rq": round(m.rq, 2), "pq_things": round(m.pq_things, 2),
        "pq_stuff": round(m.pq_stuff, 2), "map": round(m.map, 2),
        "frames": run.frames, "keyframes": run.keyframes, "segmentation_calls": run.segmentation_calls,
        "mapper_fps": round(run.mapper_fps, 2), "mapper_s": round(run.mapper_s, 2),
        "segmentation_s": round(run.segmentation_s, 2), "stage_ms": summary["run"]["stage_ms"],
        "map_memory_mb": summary["map_memory_mb"], "entities": summary["entities"],
        "per_class_pq": {k: round(v.pq, 1) for k, v in m.per_class.items()},
    }


# ------------------------------------------------------------------------------------------ cost model
#: Mapper steps in the order a label frame runs them (the mapper's `FrameStats.timings_ms` keys).
STEPS = ("depth_segmentation", "fusion", "association", "label_integration", "integration", "regularization")


def cost_model(bag: Path, frames: int, noise: str = "default", seed: int = 0) -> dict:
    """Per-step cost of the full mapper against the geometry-only mapper and Open3D, one process, same frames.

    Full mapping: `map_recording` with the oracle at `noise` and the default preset (config/mapper.yaml);
    its `mapper_s` is the mapper's own loop (segmentation, reading excluded), as `scene-recon map` reports.
    Per step: the frames it ran on and its total time, from the mapper's per-frame timings.
    """
    from panoptic_mapping.config import MapperConfig
    from panoptic_mapping.dataio import DataInputConfig
    from panoptic_mapping.mapper import PanopticMapper
    from panoptic_mapping.pipeline import class_metas, map_recording
    from panoptic_mapping.segmentation.config import SegmentationConfig
    from panoptic_mapping.segmentation.factory import make_segmenter
    from recon_core.config import CONFIG_DIR, load_config

    cfg = load_config(MapperConfig, CONFIG_DIR / "mapper.yaml")
    steps: dict[str, list[float]] = {}
    cpu = {"full": 0.0, "geometry_only": 0.0}

    class Recorder(PanopticMapper):
        """Records each frame's step timings (older checkouts have no per-step frame counts) and the
        process CPU time of each frame (all threads: on a shared machine far steadier than wall time)."""

        def integrate(self, frame, masks, *ahead):  # type: ignore[no-untyped-def]
            c0 = time.process_time()
            stats = super().integrate(frame, masks, *ahead)
            cpu["full"] += time.process_time() - c0
            for k, v in stats.timings_ms.items():
                steps.setdefault(k, []).append(v)
            return stats

    class GeometryRecorder(PanopticMapper):
        def integrate_geometry(self, frame):  # type: ignore[no-untyped-def]
            c0 = time.process_time()
            stats = super().integrate_geometry(frame)
            cpu["geometry_only"] += time.process_time() - c0
            return stats

    seg_cfg = SegmentationConfig(backend="oracle")
    seg_cfg.oracle.ground_truth, seg_cfg.oracle.level, seg_cfg.oracle.seed = str(_gt_of(bag)), noise, seed
    data = DataInputConfig(max_frames=frames)
    data.topics.labels = "/ground_truth/panoptic_labels"
    _mapper, run = map_recording(bag, make_segmenter(seg_cfg), cfg, data, progress=False,
                                 mapper=Recorder(cfg, class_metas()))
    _geo_mapper, geo = map_recording(bag, None, cfg, DataInputConfig(max_frames=frames), progress=False,
                                     mapper=GeometryRecorder(cfg, class_metas()))
    o3d_cpu: list[float] = []
    o3d_s = open3d_integration_s(bag, frames, cfg.downsample, cfg.tsdf.voxel_size_m, cpu=o3d_cpu)
    n = run.frames
    h, w = mapper_resolution(bag, cfg.downsample)
    o3d_ms = 1000 * o3d_s / n
    rows = {}
    for k in [k for k in STEPS if k in steps] + [k for k in steps if k not in STEPS]:
        t = np.asarray(steps[k])
        rows[k] = {"frames": int(t.size), "ms_per_call": round(float(t.mean()), 3),
                   "ms_per_frame": round(float(t.sum()) / n, 3),
                   "ns_per_pixel": round(float(t.mean()) * 1e6 / (h * w), 2),
                   "x_open3d_frame": round(float(t.sum()) / n / o3d_ms, 3)}
    full_ms, geo_ms = 1000 * run.mapper_s / n, 1000 * geo.mapper_s / geo.frames
    # the depth segmentation of label frames ahead runs on a worker process (pipeline.SEGMENT_AHEAD): its
    # CPU time is added to the full mapper's; its wall time overlaps the mapper's loop, but may also overlap
    # the reading and the 2D segmentation, which `mapper_s` leaves out: the loop's whole wall time less the
    # 2D segmentation's is given beside it (an upper bound of the mapper's own share)
    cpu["full"] += getattr(run, "ahead_cpu_s", 0.0)
    loop_ms = 1000 * (run.wall_s - run.segmentation_s) / n
    geo_loop_ms = 1000 * geo.wall_s / geo.frames
    import panoptic_mapping

    return {
        "code": str(Path(panoptic_mapping.__file__).resolve().parent.parent),
        "bag": str(bag), "frames": n, "resolution": [w, h], "keyframes": run.keyframes,
        "segmentation_calls": run.segmentation_calls, "segmentation_ms_per_call":
            round(1000 * run.segmentation_s / max(run.segmentation_calls, 1), 2),
        "full_ms_per_frame": round(full_ms, 2), "full_fps": round(1000 / full_ms, 2),
        "geometry_only_ms_per_frame": round(geo_ms, 2), "geometry_only_fps": round(1000 / geo_ms, 2),
        "open3d_ms_per_frame": round(o3d_ms, 2),
        "loop_ms_per_frame": {"full": round(loop_ms, 2), "geometry_only": round(geo_loop_ms, 2),
                              "ratio": round(loop_ms / geo_loop_ms, 2)},
        "segmented_ahead": {"used": getattr(run, "ahead_used", 0), "unused": getattr(run, "ahead_unused", 0),
                            "worker_cpu_ms_per_frame": round(1000 * getattr(run, "ahead_cpu_s", 0.0) / n, 2)},
        "ratio_full_vs_geometry_only": round(full_ms / geo_ms, 2), "ratio_full_vs_open3d": round(full_ms / o3d_ms, 2),
        "cpu_ms_per_frame": {"full": round(1000 * cpu["full"] / n, 2),
                             "geometry_only": round(1000 * cpu["geometry_only"] / geo.frames, 2),
                             "open3d": round(1000 * sum(o3d_cpu) / n, 2)},
        "cpu_ratio_full_vs_geometry_only": round(cpu["full"] / n / max(cpu["geometry_only"] / geo.frames, 1e-9), 2),
        "steps": rows,
    }


def map_digest(bag: Path, frames: int, noise: str = "default", seed: int = 0) -> dict:
    """sha256 of the map state and of the entities of `frames` frames of a generated bag (see `--digest`)."""
    import hashlib

    from panoptic_mapping.config import MapperConfig
    from panoptic_mapping.dataio import DataInputConfig
    from panoptic_mapping.pipeline import map_recording
    from panoptic_mapping.segmentation.config import SegmentationConfig
    from panoptic_mapping.segmentation.factory import make_segmenter
    from recon_core.config import CONFIG_DIR, load_config

    cfg = load_config(MapperConfig, CONFIG_DIR / "mapper.yaml")
    seg_cfg = SegmentationConfig(backend="oracle")
    seg_cfg.oracle.ground_truth, seg_cfg.oracle.level, seg_cfg.oracle.seed = str(_gt_of(bag)), noise, seed
    data = DataInputConfig(max_frames=frames)
    data.topics.labels = "/ground_truth/panoptic_labels"
    mapper, run = map_recording(bag, make_segmenter(seg_cfg), cfg, data, progress=False)

    def digest(arrays: dict[str, np.ndarray]) -> str:
        h = hashlib.sha256()
        for k in sorted(arrays):
            a = np.ascontiguousarray(arrays[k])
            h.update(f"{k}:{a.dtype.str}:{a.shape}".encode())
            h.update(a.tobytes())
        return h.hexdigest()

    snap = mapper.snapshot()
    # Open3D's hash map hands out block slots in a thread-timing order: blocks are compared sorted by key
    for prefix in ("tsdf_", "fine_"):
        keys = snap.arrays.get(prefix + "block_keys")
        if keys is not None and len(keys):
            order = np.lexsort(keys.T[::-1])
            for k in [k for k in snap.arrays if k.startswith(prefix)]:
                snap.arrays[k] = snap.arrays[k][order]
    meta = {k: snap.meta[k] for k in ("frames_integrated", "keyframes", "last_key_time_ns")}
    state = digest({**snap.arrays, "meta": np.frombuffer(json.dumps(meta, sort_keys=True).encode(), np.uint8)})
    ents = mapper.entities()
    arrays: dict[str, np.ndarray] = {}
    for i, e in enumerate(ents):
        arrays[f"{i}_ids"] = np.array([e.id, e.class_id, e.instance_id, e.num_voxels, e.core_vertices])
        arrays[f"{i}_v"], arrays[f"{i}_f"] = np.asarray(e.vertices), np.asarray(e.faces)
    return {"bag": str(bag), "frames": run.frames, "label_frames": run.stage_frames.get("depth_segmentation", 0),
            "map_state_sha256": state, "entities": len(ents), "entities_sha256": digest(arrays)}


def _gt_of(bag: Path) -> Path:
    from scene_recon.synthetic.generate import ground_truth_path

    return ground_truth_path(Path(bag))


def mapper_resolution(bag: Path, downsample: int) -> tuple[int, int]:
    """(height, width) of the frames the mapper processes."""
    from panoptic_mapping.dataio import DataInputConfig
    from panoptic_mapping.dataio.registry import open_dataset

    with open_dataset(bag, DataInputConfig(max_frames=1)) as loader:
        f = next(iter(loader))
    return f.depth.shape[0] // downsample, f.depth.shape[1] // downsample


def print_cost_model(r: dict, title: str = "") -> None:
    print(f"{title}{r['frames']} frames {r['resolution'][0]}x{r['resolution'][1]}, {r['keyframes']} keyframes "
          f"({r['segmentation_calls']} 2D segmentation calls, {r['segmentation_ms_per_call']} ms each, not in the "
          f"mapper's time)")
    print(f"  full mapper   {r['full_ms_per_frame']:7.2f} ms/frame = {r['full_fps']:6.1f} frames/s  "
          f"({r['ratio_full_vs_geometry_only']:.2f}x geometry only, {r['ratio_full_vs_open3d']:.2f}x Open3D)")
    print(f"  geometry only {r['geometry_only_ms_per_frame']:7.2f} ms/frame = {r['geometry_only_fps']:6.1f} frames/s")
    print(f"  Open3D        {r['open3d_ms_per_frame']:7.2f} ms/frame (depth-only VoxelBlockGrid, same frames)")
    lp, ah = r.get("loop_ms_per_frame"), r.get("segmented_ahead")
    if lp:
        print(f"  whole loop less 2D segmentation (reading, gravity included): full {lp['full']:.2f} ms/frame, "
              f"geometry only {lp['geometry_only']:.2f} ({lp['ratio']:.2f}x)")
    if ah:
        print(f"  depth segmentation ahead on the worker process: {ah['used']} frames used, {ah['unused']} unused, "
              f"{ah['worker_cpu_ms_per_frame']:.2f} ms worker CPU per frame (in the full CPU time below)")
    c = r.get("cpu_ms_per_frame")
    if c:
        print(f"  CPU time (all threads) per frame: full {c['full']:.2f} ms, geometry only {c['geometry_only']:.2f} ms "
              f"({r['cpu_ratio_full_vs_geometry_only']:.2f}x), Open3D {c['open3d']:.2f} ms")
    print(f"  {'step':20s} {'frames':>6s} {'ms/call':>8s} {'ms/frame':>9s} {'ns/pixel':>9s} {'x Open3D':>9s}")
    for k, row in r["steps"].items():
        print(f"  {k:20s} {row['frames']:6d} {row['ms_per_call']:8.2f} {row['ms_per_frame']:9.2f} "
              f"{row['ns_per_pixel']:9.1f} {row['x_open3d_frame']:9.2f}")


def _best(rounds: list[dict]) -> dict:
    """The round with the fastest full mapper, with each step's best (least loaded) round beside it."""
    best = dict(min(rounds, key=lambda r: r["full_ms_per_frame"]))
    best["geometry_only_ms_per_frame"] = min(r["geometry_only_ms_per_frame"] for r in rounds)
    best["open3d_ms_per_frame"] = min(r["open3d_ms_per_frame"] for r in rounds)
    best["steps"] = {k: min((r["steps"][k] for r in rounds if k in r["steps"]), key=lambda s: s["ms_per_frame"])
                     for k in best["steps"]}
    if all("cpu_ms_per_frame" in r for r in rounds):
        best["cpu_ms_per_frame"] = {k: min(r["cpu_ms_per_frame"][k] for r in rounds) for k in best["cpu_ms_per_frame"]}
        best["cpu_ratio_full_vs_geometry_only"] = round(best["cpu_ms_per_frame"]["full"]
                                                        / best["cpu_ms_per_frame"]["geometry_only"], 2)
    # full against geometry only within each round (one process, the same load), the median round
    best["ratio_full_vs_geometry_only"] = float(np.median([r["ratio_full_vs_geometry_only"] for r in rounds]))
    return best


def compare_roots(roots: dict[str, Path], bag: Path, frames: int, rounds: int,
                  segment_ahead: int | None = None) -> dict:
    """The cost model of each checkout (name -> repository root) in alternating subprocesses."""
    out: dict[str, list[dict]] = {k: [] for k in roots}
    names = list(roots)
    for i in range(rounds):
        for j in range(len(names)):
            name = names[(i + j) % len(names)]
            root = roots[name]
            env = {**os.environ, "PYTHONPATH": str(root), "SCENE_RECON_CONFIG_DIR": str(root / "config")}
            cmd = [sys.executable, str(Path(__file__).resolve()), "--cost-model-worker", str(root), "--bag", str(bag),
                   "--frames", str(frames)] + ([] if segment_ahead is None else ["--segment-ahead", str(segment_ahead)])
            res = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
            r = json.loads(res.stdout.strip().splitlines()[-1])
            out[name].append(r)
            print(f"round {i + 1} {name:8s} full {r['full_ms_per_frame']:.2f} ms/frame, geometry only "
                  f"{r['geometry_only_ms_per_frame']:.2f}, Open3D {r['open3d_ms_per_frame']:.2f}", flush=True)
    return {k: {"best": _best(v), "rounds": v} for k, v in out.items()}


def cost_model_main(args: argparse.Namespace) -> int:
    if args.bag is not None:
        bag = args.bag
    else:
        from scene_recon.synthetic.suite import suite_scene

        bag, _gt = suite_scene(args.scenes[0] if args.scenes else "bench-small", progress=False)
    frames = args.frames or 120
    if args.compare_root is None:
        r = cost_model(bag, frames)
        print_cost_model(r)
        print(f"wrote {write_result('mapping_cost_model', r)}")
        return 0
    here = Path(__file__).resolve().parent.parent
    res = compare_roots({"before": args.compare_root.resolve(), "after": here}, bag, frames, args.rounds,
                        args.segment_ahead)
    before, after = res["before"]["best"], res["after"]["best"]
    for name, r in (("before", before), ("after", after)):
        print_cost_model(r, f"{name} (best of {args.rounds} rounds): ")
    ratios = {"full_ms_per_frame": round(before["full_ms_per_frame"] / after["full_ms_per_frame"], 2),
              "geometry_only_ms_per_frame": round(before["geometry_only_ms_per_frame"]
                                                  / after["geometry_only_ms_per_frame"], 2),
              "steps": {k: round(before["steps"][k]["ms_per_frame"] / max(after["steps"][k]["ms_per_frame"], 1e-9), 2)
                        for k in before["steps"] if k in after["steps"]}}
    if "cpu_ms_per_frame" in before and "cpu_ms_per_frame" in after:
        b_cpu, a_cpu = before["cpu_ms_per_frame"]["full"], after["cpu_ms_per_frame"]["full"]
        ratios["full_cpu_ms_per_frame"] = round(b_cpu / a_cpu, 2)
    print("speed-up before/after (ms per frame):", json.dumps(ratios))
    print(f"wrote {write_result('mapping_cost_model_compare', {**res, 'speedup': ratios})}")
    return 0


def digest_main(args: argparse.Namespace, suite_scene) -> int:  # type: ignore[no-untyped-def]
    """`--digest`; with `--compare-root`, that checkout's maps too (a subprocess with its code first) and
    whether each scene's digests are equal."""
    scenes = args.scenes or ["bench-small", "bench-kitchen"]
    if args.cost_model_worker is not None or args.compare_root is None:
        import panoptic_mapping

        code = Path(panoptic_mapping.__file__).resolve().parent.parent
        if args.cost_model_worker is not None and code != args.cost_model_worker.resolve():
            raise SystemExit(f"the digest of {args.cost_model_worker} would be of {code}'s code")
        for name in scenes:
            bag, _gt = suite_scene(name, progress=False)
            print(json.dumps({"scene": name, **map_digest(bag, args.frames or 120)}), flush=True)
        return 0
    root = args.compare_root.resolve()
    env = {**os.environ, "PYTHONPATH": str(root), "SCENE_RECON_CONFIG_DIR": str(root / "config")}
    cmd = [sys.executable, str(Path(__file__).resolve()), "--digest", "--cost-model-worker", str(root),
           "--frames", str(args.frames or 120), "--scenes", *scenes]
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
    before = {r["scene"]: r for r in (json.loads(x) for x in res.stdout.splitlines() if x.startswith("{"))}
    same = True
    for name in scenes:
        bag, _gt = suite_scene(name, progress=False)
        after = map_digest(bag, args.frames or 120)
        b = before[name]
        eq = {k: b[k] == after[k] for k in ("map_state_sha256", "entities_sha256", "frames", "entities")}
        same &= all(eq.values())
        print(f"{name}: {'identical' if all(eq.values()) else 'DIFFERENT ' + json.dumps(eq)} "
              f"(map state {after['map_state_sha256'][:16]}, entities {after['entities_sha256'][:16]})", flush=True)
    return 0 if same else 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="*", default=None)
    ap.add_argument("--configs", nargs="*", default=list(CONFIGS))
    ap.add_argument("--frames", type=int, default=0, help="limit frames per scene (0: all; cost model: 120)")
    ap.add_argument("--cost-model", action="store_true", help="per-step cost model (see above)")
    ap.add_argument("--bag", type=Path, default=None, help="cost model: a generated bag instead of a suite scene")
    ap.add_argument("--compare-root", type=Path, default=None, help="cost model: also run this checkout's code")
    ap.add_argument("--rounds", type=int, default=3, help="cost model with --compare-root: alternating rounds")
    ap.add_argument("--segment-ahead", type=int, default=None, metavar="N",
                    help="cost model / digest: frames whose depth segmentation may run ahead on the worker process "
                    "(panoptic_mapping.pipeline.SEGMENT_AHEAD; 0: none, every frame segmented on the mapper's thread)")
    ap.add_argument("--digest", action="store_true", help="sha256 of each scene's map state and entities (see above)")
    ap.add_argument("--cost-model-worker", type=Path, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.cost_model_worker is not None:  # a subprocess of --compare-root: that checkout's code first
        sys.path.insert(0, str(args.cost_model_worker))
    if args.segment_ahead is not None:
        import panoptic_mapping.pipeline as pipeline

        pipeline.SEGMENT_AHEAD = args.segment_ahead  # (an older checkout: set but unused)
    if args.cost_model_worker is not None and not args.digest:
        print(json.dumps(cost_model(args.bag, args.frames)))
        return 0
    if args.cost_model:
        return cost_model_main(args)
    from scene_recon.synthetic.suite import SUITE, suite_scene

    if args.digest:
        return digest_main(args, suite_scene)

    args.scenes = args.scenes or list(SUITE)
    results: dict[str, dict] = {}
    tmp = Path(tempfile.mkdtemp(prefix="bench_map_"))
    for name in args.scenes:
        bag, gt = suite_scene(name, progress=False)
        results[name] = {}
        for cname in args.configs:
            r = run_one(bag, gt, CONFIGS[cname], args.frames, tmp / name / cname.replace("/", "_"))
            results[name][cname] = r
            print(f"{name:14s} {cname:24s} PQ {r['pq']:5.1f} "
                  f"(things {r['pq_things']:5.1f}, stuff {r['pq_stuff']:5.1f}) "
                  f"SQ {r['sq']:5.1f} RQ {r['rq']:5.1f} mAP {r['map']:5.1f} | {r['mapper_fps']:5.1f} frames/s, "
                  f"{r['segmentation_calls']} seg calls", flush=True)
        full = results[name].get("full/default")
        if full:
            from panoptic_mapping.config import MapperConfig
            from recon_core.config import CONFIG_DIR, load_config

            ds = load_config(MapperConfig, CONFIG_DIR / "mapper.yaml").downsample
            o3d_proc = open3d_integration_s(bag, args.frames, ds, 0.02)
            o3d_full = o3d_proc if ds == 1 else open3d_integration_s(bag, args.frames, 1, 0.02)
            results[name]["open3d_depth_only"] = {
                "processing_resolution_fps": round(full["frames"] / o3d_proc, 2),
                "full_resolution_fps": round(full["frames"] / o3d_full, 2),
                "ratio_ours_vs_processing_resolution": round(full["mapper_s"] / o3d_proc, 2),
                "ratio_ours_vs_full_resolution": round(full["mapper_s"] / o3d_full, 2),
            }
            print(f"{name:14s} Open3D depth-only integration: {results[name]['open3d_depth_only']}", flush=True)
    # averages over scenes
    avg = {}
    for cname in args.configs:
        rows = [results[s][cname] for s in args.scenes if cname in results[s]]
        avg[cname] = {k: round(float(np.mean([r[k] for r in rows])), 2)
                      for k in ("pq", "sq", "rq", "pq_things", "pq_stuff", "map", "mapper_fps", "segmentation_calls")}
    results["average"] = avg
    print(json.dumps(avg, indent=1))
    path = write_result("mapping", {"scenes": args.scenes, "results": results})
    print(f"wrote {path}")
    _plot(avg, RESULTS_DIR / "mapping.png")
    return 0


def _plot(avg: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for name, r in avg.items():
        ax.scatter(r["mapper_fps"], r["pq"], s=60)
        ax.annotate(name, (r["mapper_fps"], r["pq"]), textcoords="offset points", xytext=(5, 5), fontsize=8)
    ax.set_xlabel("mapper frames/s (segmentation excluded)")
    ax.set_ylabel("class-averaged 3D PQ")
    ax.set_title("panoptic mapping on the benchmark suite")
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    sys.exit(main())
