"""`scene-recon replace` as a user meets it: a fresh process, end to end, with empty and with warm caches.

The input is a generated scene outside the suite (``scene-recon generate --seed 7``: 20 objects; only
its ground truth is used) turned into a contact graph by ``scene-recon graph`` (the paper's cg_map
setting). Each run is ``python -m scene_recon.cli replace GRAPH --out DIR`` in a new process, timed
from the outside (wall clock: interpreter start, imports, library, worker start, fits, physical check,
every export, the before/after picture):

  cold   ``XDG_CACHE_HOME`` emptied first (no feature, geometry or result cache: a first run ever)
  warm   the caches the previous run (the cold one) left

``--repeats`` (default 3) rounds of cold-then-warm; medians are reported. With ``--baseline DIR`` (a
checkout of another commit, e.g. ``git worktree add /tmp/base 6fa37e0``) the same runs of that tree
are interleaved with this one's (``PYTHONPATH=DIR``, ``SCENE_RECON_CONFIG_DIR=DIR/config``; each tree
has its own cache folder), so both meet the same machine load; ratios are new / baseline.

The ROS node's figure is measured too: the warm in-node update of one entity (``CadReplacer`` with
its worker pool, the scene replaced twice, then one entity's new revision replaced: only it is
re-matched), median of ``--repeats``.

Writes ``benchmarks/results/replace_cli.json`` and ``replace_cli.png``.

    .venv/bin/python benchmarks/bench_replace_cli.py [--repeats 3] [--baseline DIR] [--seed 7]
        [--work DIR] [--no-node]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import RESULTS_DIR, write_result

ROOT = Path(__file__).resolve().parent.parent
#: The issue's targets (issue 23, build item 4), seconds.
TARGET_WARM_S = 4.0
TARGET_COLD_S = 8.0
TARGET_NODE_UPDATE_S = 1.0


def _env(tree: Path | None, cache: Path | None) -> dict[str, str]:
    env = dict(os.environ)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env.setdefault("ROS_DOMAIN_ID", "77")
    tree = tree or ROOT  # this checkout's code and config, whatever the venv's editable install points at
    env["PYTHONPATH"] = str(tree)
    env["SCENE_RECON_CONFIG_DIR"] = str(tree / "config")
    if cache is not None:
        env["XDG_CACHE_HOME"] = str(cache)
    return env


#: A cgroup-v1 CPU accounting folder: where it can be made, each run's process tree (the command, its
#: fork server and workers) is counted there and its CPU seconds are reported beside the wall clock,
#: which on a shared machine measures the neighbours too.
CPUACCT = Path("/sys/fs/cgroup/cpuacct")


def _cpu_group() -> Path | None:
    group = CPUACCT / f"bench_replace_cli_{os.getpid()}"
    try:
        group.mkdir(exist_ok=True)
        (group / "cpuacct.usage").write_text("0")
    except OSError:
        return None
    return group


def _cli(args: list[str], tree: Path | None = None, cache: Path | None = None) -> tuple[float, str, float | None]:
    """Run ``python -m scene_recon.cli ARGS`` in a new process; (wall seconds, its output, CPU seconds of
    its process tree or None)."""
    group = _cpu_group()
    command = [sys.executable, "-m", "scene_recon.cli", *args]
    if group is not None:  # the shell joins the group, then becomes the command (children inherit it)
        command = ["sh", "-c", f'echo $$ > {group}/cgroup.procs && exec "$@"', "sh", *command]
    t0 = time.perf_counter()
    proc = subprocess.run(command, cwd=tree or ROOT, env=_env(tree, cache), capture_output=True, text=True,
                          check=False)
    wall = time.perf_counter() - t0
    cpu = None
    if group is not None:
        time.sleep(0.2)  # the fork server and workers exit just after the command
        cpu = int((group / "cpuacct.usage").read_text()) / 1e9
        with contextlib.suppress(OSError):
            group.rmdir()
    if proc.returncode != 0:
        raise RuntimeError(f"scene-recon {' '.join(args)} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    return wall, proc.stdout + proc.stderr, cpu


def make_input(work: Path, seed: int, objects: int) -> Path:
    """The contact graph of a generated scene outside the suite (made once, reused)."""
    graph = work / f"graph_s{seed}"
    if (graph / "contact_graph.json").is_file() and (graph / "nodes" / "entities.json").is_file():
        return graph
    bag = work / f"scene_s{seed}"
    shutil.rmtree(bag, ignore_errors=True)
    shutil.rmtree(Path(f"{bag}_groundtruth"), ignore_errors=True)
    _cli(["generate", "--out", str(bag), "--seed", str(seed), "--objects", str(objects), "--frames", "10"])
    shutil.rmtree(bag, ignore_errors=True)  # the recording is not used: its ground truth is
    _cli(["graph", f"{bag}_groundtruth", "--out", str(graph), "--no-picture"])
    return graph


def _run_replace(graph: Path, out: Path, tree: Path | None, cache: Path, cold: bool) -> dict[str, Any]:
    if cold:
        shutil.rmtree(cache, ignore_errors=True)
    shutil.rmtree(out, ignore_errors=True)
    wall, _log, cpu = _cli(["replace", str(graph), "--out", str(out)], tree, cache)
    rep = json.loads((out / "replacement.json").read_text())
    details = rep.get("objects_detail", [])
    restored = sum(1 for d in details if "restored_s" in (d.get("timings") or {}))
    return {"wall_s": wall, "cpu_s": cpu, "replace_log_s": rep.get("wall_s"), "objects": rep.get("objects"),
            "rematched": rep.get("rematched"), "restored": restored,
            "picture": (out / "before_after.png").is_file(), "timings": rep.get("timings"),
            "phases_s": rep.get("phases_s")}


#: The command's own marks (``replacement.json`` ``phases_s``: when each phase ended, seconds since the
#: process started): imports done, graph and library read, objects replaced (fits or results read back,
#: physical check), scene folder written, picture done (what is left after it is writing the summary).
PHASES = ("imports", "input", "replaced", "exported", "picture")


def _phase_text(phases: dict[str, float | None] | None) -> str:
    if not phases:
        return ""
    return " [" + ", ".join(f"{k} {phases[k]:.2f}" for k in PHASES if phases.get(k) is not None) + "]"


def node_update(graph_dir: Path, repeats: int) -> dict[str, Any]:
    """The ROS node's warm update of one entity (as ``bench_cad.py``: a new revision of the largest object)."""
    from cad_replacement.cad.library import CadLibrary
    from cad_replacement.physical_check import PhysicalCheck
    from cad_replacement.replace_config import CadReplacementConfig
    from cad_replacement.replacer import CadReplacer
    from recon_core.contact_graph import ContactGraph
    from recon_core.entity import load_entities

    graph = ContactGraph.load(graph_dir / "contact_graph.json")
    nodes = {e.id: e for e in load_entities(graph_dir / "nodes")}
    library = CadLibrary()
    replacer = CadReplacer(library, CadReplacementConfig(), physical_check=PhysicalCheck())
    try:
        replacer.replace(graph, nodes)  # cold caches and worker start
        t0 = time.perf_counter()
        replacer.replace(graph, nodes)  # nothing changed: every result reused
        unchanged_s = time.perf_counter() - t0
        target = max((n for n in graph.nodes.values() if n.category != "layout" and n.id in nodes),
                     key=lambda n: len(nodes[n.id].vertices))
        times, rematched = [], []
        for k in range(repeats):
            bumped = dict(nodes)
            bumped[target.id] = dataclasses.replace(nodes[target.id], revision=nodes[target.id].revision + 1 + k)
            t1 = time.perf_counter()
            result = replacer.replace(graph, bumped)
            times.append(time.perf_counter() - t1)
            rematched.append(result.rematched)
        return {"entity": target.name, "update_s": times, "update_s_median": statistics.median(times),
                "rematched": rematched, "unchanged_s": unchanged_s, "workers": replacer.workers_running}
    finally:
        replacer.close()


def node_update_in(tree: Path | None, graph_dir: Path, repeats: int, work: Path) -> dict[str, Any]:
    """``node_update`` with the code of ``tree`` (this checkout when None), in a new process."""
    out = work / f"node_{'this' if tree is None else 'baseline'}.json"
    out.unlink(missing_ok=True)
    command = [sys.executable, str(Path(__file__).resolve()), "--node-only", str(graph_dir), "--repeats",
               str(repeats), "--node-out", str(out), "--tree", str(tree or ROOT)]
    proc = subprocess.run(command, env=_env(tree, None), capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"node update ({tree or 'this'}) failed:\n{proc.stderr[-3000:]}")
    return json.loads(out.read_text())


def _median(rows: list[dict[str, Any]], key: str = "wall_s") -> float | None:
    values = [r[key] for r in rows if r.get(key) is not None]
    return float(statistics.median(values)) if values else None


def _plot(result: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    trees = list(result["runs"])
    keys = [("wall_s", "wall seconds, fresh process")]
    if any(r.get("cpu_s") is not None for t in trees for m in ("cold", "warm") for r in result["runs"][t][m]):
        keys.append(("cpu_s", "CPU seconds of its process tree"))
    fig, axes = plt.subplots(1, len(keys), figsize=(6.5 * len(keys), 4.4), squeeze=False)
    width = 0.38
    for ax, (key, label) in zip(axes[0], keys, strict=True):
        for i, mode in enumerate(("cold", "warm")):
            for j, tree in enumerate(trees):
                rows = result["runs"][tree][mode]
                med = _median(rows, key)
                if med is None:
                    continue
                x = i + (j - 0.5 * (len(trees) - 1)) * width
                ax.bar(x, med, width * 0.9, color=("#888888" if tree == "baseline" else "#2a7ab0"),
                       label=tree if i == 0 else None)
                ax.scatter([x] * len(rows), [r[key] for r in rows], color="k", s=10, zorder=3)
                ax.annotate(f"{med:.1f}", (x, med), ha="center", va="bottom", fontsize=8)
        if key == "wall_s":
            ax.axhline(TARGET_COLD_S, color="#c0392b", ls="--", lw=1)
            ax.axhline(TARGET_WARM_S, color="#27ae60", ls="--", lw=1)
            ax.text(1.6, TARGET_COLD_S, "cold target 8 s", color="#c0392b", fontsize=7, va="bottom", ha="right")
            ax.text(1.6, TARGET_WARM_S, "warm target 4 s", color="#27ae60", fontsize=7, va="bottom", ha="right")
        ax.set_xticks([0, 1], ["empty caches (first run)", "caches of the previous run"])
        ax.set_ylabel(f"{label} (median; dots: runs)")
        ax.legend(fontsize=8)
        ax.grid(axis="y", alpha=0.3)
    node = result.get("node_update")
    title = f"scene-recon replace, {result['objects']} objects, {result['machine_load']}"
    if node:
        title += f"; in-node warm update of one entity: {node['update_s_median']:.2f} s"
        if node.get("baseline"):
            title += f" (baseline {node['baseline']['update_s_median']:.2f} s)"
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3, help="rounds of cold + warm runs (default 3)")
    parser.add_argument("--baseline", type=Path, help="another checkout to time interleaved with this one")
    parser.add_argument("--seed", type=int, default=7, help="seed of the generated scene (default 7)")
    parser.add_argument("--objects", type=int, default=20, help="objects of the generated scene (default 20)")
    parser.add_argument("--work", type=Path, default=ROOT / "out" / "bench_replace_cli",
                        help="folder for the input, caches and outputs (default out/bench_replace_cli)")
    parser.add_argument("--no-node", action="store_true", help="skip the in-node one-entity update")
    parser.add_argument("--node-only", type=Path, metavar="GRAPH", help=argparse.SUPPRESS)
    parser.add_argument("--node-out", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--tree", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.node_only is not None:  # one tree's in-node figure (its code first on the path)
        sys.path.insert(0, str(args.tree or ROOT))
        args.node_out.write_text(json.dumps(node_update(args.node_only, args.repeats)))
        return 0

    work = args.work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    graph = make_input(work, args.seed, args.objects)
    trees: dict[str, Path | None] = {"this": None}
    if args.baseline is not None:
        trees = {"baseline": args.baseline.resolve(), "this": None}
    runs: dict[str, dict[str, list[dict[str, Any]]]] = {t: {"cold": [], "warm": []} for t in trees}
    load_before = os.getloadavg()[0]
    for k in range(args.repeats):
        for mode in ("cold", "warm"):
            # alternate which tree goes first, so neither always meets the other's after-effects
            for name in (list(trees) if k % 2 == 0 else list(reversed(trees))):
                row = _run_replace(graph, work / f"out_{name}", trees[name], work / f"cache_{name}", mode == "cold")
                runs[name][mode].append(row)
                cpu = "" if row["cpu_s"] is None else f", {row['cpu_s']:.2f} CPU s"
                print(f"round {k + 1} {mode:4s} {name:8s} {row['wall_s']:6.2f} s wall{cpu} (replacement by its "
                      f"log {row['replace_log_s']:.2f} s, {row['restored']} results restored, load "
                      f"{os.getloadavg()[0]:.1f}){_phase_text(row.get('phases_s'))}", flush=True)
    load_after = os.getloadavg()[0]
    summary: dict[str, Any] = {}
    for name in trees:
        summary[name] = {}
        for mode in ("cold", "warm"):
            summary[name][f"{mode}_median_s"] = _median(runs[name][mode])
            summary[name][f"{mode}_s"] = [r["wall_s"] for r in runs[name][mode]]
            summary[name][f"{mode}_cpu_median_s"] = _median(runs[name][mode], "cpu_s")
            marks = [r["phases_s"] for r in runs[name][mode] if r.get("phases_s")]
            summary[name][f"{mode}_phases_median_s"] = {
                k: statistics.median(m[k] for m in marks) for k in PHASES
                if marks and all(m.get(k) is not None for m in marks)}
    if "baseline" in summary:
        summary["ratio_this_over_baseline"] = {
            f"{mode}{kind}": summary["this"][f"{mode}{kind}_median_s"] / summary["baseline"][f"{mode}{kind}_median_s"]
            for mode in ("cold", "warm") for kind in ("", "_cpu")
            if summary["this"][f"{mode}{kind}_median_s"] and summary["baseline"][f"{mode}{kind}_median_s"]}
    node = None
    if not args.no_node:
        node = node_update_in(None, graph, args.repeats, work)
        if "baseline" in trees:
            node["baseline"] = node_update_in(trees["baseline"], graph, args.repeats, work)
    result: dict[str, Any] = {
        "input": str(graph), "seed": args.seed, "objects": args.objects, "repeats": args.repeats,
        "baseline": str(trees.get("baseline")) if "baseline" in trees else None,
        "machine_load": f"load average {load_before:.1f} -> {load_after:.1f} on {os.cpu_count()} CPUs",
        "targets_s": {"warm": TARGET_WARM_S, "cold": TARGET_COLD_S, "node_update": TARGET_NODE_UPDATE_S},
        "summary": summary, "node_update": node, "runs": runs,
        "meets_targets": {"warm": summary["this"]["warm_median_s"] <= TARGET_WARM_S,
                          "cold": summary["this"]["cold_median_s"] <= TARGET_COLD_S,
                          "node_update": None if node is None else node["update_s_median"] <= TARGET_NODE_UPDATE_S},
    }
    path = write_result("replace_cli", result)
    _plot(result, RESULTS_DIR / "replace_cli.png")
    for name in trees:
        s = summary[name]
        cpu = "" if s["cold_cpu_median_s"] is None else \
            f" (CPU s of the process tree: cold {s['cold_cpu_median_s']:.2f}, warm {s['warm_cpu_median_s']:.2f})"
        print(f"{name:8s} wall median: cold {s['cold_median_s']:.2f} s, warm {s['warm_median_s']:.2f} s{cpu}")
        for mode in ("cold", "warm"):
            if s.get(f"{mode}_phases_median_s"):
                print(f"         {mode} phases (median, s since the process started):"
                      f"{_phase_text(s[f'{mode}_phases_median_s'])}")
    if "ratio_this_over_baseline" in summary:
        print("this / baseline: " + ", ".join(f"{k} {v:.2f}" for k, v in summary["ratio_this_over_baseline"].items()))
    if node is not None:
        base = node.get("baseline")
        print(f"in-node warm update of one entity ({node['entity']}): median {node['update_s_median']:.2f} s "
              f"({node['rematched']} re-matched)" + (f"; baseline {base['update_s_median']:.2f} s" if base else ""))
    print(f"{result['machine_load']}; wrote {path} and {RESULTS_DIR / 'replace_cli.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
