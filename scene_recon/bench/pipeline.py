"""One configuration end to end on a generated scene: stage times and every accuracy figure.

The stages run through the same library calls as `scene-recon map/graph/replace` (no pictures, no
checkpoints: they are the CLI's conveniences, not the pipeline's work), with their configs built
from the stage schemas plus a preset's overrides (`recon_core.config.load_preset`), so a measured
preset is exactly what `--preset NAME` runs. Scores come from `scene_recon.evaluation`: 3D PQ and
mAP of the map, GED and oriented-box mAP of the contact graph (seen-only, as bench_graph_mapped),
CAD pose success / Alignment Error / physics stillness of the scene (as bench_cad).

A suite runs many configurations that differ only in a later stage (the paper's CAD method on the
balanced map, RANSAC or CAD sweeps, CAD perturbations): a `StageCache` keeps each mapped scene (and
each contact graph) by the settings it depends on, and a run whose map (graph) settings equal an
earlier run's reuses it instead of mapping the same frames again. Such a row says so (`shared`) and
carries the time and CPU seconds the shared stage took when it was computed, so its end-to-end
figures stay what running it alone would cost.
"""

from __future__ import annotations

import contextlib
import copy
import io
import json
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from recon_core.config import CONFIG_DIR, Preset, build_config, load_config, preset_overrides, to_dict


@dataclass
class RunSpec:
    """What to run: a preset (or None: the config files' defaults), extra dotted overrides per section
    (``{"mapper": {"tsdf.voxel_size_m": 0.03}}``), the mapper mode and the CAD method."""

    label: str
    preset: Preset | None = None
    extra: dict[str, dict[str, Any]] = field(default_factory=dict)
    mode: str = "full"
    method: str = "ours"
    noise: str = "default"
    #: The oracle's noise draw (`oracle.seed`): the robustness protocol maps every scene under several.
    noise_seed: int = 0
    physics: bool = True
    seeds_per_class: int = 10

    def overrides(self, section: str, explicit: dict[str, Any] | None = None) -> dict[str, Any]:
        out = preset_overrides(self.preset, section)
        out.update(self.extra.get(section, {}))
        out.update(explicit or {})
        return out


def _quiet():
    return contextlib.redirect_stdout(io.StringIO())


@dataclass
class StageCache:
    """Mapped scenes and contact graphs of earlier runs, by the settings they depend on (see the module
    docstring); `hits` counts the stages reused."""

    maps: OrderedDict[str, dict[str, Any]] = field(default_factory=OrderedDict)
    graphs: OrderedDict[str, dict[str, Any]] = field(default_factory=OrderedDict)
    hits: dict[str, int] = field(default_factory=lambda: {"map": 0, "graph": 0})
    #: Maps (graphs) kept, the least recently used dropped first.
    capacity: int = 8

    def get(self, store: OrderedDict[str, dict[str, Any]], key: str) -> dict[str, Any] | None:
        hit = store.get(key)
        if hit is not None:
            store.move_to_end(key)
        return hit

    def put(self, store: OrderedDict[str, dict[str, Any]], key: str, value: dict[str, Any]) -> None:
        store[key] = value
        while len(store) > self.capacity:
            store.popitem(last=False)

    @staticmethod
    def map_key(bag: Path, mapper_cfg: Any, data_cfg: Any, noise: str, noise_seed: int = 0) -> str:
        """The settings a map depends on: the recording, the resolved mapper and data configs (a sweep
        point equal to a preset's value is the same map), the oracle's noise level and draw."""
        return json.dumps([str(bag), to_dict(mapper_cfg), to_dict(data_cfg), noise, noise_seed], sort_keys=True,
                          default=str)

    @staticmethod
    def graph_key(map_key: str, graph_cfg: Any) -> str:
        return json.dumps([map_key, to_dict(graph_cfg)], sort_keys=True, default=str)


def stage_configs(spec: RunSpec) -> tuple[Any, Any, Any, Any]:
    """The mapper, data, contact-graph and CAD configs of ``spec`` (config files, preset, its overrides):
    each through its stage's schema, so an unknown or out-of-range key raises ``ConfigError`` naming it."""
    from cad_replacement.replace_config import CadReplacementConfig
    from panoptic_mapping.config import MapperConfig
    from panoptic_mapping.dataio import DataInputConfig
    from scene_graph.config import load_scene_graph_config

    mapper_cfg = load_config(MapperConfig, CONFIG_DIR / "mapper.yaml",
                             spec.overrides("mapper", {"mode": spec.mode, "checkpoint.enabled": False}))
    data_cfg = load_config(DataInputConfig, CONFIG_DIR / "data.yaml",
                           spec.overrides("data", {"topics.labels": "/ground_truth/panoptic_labels"}))
    graph_cfg = load_scene_graph_config(None, spec.overrides("scene_graph"))
    cad_cfg = build_config(CadReplacementConfig, {}, spec.overrides("cad", {"method": spec.method}))
    return mapper_cfg, data_cfg, graph_cfg, cad_cfg


def run_pipeline(bag: Path, gt: Path, out: Path, spec: RunSpec, library: Any = None,
                 cache: StageCache | None = None) -> dict[str, Any]:
    """Map, build the graph, replace and score one configuration; returns times (s) and figures.

    `cache`: reuse the map (and graph) of an earlier run with the same stage settings (a deep copy:
    nothing a later stage does reaches the cached scene), and keep this run's for later ones."""
    from cad_replacement.cad.library import CadLibrary
    from cad_replacement.export import export_scene
    from cad_replacement.physical_check import PhysicalCheck
    from cad_replacement.replacer import CadReplacer
    from panoptic_mapping.pipeline import map_recording, write_map_outputs
    from panoptic_mapping.segmentation.config import SegmentationConfig
    from panoptic_mapping.segmentation.factory import make_segmenter
    from scene_graph.builder import ContactGraphBuilder
    from scene_graph.joints import load_support_joints
    from scene_recon.evaluation.graph_ground_truth import ground_truth_graph, seen_entity_ids
    from scene_recon.evaluation.graph_metrics import evaluate_graph
    from scene_recon.evaluation.map_metrics import evaluate_panoptic_map
    from scene_recon.evaluation.scene_eval import evaluate_scene
    from scene_recon.synthetic.scene import GroundTruthScene

    out.mkdir(parents=True, exist_ok=True)
    mapper_cfg, data_cfg, graph_cfg, cad_cfg = stage_configs(spec)
    seg_cfg = SegmentationConfig(backend="oracle")
    seg_cfg.oracle.ground_truth, seg_cfg.oracle.level, seg_cfg.oracle.seed = str(gt), spec.noise, spec.noise_seed
    library = library or CadLibrary(seeds_per_class=spec.seeds_per_class)
    scene = GroundTruthScene.load(gt)

    map_key = StageCache.map_key(bag, mapper_cfg, data_cfg, spec.noise, spec.noise_seed)
    graph_key = StageCache.graph_key(map_key, graph_cfg)
    shared: list[str] = []
    # stage 1-2: segmentation + mapping (frames read, segmented, integrated; entities extracted)
    c0, t0 = time.process_time(), time.perf_counter()
    hit = cache.get(cache.maps, map_key) if cache is not None else None
    if hit is not None and cache is not None:
        cache.hits["map"] += 1
        shared.append("map")
        entities, summary, run = copy.deepcopy((hit["entities"], hit["summary"], hit["run"]))
        map_s, map_cpu = hit["map_s"], hit["map_cpu"]
    else:
        mapper, run = map_recording(bag, make_segmenter(seg_cfg), mapper_cfg, data_cfg, progress=False)
        entities, summary = write_map_outputs(out / "map", mapper, run)
        del mapper
        map_s, map_cpu = time.perf_counter() - t0, time.process_time() - c0
        if cache is not None:
            cache.put(cache.maps, map_key, copy.deepcopy({"entities": entities, "summary": summary, "run": run,
                                                          "map_s": map_s, "map_cpu": map_cpu}))
    # stage 3: contact graph
    c1, t1 = time.process_time(), time.perf_counter()
    ghit = cache.get(cache.graphs, graph_key) if cache is not None else None
    if ghit is not None and cache is not None:
        cache.hits["graph"] += 1
        shared.append("graph")
        graph, nodes = copy.deepcopy((ghit["graph"], ghit["nodes"]))
        graph_s, graph_cpu = ghit["graph_s"], ghit["graph_cpu"]
    else:
        builder = ContactGraphBuilder(graph_cfg, load_support_joints(graph_cfg.support_joints or None))
        builder.update(entities)
        graph = builder.build(name=scene.name)
        nodes = builder.node_entities()
        graph_s, graph_cpu = time.perf_counter() - t1, time.process_time() - c1
        if cache is not None:
            cache.put(cache.graphs, graph_key, copy.deepcopy({"graph": graph, "nodes": nodes, "graph_s": graph_s,
                                                              "graph_cpu": graph_cpu}))
    # stage 4: CAD replacement + export
    c2, t2 = time.process_time(), time.perf_counter()
    check = PhysicalCheck(method=spec.method)
    replacer = CadReplacer(library, cad_cfg, physical_check=check)
    result = replacer.replace(graph, nodes)
    replace_s, replace_cpu = time.perf_counter() - t2, time.process_time() - c2
    t3 = time.perf_counter()
    export_scene(result.scene, out / "scene")
    export_s = time.perf_counter() - t3
    export_cpu = time.process_time() - c2 - replace_cpu
    # a shared stage counts with what it cost when it was computed (the row's own end to end)
    total_s = map_s + graph_s + replace_s + export_s
    total_cpu = map_cpu + graph_cpu + replace_cpu + export_cpu
    # skip: the same graph again, nothing changed -> no CAD work
    t4 = time.perf_counter()
    again = replacer.replace(graph, nodes)
    replacer.close()
    unchanged_s = time.perf_counter() - t4

    c5, t5 = time.process_time(), time.perf_counter()
    m = evaluate_panoptic_map(entities, scene.entities)
    seen = seen_entity_ids(scene, graph_cfg.match.seen_min_pixels)
    g = evaluate_graph(graph, ground_truth_graph(scene), graph_cfg.match, seen)
    gs = g.get("seen_only", g)
    with _quiet():
        s = evaluate_scene(result.scene, {r.name: r.to_dict() for r in result.records}, scene, library,
                           out / "scene" if spec.physics else None, graph)
    objects = s.get("objects", {})
    still = [rep.get("still_fraction") for rep in s.get("physics", {}).values()
             if rep.get("still_fraction") is not None]
    cad_objects = sum(1 for r in result.records if r.kind == "cad")
    # Pose success counts CAD-placed objects only: an object stage 4 keeps as its observed mesh is out of
    # its denominator. The recall beside it does not flatter a stricter gate: correct CAD poses over every
    # ground-truth object the camera saw.
    seen_objects = sum(1 for e in scene.entities if e.model_seed is not None and (seen is None or e.id in seen))
    successes = round(float(objects.get("pose_success") or 0.0) * int(objects.get("objects") or 0))
    return {
        "label": spec.label, "preset": spec.preset.name if spec.preset else None, "method": spec.method,
        "mode": spec.mode, "extra": spec.extra, "shared": "+".join(shared) or None,
        # scoring (not part of the pipeline's time): what the suite spends beside the runs themselves
        "eval_s": round(time.perf_counter() - t5, 3), "eval_cpu_s": round(time.process_time() - c5, 3),
        "times_s": {"map": round(map_s, 3), "graph": round(graph_s, 3), "replace": round(replace_s, 3),
                    "export": round(export_s, 3), "total": round(total_s, 3),
                    "segmentation": round(run.segmentation_s, 3), "mapper": round(run.mapper_s, 3),
                    "replace_unchanged": round(unchanged_s, 3)},
        # CPU seconds of this process (all its threads): far less disturbed than wall time by other work
        # on a shared machine; the speed ratios of the report use both
        "cpu_s": {"map": round(map_cpu, 3), "graph": round(graph_cpu, 3), "replace": round(replace_cpu, 3),
                  "total": round(total_cpu, 3)},
        "frames": run.frames, "keyframes": run.keyframes, "segmentation_calls": run.segmentation_calls,
        "map_memory_mb": summary.get("map_memory_mb"), "entities": len(entities),
        "stage_ms": summary["run"]["stage_ms"],
        "pq": round(m.pq, 2), "map_mAP": round(m.map, 2), "pq_things": round(m.pq_things, 2),
        "pq_stuff": round(m.pq_stuff, 2),
        # what PQ is made of: false positives and misses, and the classes predicted that the scene lacks
        # (each counts as a class of PQ 0 in the mean)
        "map_fp": sum(c.fp for c in m.per_class.values()), "map_fn": sum(c.fn for c in m.per_class.values()),
        "false_classes": sorted(c.class_name for c in m.per_class.values() if c.num_gt == 0 and c.fp > 0),
        "ged_ratio": round(float(gs["ged"]["ratio"]), 4), "box_mAP": round(float(gs["box_map_refined"]["mAP"]), 4),
        "pose_success": objects.get("pose_success"), "ae_median_m": objects.get("ae_median"),
        # per ground-truth class: placed objects, successes and the criteria missed (the report's
        # "why mapped poses fail" table)
        "pose_by_class": s.get("objects_by_class", {}),
        "cad_objects": cad_objects, "matched_objects": s.get("matched"),
        "observed_mesh_objects": sum(1 for r in result.records if r.kind == "observed_mesh"),
        "seen_objects": seen_objects,
        "pose_recall": round(successes / seen_objects, 4) if seen_objects else None,
        "stillness": round(float(sum(still) / len(still)), 4) if still else None,
        "unchanged_rematched": again.rematched,
    }


def accuracy_score(row: dict[str, Any]) -> float:
    """One accuracy number for Pareto fronts (higher is better): the mean of PQ/100, box mAP,
    1 - GED ratio and CAD pose success (the figures every stage is judged by, equally weighted)."""
    parts = [row["pq"] / 100.0, row["box_mAP"], max(0.0, 1.0 - row["ged_ratio"])]
    if row.get("pose_success") is not None:
        parts.append(float(row["pose_success"]))
    return round(sum(parts) / len(parts), 4)


def pareto_front(rows: list[dict[str, Any]], time_key: str = "total", score=accuracy_score,
                 cpu: bool = False) -> list[str]:
    """Labels of the rows no other row beats in both time (lower) and accuracy (higher); `cpu`: CPU time."""
    times = "cpu_s" if cpu else "times_s"
    front = []
    for r in rows:
        t, a = r[times][time_key], score(r)
        dominated = any((o[times][time_key] <= t and score(o) >= a)
                        and (o[times][time_key] < t or score(o) > a) for o in rows if o is not r)
        if not dominated:
            front.append(r["label"])
    return front
