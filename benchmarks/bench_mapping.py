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

    .venv/bin/python benchmarks/bench_mapping.py [--scenes bench-small bench-kitchen] [--frames N]
"""

from __future__ import annotations

import argparse
import json
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


def open3d_integration_s(bag: Path, frames: int, downsample: int, voxel: float) -> float:
    """Depth-only TSDF integration of the same frames with Open3D's VoxelBlockGrid (timed part only)."""
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
            t0 = time.perf_counter()
            dt = o3d.t.geometry.Image(o3c.Tensor(depth))
            k = o3c.Tensor(intr.matrix)
            e = o3c.Tensor(np.linalg.inv(f.pose))
            blocks = vbg.compute_unique_block_coordinates(dt, k, e, 1.0, 4.0, 4.0)
            vbg.integrate(blocks, dt, k, e, 1.0, 4.0, 4.0)
            total += time.perf_counter() - t0
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


def main() -> int:
    from scene_recon.synthetic.suite import SUITE, suite_scene

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="*", default=list(SUITE))
    ap.add_argument("--configs", nargs="*", default=list(CONFIGS))
    ap.add_argument("--frames", type=int, default=0, help="limit frames per scene (0: all)")
    args = ap.parse_args()
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
