"""Stage 4 on whole scenes: contact graph -> CAD replacement -> physical check -> export, scored end to end.

For every suite scene (``scene-recon suite NAME``) the same contact graph goes through the whole
replacement (``CadReplacer`` + ``PhysicalCheck`` + ``export_scene``) in these settings, all in one run:

  gt/ours/in-library   ground-truth entities (the paper's cg_map setting), our method, a library
                       holding the scene objects' own models (plus 10 seeds per class)
  gt/ours/unseen       the same with the default library only (10 seeds per class: the scenes' seeds
                       are random 31-bit integers, never among them)
  gt/paper/unseen      the paper's method (all 24 orientations, dense LM, hull collisions) on the same
                       graphs and library
  mapped/ours/unseen   entities of the scene mapped with the oracle at `default` noise (``--maps DIR``
                       reuses maps of `bench_graph_mapped.py`/`scene-recon map`; otherwise they are mapped)

Figures per setting: pose success, front flips, Alignment Error median/p90, articulation, max
interpenetration, support gaps, PyBullet/MuJoCo stillness of the export, replacement time per scene
(warm: the second replacement of the scene by a fresh replacer, as in a running node; the first, with
cold caches and worker start, is ``replace_first_s``), with ``workers`` processes (config default:
one per CPU; ``--set workers=1`` for one process). Writes ``benchmarks/results/bench_cad.json``.

    .venv/bin/python benchmarks/bench_cad.py [--scenes bench-small ...] [--no-paper] [--no-mapped]
        [--only gt/ours/unseen ...] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import write_result
from cad_replacement.cad.library import DEFAULT_SEEDS_PER_CLASS, CadLibrary
from cad_replacement.export import export_scene
from cad_replacement.physical_check import PhysicalCheck
from cad_replacement.replace_config import CadReplacementConfig
from cad_replacement.replacer import CadReplacer
from cad_replacement.seeded_library import SeededLibrary
from cad_replacement.workers import ReplaceWorkers, resolve_workers
from recon_core.entity import Entity, load_entities
from scene_graph.builder import ContactGraphBuilder
from scene_graph.config import load_scene_graph_config
from scene_recon.evaluation.scene_eval import evaluate_scene
from scene_recon.synthetic.scene import GroundTruthScene, entities_from_ground_truth
from scene_recon.synthetic.suite import SUITE, suite_scene


def graph_of(entities: list[Entity], name: str):
    builder = ContactGraphBuilder(load_scene_graph_config())
    builder.update(entities)
    return builder.build(name=name), builder.node_entities()


def mapped_entities(bag: Path, maps: Path | None, name: str) -> list[Entity]:
    folder = (maps / name) if maps else Path(tempfile.mkdtemp()) / name
    if not (folder / "entities.json").is_file():
        from scene_recon.cli import main

        with contextlib.redirect_stdout(io.StringIO()):
            main(["map", str(bag), "--out", str(folder), "--segmenter", "oracle", "--noise", "default", "--json"])
    return load_entities(folder)


def run_setting(graph, nodes, gt: GroundTruthScene, library: CadLibrary, method: str, out: Path,
                overrides: dict[str, Any] | None = None, workers: ReplaceWorkers | None = None) -> dict[str, Any]:
    config = dataclasses.replace(CadReplacementConfig(method=method), **(overrides or {}))
    # The first replacement of a scene warms what a running system has warm (geometry caches, worker
    # processes); the second, by a fresh replacer (no reused results), is the one timed as "replace".
    t_first = time.perf_counter()
    CadReplacer(library, config, physical_check=PhysicalCheck(method=method), workers=workers).replace(graph, nodes)
    first_s = time.perf_counter() - t_first
    check = PhysicalCheck(method=method)
    replacer = CadReplacer(library, config, physical_check=check, workers=workers)
    t0, c0 = time.perf_counter(), time.process_time()
    result = replacer.replace(graph, nodes)
    # CPU time beside wall time: on a shared machine the wall clock measures the neighbours too (with
    # workers it is this process's share only)
    replace_s, replace_cpu_s = time.perf_counter() - t0, time.process_time() - c0
    # An update of one entity (a new revision of the largest object): only it is re-matched.
    target = max((n for n in graph.nodes.values() if n.category != "layout" and n.id in nodes),
                 key=lambda n: len(nodes[n.id].vertices), default=None)
    update_s, update_cpu_s, rematched = None, None, None
    if target is not None:
        bumped = dict(nodes)
        bumped[target.id] = dataclasses.replace(nodes[target.id], revision=nodes[target.id].revision + 1)
        t_up, c_up = time.perf_counter(), time.process_time()
        updated = replacer.replace(graph, bumped)
        update_s, rematched = time.perf_counter() - t_up, updated.rematched
        update_cpu_s = time.process_time() - c_up
    t1 = time.perf_counter()
    export_scene(result.scene, out)
    export_s = time.perf_counter() - t1
    with contextlib.redirect_stdout(io.StringIO()):
        figures = evaluate_scene(result.scene, {r.name: r.to_dict() for r in result.records}, gt, library, out,
                                 graph)
    objects = sum(1 for r in result.records if r.kind == "cad")
    return {"replace_s": replace_s, "replace_cpu_s": replace_cpu_s, "replace_first_s": first_s,
            "workers": workers.workers if workers is not None else 1, "export_s": export_s, "cad_objects": objects,
            "update_s": update_s, "update_cpu_s": update_cpu_s, "update_rematched": rematched,
            "per_object_s": replace_s / max(objects, 1), "physical_check_s": result.timings["physical_check_s"],
            "conflicts_before": len(check.last_report.conflicts_before),
            "conflicts_after": len(check.last_report.conflicts_after),
            "support_switches": {k: list(v) for k, v in check.last_report.support_switches.items()}, **figures}


def _plot(results: dict[str, list[dict[str, Any]]], path: Path) -> None:
    """Run time against error: per setting and scene, seconds per object vs pose success and AE."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    markers = {"gt/ours/in-library": "o", "gt/ours/unseen": "s", "gt/paper/unseen": "x", "mapped/ours/unseen": "^"}
    for label, rows in results.items():
        x = [r["per_object_s"] for r in rows]
        pose = [100.0 * (r["objects"].get("pose_success") or 0.0) for r in rows]
        ae = [1000.0 * (r["objects"].get("ae_median") or 0.0) for r in rows]
        m = markers.get(label, ".")
        axes[0].scatter(x, pose, marker=m, label=label)
        axes[1].scatter(x, ae, marker=m, label=label)
        for xi, yi, r in zip(x, pose, rows, strict=True):
            axes[0].annotate(r["scene"].replace("bench-", ""), (xi, yi), fontsize=7, alpha=0.7)
    axes[0].set_ylabel("pose success per scene (%)")
    axes[1].set_ylabel("Alignment Error median per scene (mm)")
    for ax in axes:
        ax.set_xlabel("wall seconds per object (warm)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("CAD replacement: run time against error (bench_cad.py)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _overrides(pairs: list[str]) -> dict[str, Any]:
    """``KEY=VALUE`` strings -> typed CadReplacementConfig overrides (the field's default gives the type)."""
    defaults = CadReplacementConfig()
    out: dict[str, Any] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not hasattr(defaults, key):
            raise SystemExit(f"--set {pair!r}: expected KEY=VALUE with KEY a CadReplacementConfig field")
        default = getattr(defaults, key)
        kind = float if default is None else type(default)
        if kind is bool:  # bool("false") is True
            if value.lower() not in ("true", "false", "1", "0", "yes", "no"):
                raise SystemExit(f"--set {pair!r}: {key} takes true or false")
            out[key] = value.lower() in ("true", "1", "yes")
        else:
            out[key] = value if kind is str else kind(float(value)) if kind is int else kind(value)
    return out


def _summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    def mean(key: str, sub: str | None = None) -> float | None:
        vals = [(r["objects"].get(key) if sub is None else r.get(sub, {}).get(key)) for r in rows]
        vals = [v for v in vals if v is not None]
        return float(np.mean(vals)) if vals else None

    still = {e: [r["physics"][e]["still_fraction"] for r in rows if "physics" in r] for e in ("pybullet", "mujoco")}
    return {
        "pose_success": mean("pose_success"), "front_flips": mean("front_flips"), "ae_median": mean("ae_median"),
        "ae_p90": mean("ae_p90"), "articulation_type_count_ok": mean("articulation_type_count_ok"),
        "joint_value_ok": mean("joint_value_ok"),
        "max_interpenetration_m": max(r["max_interpenetration_m"] for r in rows),
        "support_gap_max_m": max((r["support_gap_max_m"] or 0.0) for r in rows),
        "still_pybullet": float(np.mean(still["pybullet"])) if still["pybullet"] else None,
        "still_mujoco": float(np.mean(still["mujoco"])) if still["mujoco"] else None,
        "loaded_all": all(r["physics"][e]["loaded"] for r in rows for e in ("pybullet", "mujoco")),
        "replace_s_mean": float(np.mean([r["replace_s"] for r in rows])),
        "replace_s_max": float(np.max([r["replace_s"] for r in rows])),
        "update_s_max": max((r["update_s"] for r in rows if r["update_s"] is not None), default=None),
        "update_cpu_s_max": max((r["update_cpu_s"] for r in rows if r["update_cpu_s"] is not None), default=None),
        "replace_cpu_s_mean": float(np.mean([r["replace_cpu_s"] for r in rows])),
        "per_object_cpu_s_mean": float(np.mean([r["replace_cpu_s"] / max(r["cad_objects"], 1) for r in rows])),
        "replace_first_s_max": float(np.max([r["replace_first_s"] for r in rows])),
        "workers": max(r["workers"] for r in rows),
        "ged_unchanged": all(r.get("ged_unchanged", True) for r in rows),
        "per_object_s_mean": float(np.mean([r["per_object_s"] for r in rows])),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", nargs="+", default=list(SUITE), help="suite scenes (default: all)")
    parser.add_argument("--maps", type=Path, help="folder of mapped scenes <DIR>/<scene>/entities.json to reuse")
    parser.add_argument("--no-paper", action="store_true", help="skip the paper's method (the slow one)")
    parser.add_argument("--no-mapped", action="store_true", help="skip the mapped-entities setting")
    parser.add_argument("--seeds-per-class", type=int, default=DEFAULT_SEEDS_PER_CLASS,
                        help="procedural models per class of the unseen library (default %(default)s)")
    parser.add_argument("--only", nargs="+", metavar="SETTING",
                        help="run only these settings (e.g. gt/ours/unseen mapped/ours/unseen)")
    parser.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE",
                        help="override CadReplacementConfig fields for every setting (parameter sweeps)")
    args = parser.parse_args(argv)
    overrides = _overrides(args.set)
    results: dict[str, list[dict[str, Any]]] = {}
    work = Path(tempfile.mkdtemp(prefix="bench_cad_"))
    for name in args.scenes:
        bag, gt_dir = suite_scene(name)
        gt = GroundTruthScene.load(gt_dir)
        seeds: dict[str, list[int]] = {}
        for e in gt.entities:
            if e.model_seed is not None:
                seeds.setdefault(e.class_name, []).append(int(e.model_seed))
        libraries = {"in-library": SeededLibrary(extra_seeds=seeds),
                     "unseen": CadLibrary(seeds_per_class=args.seeds_per_class)}
        n_workers = resolve_workers(int(overrides.get("workers", CadReplacementConfig().workers)))
        pools = {k: ReplaceWorkers(lib, n_workers) if n_workers > 1 else None for k, lib in libraries.items()}
        graph, nodes = graph_of(entities_from_ground_truth(gt), name)
        settings = [("gt/ours/in-library", graph, nodes, "in-library", "ours"),
                    ("gt/ours/unseen", graph, nodes, "unseen", "ours")]
        if not args.no_paper:
            settings.append(("gt/paper/unseen", graph, nodes, "unseen", "paper"))
        if not args.no_mapped:
            mgraph, mnodes = graph_of(mapped_entities(bag, args.maps, name), name)
            settings.append(("mapped/ours/unseen", mgraph, mnodes, "unseen", "ours"))
        for label, g, n, lib, method in settings:
            if args.only and label not in args.only:
                continue
            row = run_setting(g, n, gt, libraries[lib], method, work / name / label.replace("/", "_"), overrides,
                              pools[lib])
            row["scene"] = name
            results.setdefault(label, []).append(row)
            o = row["objects"]
            print(f"{name:14s} {label:20s} pose {o.get('pose_success', 0):.3f} flips {o.get('front_flips', 0):.3f} "
                  f"AE med {1000 * (o.get('ae_median') or 0):.1f} mm  interpen "
                  f"{100 * row['max_interpenetration_m']:.2f} cm  gap "
                  f"{1000 * (row['support_gap_max_m'] or 0):.1f} mm  still pb "
                  f"{row['physics']['pybullet']['still_fraction']} mj {row['physics']['mujoco']['still_fraction']}  "
                  f"{row['replace_s']:.2f} s wall, {row['replace_cpu_s']:.2f} s CPU "
                  f"({1000 * row['per_object_s']:.0f} ms/object; first {row['replace_first_s']:.2f} s)", flush=True)
        for pool in pools.values():
            if pool is not None:
                pool.close()
    summary = {label: _summary(rows) for label, rows in results.items()}
    for label, s in summary.items():
        print(label, {k: (round(v, 4) if isinstance(v, float) else v) for k, v in s.items()})
    path = write_result("bench_cad", {"summary": summary, "rows": results, "overrides": overrides})
    _plot(results, path.with_suffix(".png"))
    print(f"wrote {path} and {path.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
