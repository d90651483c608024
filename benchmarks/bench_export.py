"""Scene export and physics stillness: primitive/box-CSG collisions vs the visual mesh as collision.

For each seed a generated scene (``build_scene(objects, seed)``, the ground truth of
``scene-recon generate --seed N --objects K``) is exported twice through
``cad_replacement.export.export_scene``: *after* (collision shapes from the CAD parts) and
*before* (every link collides as its visual mesh, i.e. as its convex hull in both engines). Both
folders are simulated for ``--seconds`` in PyBullet and MuJoCo; an object is still when it moved
less than 2 cm. Writes ``benchmarks/results/bench_export.json``.

    .venv/bin/python benchmarks/bench_export.py [--seeds 0 1 2 3 4 5] [--objects 20] [--seconds 2]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import write_result
from cad_replacement.export import export_scene
from scene_recon.evaluation.physics import STILL_THRESHOLD, check_mujoco, check_pybullet
from scene_recon.synthetic.scene import build_scene, ground_truth_scene


def run(seeds: list[int], objects: int, seconds: float) -> dict:
    rows = []
    totals: dict[str, dict[str, list[int]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            scene = ground_truth_scene(build_scene(objects, seed))
            for variant, visual in (("after", False), ("before", True)):
                folder = Path(tmp) / f"s{seed}_{variant}"
                t0 = time.perf_counter()
                result = export_scene(scene, folder, visual_collisions=visual)
                export_s = time.perf_counter() - t0
                row = {"seed": seed, "variant": variant, "export_s": round(export_s, 3), "links": result.links,
                       "collision_shapes": result.collision_shapes, "movable": len(result.object_urdfs)}
                for engine, check in (("pybullet", check_pybullet), ("mujoco", check_mujoco)):
                    report = check(folder, seconds)
                    d = report.to_dict()
                    row[engine] = {"loaded": d["loaded"], "errors": d["errors"], "still": len(report.still),
                                   "still_fraction": round(d["still_fraction"], 4), "moved": {
                                       k: round(report.displacement[k], 4) for k in d["moved"]},
                                   "max_displacement": round(max(report.displacement.values(), default=0.0), 4),
                                   "sim_wall_s": round(report.wall_time, 2)}
                    tot = totals.setdefault(f"{variant}/{engine}", {"loaded": [], "still": [], "movable": []})
                    tot["loaded"].append(int(report.loaded))
                    tot["still"].append(len(report.still))
                    tot["movable"].append(len(report.displacement))
                rows.append(row)
                print(f"seed {seed} {variant:6s} export {export_s:5.2f}s  "
                      + "  ".join(f"{e}: {row[e]['still']}/{row['movable']} still, loaded={row[e]['loaded']}"
                                  for e in ("pybullet", "mujoco")), flush=True)
    summary = {k: {"scenes_loaded": f"{sum(v['loaded'])}/{len(v['loaded'])}",
                   "still": f"{sum(v['still'])}/{sum(v['movable'])}",
                   "still_fraction": round(sum(v["still"]) / max(sum(v["movable"]), 1), 4)}
               for k, v in totals.items()}
    export_times = [r["export_s"] for r in rows if r["variant"] == "after"]
    return {"seeds": seeds, "objects": objects, "seconds": seconds, "still_threshold_m": STILL_THRESHOLD,
            "export_s_mean": round(sum(export_times) / len(export_times), 3), "summary": summary, "scenes": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4, 5])
    ap.add_argument("--objects", type=int, default=20)
    ap.add_argument("--seconds", type=float, default=2.0)
    args = ap.parse_args()
    data = run(args.seeds, args.objects, args.seconds)
    for k, v in data["summary"].items():
        print(f"{k:16s} loaded {v['scenes_loaded']}  still {v['still']} ({100 * v['still_fraction']:.1f} %)")
    print(f"export mean {data['export_s_mean']} s -> {write_result('bench_export', data)}")


if __name__ == "__main__":
    main()
