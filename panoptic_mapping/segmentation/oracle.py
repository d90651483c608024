"""`oracle` backend: ground-truth labels of generated scenes, spoiled to look like a real network.

The later stages (fusion, data association, map regularisation) exist to cope with noisy
per-frame segmentation; testing them on perfect labels would prove nothing, and testing them on a
real network needs weights this project cannot ship. The oracle sits in between: it starts from the
exact entity-id image of a generated frame and applies, per frame, the errors networks make
(see `OracleNoiseConfig`): missed and spurious instances, class confusion within the class table's
confusion groups, over- and under-segmentation, boundary erosion/dilation, masks bleeding onto far
background, scores, and per-frame ids that carry no identity, with frame-to-frame flicker.
Everything is drawn from a generator seeded by (seed, frame key): reproducible, and independent
of which other frames were segmented.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from scipy import ndimage

from panoptic_mapping.segmentation.base import PanopticSegmenter
from panoptic_mapping.segmentation.config import OracleConfig, OracleNoiseConfig, PaintConfig
from panoptic_mapping.segmentation.noise import (
    bleed_onto_background,
    erode_or_dilate,
    random_blob,
    split_along_line,
    touching_pairs,
)
from panoptic_mapping.segmentation.panoptic import assemble
from panoptic_mapping.segmentation.types import MaskCrop, PanopticSegmentation, SegmentationError, SegmentCandidate
from recon_core.classes import GENERIC_CLASS_NAME, ClassInfo, ClassTable, load_class_table
from recon_core.frame import RGBDFrame

#: SeedSequence entropy must be non-negative: frame keys (indices or stamps) are folded into 64 bits.
_KEY_MASK = (1 << 64) - 1


class EntityClass(NamedTuple):
    """What the oracle knows about one ground-truth entity (a value of the label image)."""

    class_name: str
    class_id: int
    is_thing: bool


class OracleSegmenter(PanopticSegmenter):
    """Ground-truth entity-id images -> noisy panoptic segmentation."""

    name = "oracle"

    def __init__(
        self,
        entities: Mapping[int, EntityClass | tuple[str, int, bool]],
        noise: OracleNoiseConfig | None = None,
        seed: int = 0,
        class_table: ClassTable | None = None,
    ) -> None:
        """entities: entity id (value in the label image) -> (class_name, class_id, is_thing)."""
        self.table = class_table or load_class_table()
        self.noise = noise or OracleNoiseConfig()
        self.seed = int(seed)
        if not entities:
            raise SegmentationError("the oracle needs at least one ground-truth entity")
        if min(entities) <= 0:
            raise SegmentationError("entity ids must be > 0 (0 marks pixels with no entity)")
        self.entities: dict[int, ClassInfo] = {}
        for eid, ent in entities.items():
            ent = EntityClass(*ent)
            info = self.table.by_name(ent.class_name)  # raises naming the known classes
            if info.id != ent.class_id or info.is_thing != ent.is_thing:
                raise SegmentationError(
                    f"entity {eid} says class {ent.class_name!r} has id {ent.class_id}, is_thing {ent.is_thing}; "
                    f"the class table says id {info.id}, is_thing {info.is_thing}"
                )
            self.entities[int(eid)] = info
        #: entity id -> known?, for a vectorised check of each label image.
        self._known = np.zeros(max(self.entities) + 1, bool)
        self._known[list(self.entities)] = True
        # Spurious blobs take a class the generated world has: not the generic class of real detectors.
        self._thing_classes = [c for c in self.table if c.is_thing and c.name != GENERIC_CLASS_NAME]

    @classmethod
    def from_ground_truth(
        cls, ground_truth: Any, config: OracleConfig | None = None, class_table: ClassTable | None = None
    ) -> OracleSegmenter:
        """From a ground-truth folder (scene.json), the generated bag beside it, or any object with
        ``.entities`` carrying ``id, class_name, class_id, is_thing``."""
        cfg = config or OracleConfig()
        if isinstance(ground_truth, (str, Path)):
            entities = load_ground_truth(ground_truth)
        elif hasattr(ground_truth, "entities"):
            entities = {e.id: EntityClass(e.class_name, e.class_id, e.is_thing) for e in ground_truth.entities}
        else:
            raise SegmentationError(f"expected a ground-truth folder or scene, got {type(ground_truth).__name__}")
        return cls(entities, cfg.noise(), cfg.seed, class_table)

    def _segment(
        self, color: np.ndarray, depth: np.ndarray | None, frame: RGBDFrame | None
    ) -> PanopticSegmentation:
        if frame is None or "labels" not in frame.extras:
            raise SegmentationError(
                "the oracle backend needs the ground-truth label image: pass frame= with extras['labels'] "
                "(generated scenes; read bags with DataInputConfig.topics.labels set)"
            )
        labels = frame.extras["labels"]
        if labels.shape != color.shape[:2]:
            raise SegmentationError(f"label image {labels.shape} and color {color.shape[:2]} differ in size")
        # keyed by the frame's stamp, not its index: the ROS service sees stamps only, and the same
        # frame must get the same noise offline (`scene-recon run`) and through the ROS graph
        return self._spoil(labels, depth, frame.timestamp_ns)

    def segment_labels(
        self, labels: np.ndarray, depth: np.ndarray | None = None, key: int = 0
    ) -> PanopticSegmentation:
        """Segment from a bare label image; `key` (frame index or stamp) seeds the frame's noise."""
        if depth is not None and depth.shape != labels.shape:
            raise SegmentationError(f"depth {depth.shape} and label image {labels.shape} differ in size")
        t0 = time.perf_counter()
        result = self._spoil(labels, depth, key)
        result.latency_ms = (time.perf_counter() - t0) * 1e3
        return result

    # ------------------------------------------------------------------ the noise model
    def _spoil(self, labels: np.ndarray, depth: np.ndarray | None, key: int) -> PanopticSegmentation:
        gt, counts = self._check_labels(labels)
        shape = gt.shape
        nz = self.noise
        rng = np.random.default_rng([self.seed & _KEY_MASK, int(key) & _KEY_MASK])
        scale = shape[0] / nz.reference_height_px
        flicker = 1.0 + nz.flicker * rng.uniform(-1.0, 1.0)

        def happens(prob: float) -> bool:
            return prob > 0 and rng.random() < min(prob * flicker, 1.0)

        slices = ndimage.find_objects(gt)
        crops = {eid: MaskCrop(sl[1].start, sl[0].start, gt[sl] == eid)
                 for eid, sl in enumerate(slices, start=1) if sl is not None}
        groups = self._merge_groups(gt, crops, rng, flicker)
        candidates: list[SegmentCandidate] = []
        stuff: dict[int, MaskCrop] = {}
        for group in groups:
            info = self.entities[group[0]]
            mask = crops[group[0]]
            for eid in group[1:]:
                mask = mask.union(crops[eid])
            if not info.is_thing:
                stuff[info.id] = mask if info.id not in stuff else stuff[info.id].union(mask)
                continue
            candidates.extend(self._spoil_thing(mask, info, depth, shape, scale, rng, happens))
        for class_id, stuff_mask in stuff.items():
            kept = self._boundary(stuff_mask, shape, scale, rng, happens) if nz.stuff_boundary_noise else stuff_mask
            if kept is not None:
                candidates.append(SegmentCandidate(kept, self.table.by_id(class_id), self._score(rng, nz.score_mean)))
        for _ in range(rng.poisson(nz.spurious_rate * flicker) if nz.spurious_rate > 0 else 0):
            blob = random_blob(rng, shape, (nz.spurious_axes_px[0] * scale, nz.spurious_axes_px[1] * scale))
            info = self._thing_classes[int(rng.integers(len(self._thing_classes)))]
            candidates.append(SegmentCandidate(blob, info, self._score(rng, nz.spurious_score_mean)))
        paint = PaintConfig(nz.paint.overlap_threshold, round(nz.paint.min_area_px * scale * scale))
        valid = gt != 0 if counts[0] else None
        return assemble(shape, candidates, paint, valid=valid, rng=rng)

    def _spoil_thing(
        self,
        mask: MaskCrop,
        info: ClassInfo,
        depth: np.ndarray | None,
        shape: tuple[int, int],
        scale: float,
        rng: np.random.Generator,
        happens: Callable[[float], bool],
    ) -> list[SegmentCandidate]:
        nz = self.noise
        area = mask.area
        small = max(0.0, 1.0 - area / max(nz.small_area_px * scale * scale, 1.0))
        p_miss = nz.miss_prob + nz.miss_prob_small * small + nz.miss_prob_truncated * mask.touches_border(shape)
        if happens(min(p_miss, 1.0)):
            return []
        if info.confusable_with and happens(nz.confusion_prob):
            info = self.table.by_name(info.confusable_with[int(rng.integers(len(info.confusable_with)))])
        noisy = self._boundary(mask, shape, scale, rng, happens)
        if noisy is None:
            return []
        mask = noisy
        if depth is not None and happens(nz.bleed_prob):
            radius = max(round(nz.bleed_radius_px * scale), 1)
            mask = bleed_onto_background(mask, depth, radius, nz.bleed_depth_gap_m)
        parts: tuple[MaskCrop, ...] = (mask,)
        if area >= nz.split_min_area_px * scale * scale and happens(nz.split_prob):
            parts = split_along_line(mask, float(rng.uniform(0.0, math.pi))) or parts
        return [SegmentCandidate(p, info, self._score(rng, nz.score_mean)) for p in parts]

    def _boundary(
        self,
        mask: MaskCrop,
        shape: tuple[int, int],
        scale: float,
        rng: np.random.Generator,
        happens: Callable[[float], bool],
    ) -> MaskCrop | None:
        nz = self.noise
        if nz.boundary_max_radius_px <= 0 or not happens(nz.boundary_prob):
            return mask
        # radius drawn in this image's pixels, so an event always changes the outline (>= 1 px)
        radius = int(rng.integers(1, max(round(nz.boundary_max_radius_px * scale), 1) + 1))
        return erode_or_dilate(mask, radius, dilate=bool(rng.random() < 0.5), shape=shape)

    def _score(self, rng: np.random.Generator, mean: float) -> float:
        nz = self.noise
        value = rng.normal(mean, nz.score_std) if nz.score_std > 0 else mean
        return float(np.clip(value, nz.score_min, 1.0))

    def _merge_groups(
        self, gt: np.ndarray, crops: dict[int, MaskCrop], rng: np.random.Generator, flicker: float
    ) -> list[list[int]]:
        """Entity ids grouped by under-segmentation: touching same-class things merged at random."""
        ids = sorted(crops)
        p = min(self.noise.merge_prob * flicker, 1.0)
        thing_classes = [self.entities[i].id for i in ids if self.entities[i].is_thing]
        if p <= 0 or len(set(thing_classes)) == len(thing_classes):  # no two things of one class in view
            return [[i] for i in ids]
        parent = {i: i for i in ids}

        def root(i: int) -> int:
            while parent[i] != i:
                parent[i] = parent[parent[i]]
                i = parent[i]
            return i

        for a, b in touching_pairs(gt):
            ia, ib = self.entities[int(a)], self.entities[int(b)]
            if ia.is_thing and ib.is_thing and ia.id == ib.id and rng.random() < p:
                parent[root(int(b))] = root(int(a))
        groups: dict[int, list[int]] = {}
        for i in ids:
            groups.setdefault(root(i), []).append(i)
        return list(groups.values())

    def _check_labels(self, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """int32 view of the label image and its per-id pixel counts; unknown ids raise."""
        gt = np.asarray(labels)
        if gt.ndim != 2 or gt.dtype.kind not in "iu" or gt.size == 0:
            raise SegmentationError(f"label image must be a non-empty 2D integer array, got {gt.dtype} {gt.shape}")
        gt = gt.astype(np.int32, copy=False)
        if int(gt.min()) >= 0 and int(gt.max()) < self._known.size:
            counts = np.bincount(gt.ravel())
            present = np.flatnonzero(counts[1:]) + 1
            if self._known[present].all():
                return gt, counts
        present_ids = set(np.unique(gt).tolist()) - {0}
        raise SegmentationError(
            f"label image holds entity ids {sorted(present_ids - set(self.entities))} that the ground truth "
            f"does not know (known: {sorted(self.entities)}); is it the right scene?"
        )


def load_ground_truth(path: str | Path) -> dict[int, EntityClass]:
    """Entity id -> class of a recording's ground truth, read from its ``scene.json`` as plain data.

    ``path`` is the ground-truth folder, its scene.json, or the recorded bag beside it
    (``<bag>_groundtruth/``). Only the annotation is read: the label images themselves come with the
    recording (its labels topic), so the oracle never needs the simulator.
    """
    p = Path(path)
    base = p.parent if p.is_file() and p.suffix in (".mcap", ".db3") else p
    candidates = [p, base.with_name(base.name + "_groundtruth")]
    for c in candidates:
        f = c if c.is_file() and c.name == "scene.json" else c / "scene.json"
        if f.is_file():
            try:
                data = json.loads(f.read_text(encoding="utf-8"))
                return {int(d["id"]): EntityClass(d["class_name"], int(d["class_id"]), bool(d["is_thing"]))
                        for d in data["entities"]}
            except (OSError, ValueError, KeyError, TypeError) as exc:
                raise SegmentationError(f"{f}: cannot read the ground-truth annotation: {exc}") from exc
    raise SegmentationError(
        f"no ground truth at {p}: expected a folder with scene.json (`scene-recon generate` writes it as "
        "<bag>_groundtruth/), or the generated bag folder beside it"
    )
