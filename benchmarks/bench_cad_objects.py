"""Stage 4 per-object CAD replacement on the suite scenes' ground-truth entities: ours vs the paper.

For every thing entity of the suite scenes (``scene-recon suite NAME``; generated on first use)
an observation is made from its ground-truth mesh (4000 surface samples with normals, support
height = the entity's base height, front hint from walls/tall neighbours as
``front_direction_from_context`` sees them) and replaced with two libraries:

* in-library: the 10 default seeds per class plus the scene objects' own seeds;
* unseen: the 10 default seeds only (scene seeds are random 31-bit integers, never among them).

Pose success / AE / front flips / articulation / time per object are written to
``benchmarks/results/bench_cad_objects.json``. The geometry cache is shared per scene and library
(as the pipeline does) and warmed by one untimed pass, so times are per-object replacement costs.

    .venv/bin/python benchmarks/bench_cad_objects.py [--scenes bench-kitchen ...] [--no-paper]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import write_result
from cad_replacement.cad.procedural import build_model
from cad_replacement.geometry_cache import GeometryCache, library_store
from cad_replacement.matching import candidate_classes
from cad_replacement.observation import ObjectObservation, front_direction_from_context
from cad_replacement.replace_config import CadReplacementConfig
from cad_replacement.replace_object import replace_object
from cad_replacement.seeded_library import SeededLibrary
from recon_core.geometry.plane import Plane
from scene_recon.evaluation.cad_metrics import evaluate_object, rotational_symmetry, summarize
from scene_recon.synthetic.scene import GroundTruthScene
from scene_recon.synthetic.suite import SUITE, suite_scene


def wall_planes(scene: GroundTruthScene) -> list[Plane]:
    """Inner faces of the wall entities (normal towards the room centre)."""
    out = []
    for e in scene.entities:
        if e.class_name != "wall" or e.box is None:
            continue
        b = e.box
        axis = 0 if b.size[0] < b.size[1] else 1
        c, s = np.cos(b.yaw), np.sin(b.yaw)
        n = np.array([c, s, 0.0]) if axis == 0 else np.array([-s, c, 0.0])
        if n[:2] @ (-b.center[:2]) < 0.0:
            n = -n
        out.append(Plane(normal=n, d=-(n @ b.center + 0.5 * b.size[axis])))
    return out


def observations(scene: GroundTruthScene, samples: int) -> list[tuple[ObjectObservation, object]]:
    things = [e for e in scene.entities if e.is_thing and e.model_seed is not None]
    boxes = {e.name: e.box for e in things}
    walls = wall_planes(scene)
    out = []
    for e in things:
        others = [boxes[o.name] for o in things if o.name != e.name]
        hint = front_direction_from_context(boxes[e.name], others, walls)
        obs = ObjectObservation.from_mesh(e.id, e.name, e.class_name, e.mesh, samples=samples, seed=e.id,
                                          support_z=float(e.pose[2, 3]), front_hint=hint)
        out.append((obs, e))
    return out


def run(scenes: list[str], methods: list[str], samples: int) -> dict:
    evals: dict[str, list] = {}
    per_scene_time: dict[str, dict[str, float]] = {}
    symmetry_cache: dict[tuple[str, int], int] = {}
    for name in scenes:
        _, gt_dir = suite_scene(name, progress=False)
        scene = GroundTruthScene.load(gt_dir)
        obs_list = observations(scene, samples)
        seeds: dict[str, list[int]] = {}
        for _, e in obs_list:
            seeds.setdefault(e.class_name, []).append(int(e.model_seed))
        libs = {
            "in_library": SeededLibrary(seeds_per_class=10, extra_seeds=seeds),
            "unseen": SeededLibrary(seeds_per_class=10, exclude_seeds=seeds),
        }
        for lib_name, lib in libs.items():
            for method in methods:
                cfg = CadReplacementConfig(method=method)
                cache = GeometryCache(lib.model, samples=cfg.ae_model_samples, store=library_store(lib))
                for obs, _ in obs_list:  # warm the feature and geometry caches (untimed)
                    for c in candidate_classes(obs.class_name):
                        for entry, _f in lib.candidates(c):
                            cache.get(entry)
                key = f"{lib_name}/{method}"
                t0 = time.perf_counter()
                for obs, e in obs_list:
                    rep = replace_object(obs, lib, cfg, cache=cache)
                    gt_model = build_model(e.class_name, int(e.model_seed))
                    sk = (e.class_name, int(e.model_seed))
                    if sk not in symmetry_cache:
                        symmetry_cache[sk] = rotational_symmetry(gt_model)
                    ev = evaluate_object(rep, gt_model, e.pose, dict(e.joint_values), symmetry_cache[sk])
                    ev.name = f"{name}/{ev.name}"
                    evals.setdefault(key, []).append(ev)
                    print(f"{key:22s} {ev.name:28s} ok={ev.pose_success!s:5} t={ev.translation_error:.3f} "
                          f"yaw={ev.yaw_error_deg:6.1f} size={ev.size_error:.3f} AE={ev.ae:.4f} "
                          f"flip={ev.front_flip} art={ev.joint_types_ok}/{ev.value_ok}/{ev.joints_total} "
                          f"{ev.time_s * 1e3:.0f} ms {ev.chosen}", flush=True)
                per_scene_time.setdefault(key, {})[name] = time.perf_counter() - t0
    return {
        "summary": {k: summarize(v) for k, v in evals.items()},
        "scene_time_s": per_scene_time,
        "objects": {k: [e.to_dict() for e in v] for k, v in evals.items()},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=list(SUITE))
    ap.add_argument("--no-paper", action="store_true")
    ap.add_argument("--samples", type=int, default=4000)
    args = ap.parse_args()
    methods = ["ours"] if args.no_paper else ["ours", "paper"]
    result = run(args.scenes, methods, args.samples)
    path = write_result("bench_cad_objects", {"scenes": args.scenes, "samples": args.samples, **result})
    for k, v in result["summary"].items():
        print(k, {kk: (round(vv, 4) if isinstance(vv, float) else vv) for kk, vv in v.items()})
    print("scene times (s):", result["scene_time_s"])
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
