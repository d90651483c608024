"""Run the mapping stage over a recording: frames -> keyframe gating -> segmentation -> mapper.

Used by `scene-recon map` and the benchmarks; the ROS mapper node drives `PanopticMapper`
itself (asynchronous segmentation service), but with the same gating and conversion.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from panoptic_mapping.config import MapperConfig
from panoptic_mapping.dataio import DataInputConfig
from panoptic_mapping.dataio.registry import open_dataset
from panoptic_mapping.fusion import BACKGROUND, PanopticMasks
from panoptic_mapping.mapper import ClassMeta, PanopticMapper
from recon_core.classes import ClassTable, load_class_table
from recon_core.entity import Entity, save_entities


def class_metas(table: ClassTable | None = None) -> dict[int, ClassMeta]:
    table = table or load_class_table()
    return {c.id: ClassMeta(c.name, c.is_thing, c.category) for c in table}


def masks_from_segmentation(seg: Any) -> PanopticMasks:
    """`PanopticSegmentation` (any backend) -> the mapper's per-mask arrays."""
    n = max([s.id for s in seg.segments], default=0) + 1
    cls = np.full(n, BACKGROUND, np.int32)
    thing = np.zeros(n, bool)
    score = np.zeros(n)
    for s in seg.segments:
        cls[s.id], thing[s.id], score[s.id] = s.class_id, s.is_thing, s.score
    labels = np.where(seg.labels < n, seg.labels, 0).astype(np.int32)
    return PanopticMasks(labels, cls, thing, score)


@dataclass
class MappingRun:
    frames: int = 0
    keyframes: int = 0
    segmentation_calls: int = 0
    wall_s: float = 0.0
    mapper_s: float = 0.0
    segmentation_s: float = 0.0
    read_s: float = 0.0
    stage_ms: dict[str, float] = field(default_factory=dict)
    skipped: dict[str, int] = field(default_factory=dict)
    poses: list[np.ndarray] = field(default_factory=list)

    @property
    def mapper_fps(self) -> float:
        return self.frames / self.mapper_s if self.mapper_s > 0 else 0.0

    def summary(self) -> dict[str, Any]:
        d = {k: v for k, v in asdict(self).items() if k != "poses"}
        d["mapper_fps"] = round(self.mapper_fps, 2)
        d["stage_ms"] = {k: round(v / max(self.frames, 1), 2) for k, v in self.stage_ms.items()}
        for k in ("wall_s", "mapper_s", "segmentation_s", "read_s"):
            d[k] = round(d[k], 3)
        return d


def map_recording(
    source: str | Path,
    segmenter: Any,
    mapper_config: MapperConfig | None = None,
    data_config: DataInputConfig | None = None,
    progress: bool = True,
    mapper: PanopticMapper | None = None,
    class_table: ClassTable | None = None,
) -> tuple[PanopticMapper, MappingRun]:
    """Integrate every posed frame of `source`; segment keyframes only (when gating is enabled).

    class_table: the table the segmenter's class ids come from (default config/classes.yaml).
    """
    from tqdm import tqdm

    mapper = mapper or PanopticMapper(mapper_config, class_metas(class_table))
    run = MappingRun()
    t_start = time.perf_counter()
    with open_dataset(source, data_config) as loader:
        total = len(loader) if hasattr(loader, "__len__") else None
        frames = iter(loader)
        bar = tqdm(total=total, desc="mapping", unit="frame", disable=not progress)
        while True:
            t0 = time.perf_counter()
            try:
                frame = next(frames)
            except StopIteration:
                break
            run.read_s += time.perf_counter() - t0
            masks = None
            if segmenter is not None and mapper.is_keyframe(frame):
                mapper.mark_keyframe(frame)
                t1 = time.perf_counter()
                seg = segmenter.segment_frame(frame)
                run.segmentation_s += time.perf_counter() - t1
                run.segmentation_calls += 1
                masks = masks_from_segmentation(seg)
            elif segmenter is None and mapper.is_keyframe(frame):
                mapper.mark_keyframe(frame)
            t2 = time.perf_counter()
            stats = mapper.integrate(frame, masks)
            run.mapper_s += time.perf_counter() - t2
            for k, v in stats.timings_ms.items():
                run.stage_ms[k] = run.stage_ms.get(k, 0.0) + v
            run.frames += 1
            run.poses.append(frame.pose)
            bar.update(1)
        bar.close()
        run.skipped = {k: v for k, v in loader.skips.as_dict().items() if v}
    run.keyframes = mapper.keyframes
    run.wall_s = time.perf_counter() - t_start
    return mapper, run


def write_map_outputs(out: str | Path, mapper: PanopticMapper, run: MappingRun,
                      extra: dict[str, Any] | None = None) -> tuple[list[Entity], dict[str, Any]]:
    """entities.json + meshes, map.npz/map.json (resumable), summary.json (pictures: the tool layer)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    ents = mapper.entities()
    extract_s = time.perf_counter() - t0
    save_entities(ents, out)
    mapper.save(out)
    per_class: dict[str, int] = {}
    for e in ents:
        per_class[e.class_name] = per_class.get(e.class_name, 0) + 1
    summary = {
        "run": run.summary(), "mode": mapper.config.mode, "entities": len(ents),
        "entities_per_class": dict(sorted(per_class.items())), "extract_s": round(extract_s, 3),
        "map_blocks": mapper.tsdf.num_blocks, "map_memory_mb": round(mapper.tsdf.memory_bytes() / 2**20, 1),
        "global_segments": mapper.counts.next_label - 1, **(extra or {}),
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=1), encoding="utf-8")
    return ents, summary
