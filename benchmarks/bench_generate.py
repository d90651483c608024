"""Scene generation speed: a 300-frame 640x480 recording with 20 objects (goal < 60 s on 2 cores).

Baseline measured in the same run: Open3D ray casting of the same poses against the same
meshes (depth only, no color, noise or bag writing), i.e. the floor any renderer pays.

    .venv/bin/python benchmarks/bench_generate.py [--frames 300] [--objects 20]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import write_result
from scene_recon.synthetic.generate import GenerateConfig, generate_recording


def raycast_baseline(gt_dir: Path, bag: Path, frames: int) -> float:
    import open3d as o3d

    from panoptic_mapping.dataio.registry import open_dataset
    from scene_recon.synthetic.scene import GroundTruthScene

    scene = GroundTruthScene.load(gt_dir)
    with open_dataset(bag) as loader:
        poses = [f.pose for f in loader]
    rs = o3d.t.geometry.RaycastingScene()
    for e in scene.entities:
        rs.add_triangles(o3d.core.Tensor(np.asarray(e.mesh.vertices, np.float32)),
                         o3d.core.Tensor(np.asarray(e.mesh.faces, np.uint32)))
    k = o3d.core.Tensor([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]], o3d.core.Dtype.Float64)
    t0 = time.perf_counter()
    for pose in poses[:frames]:
        ext = o3d.core.Tensor(np.linalg.inv(pose), o3d.core.Dtype.Float64)
        rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(k, ext, 640, 480)
        rs.cast_rays(rays)["t_hit"].numpy()
    return time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--objects", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench_gen_"))
    try:
        t0 = time.perf_counter()
        summary = generate_recording(tmp / "scene", GenerateConfig(objects=args.objects, frames=args.frames,
                                                                   seed=args.seed), progress=False)
        total = time.perf_counter() - t0
        base = raycast_baseline(Path(summary["ground_truth"]), Path(summary["bag"]), args.frames)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    result = {
        "frames": args.frames, "objects": args.objects, "resolution": [640, 480],
        "total_s": round(total, 2), "per_frame_ms": round(1000 * total / args.frames, 1),
        "stages_s": summary["timings_s"],
        "baseline_raycast_only_s": round(base, 2),
        "ratio_total_over_raycast": round(total / base, 2),
        "goal_total_s": 60,
    }
    print(f"generate {args.frames} frames 640x480, {args.objects} objects: {total:.1f} s "
          f"({result['per_frame_ms']} ms/frame; goal < 60 s) | stages {summary['timings_s']}")
    ratio = result["ratio_total_over_raycast"]
    print(f"baseline (Open3D ray casting only, same poses): {base:.1f} s -> ratio {ratio}x")
    print(f"wrote {write_result('generate', result)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
