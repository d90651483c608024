"""Contact-graph build time: a 40-entity scene from ground-truth meshes (goal < 0.5 s on 2 cores).

Measured: the whole build (boxes, planes, supports, refinement, proximal relations) and its
relation stage alone, best of --repeats. Baseline measured in the same run: the same builder with
the naive all-pairs candidate search (every pair of nodes goes to the support and proximal
tests) instead of the sort-and-prune broad phase; and both again on a large tiled scene
(--tiles copies of the room side by side) where the quadratic pair count shows.

    .venv/bin/python benchmarks/bench_contact_graph.py [--entities 40] [--seed 1] [--tiles 10]
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import best_of, write_result
from recon_core.entity import Entity
from scene_graph.builder import ContactGraphBuilder, build_contact_graph
from scene_graph.config import load_scene_graph_config
from scene_recon.synthetic.scene import build_scene, entities_from_ground_truth


def scene_entities(count: int, seed: int) -> list[Entity]:
    """The first ``count`` entities of a generated room (parents come before their children)."""
    objects = count
    while True:
        ents = entities_from_ground_truth(build_scene(objects, seed))
        if len(ents) >= count:
            return ents[:count]
        objects += 5


def tiled(entities: list[Entity], tiles: int, spacing: float = 10.0) -> list[Entity]:
    """``tiles`` copies of the scene on a grid (new ids), a large scene with local relations."""
    out = []
    side = int(np.ceil(np.sqrt(tiles)))
    for t in range(tiles):
        offset = np.array([spacing * (t % side), spacing * (t // side), 0.0])
        for e in entities:
            c = copy.copy(e)
            c.id = e.id + 1000 * t
            c.name = f"{e.name}_t{t}"
            c.vertices = e.vertices + offset
            out.append(c)
    return out


def relations_time(entities: list[Entity], broadphase: str, repeats: int) -> tuple[float, dict]:
    cfg = load_scene_graph_config()
    cfg.proximal.broadphase = broadphase
    builder = ContactGraphBuilder(cfg)
    builder.update(entities)
    graph = builder.build()
    return best_of(builder.build, repeats), graph.stats


def full_time(entities: list[Entity], broadphase: str, repeats: int) -> float:
    cfg = load_scene_graph_config()
    cfg.proximal.broadphase = broadphase
    return best_of(lambda: build_contact_graph(entities, cfg), repeats)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--entities", type=int, default=40)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--tiles", type=int, default=10)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()

    ents = scene_entities(args.entities, args.seed)
    build_contact_graph(ents)  # warm up (imports, class table)
    t0 = time.perf_counter()
    graph = build_contact_graph(ents)
    first = time.perf_counter() - t0
    full = full_time(ents, "sweep", args.repeats)
    full_naive = full_time(ents, "all_pairs", args.repeats)
    rel, stats = relations_time(ents, "sweep", args.repeats)
    rel_naive, stats_naive = relations_time(ents, "all_pairs", args.repeats)

    big = tiled(ents, args.tiles)
    big_rel, big_stats = relations_time(big, "sweep", max(1, args.repeats // 2))
    big_rel_naive, big_stats_naive = relations_time(big, "all_pairs", max(1, args.repeats // 2))

    print(f"{len(ents)}-entity scene (seed {args.seed}): full build {1000 * full:.0f} ms (best of {args.repeats}; "
          f"single cold-cache run {1000 * first:.0f} ms), goal < 500 ms")
    print(f"  stages of one build: features {1000 * graph.stats['features_s']:.0f} ms, supports "
          f"{1000 * graph.stats['support_s']:.1f} ms, refinement + proximal {1000 * graph.stats['relations_s']:.1f} ms")
    print(f"  relation stage: sweep {1000 * rel:.1f} ms vs all-pairs baseline {1000 * rel_naive:.1f} ms "
          f"(x{rel_naive / rel:.1f}); exact proximal tests {stats['proximal_exact_tests']} vs "
          f"{stats_naive['proximal_exact_tests']}")
    print(f"  full build with the all-pairs baseline: {1000 * full_naive:.0f} ms (x{full_naive / full:.2f})")
    print(f"{len(big)}-entity tiled scene: relations sweep {1000 * big_rel:.0f} ms vs all-pairs "
          f"{1000 * big_rel_naive:.0f} ms (x{big_rel_naive / big_rel:.1f}); exact proximal tests "
          f"{big_stats['proximal_exact_tests']} vs {big_stats_naive['proximal_exact_tests']}")
    path = write_result("contact_graph", {
        "entities": len(ents), "seed": args.seed, "repeats": args.repeats,
        "full_build_s": full, "full_build_cold_s": first, "goal_s": 0.5, "meets_goal": full < 0.5,
        "stages_s": {k: graph.stats[k] for k in ("features_s", "support_s", "relations_s")},
        "relations_s": rel, "baseline_all_pairs": {"full_build_s": full_naive, "relations_s": rel_naive,
                                                   "proximal_exact_tests": stats_naive["proximal_exact_tests"],
                                                   "support_plane_tests": stats_naive["support_plane_tests"]},
        "speedup_relations": rel_naive / rel, "speedup_full": full_naive / full,
        "proximal_exact_tests": stats["proximal_exact_tests"], "support_plane_tests": stats["support_plane_tests"],
        "tiled": {"entities": len(big), "relations_s": big_rel, "baseline_relations_s": big_rel_naive,
                  "speedup": big_rel_naive / big_rel, "proximal_exact_tests": big_stats["proximal_exact_tests"],
                  "baseline_proximal_exact_tests": big_stats_naive["proximal_exact_tests"]},
    })
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
