"""Paint segment candidates into one non-overlapping panoptic label image.

Every backend ends here, so all of them resolve overlaps the same way (Detectron2's panoptic
combination): things by decreasing score, each taking only still-free pixels and dropped when too
little of it stays visible; then stuff, merged to one segment per class, fills what is left.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from panoptic_mapping.segmentation.config import PaintConfig
from panoptic_mapping.segmentation.types import MaskCrop, PanopticSegmentation, Segment, SegmentCandidate


def merge_stuff(candidates: Sequence[SegmentCandidate]) -> list[SegmentCandidate]:
    """Things unchanged; stuff candidates of one class united into one (score: the highest)."""
    out: list[SegmentCandidate] = []
    stuff: dict[int, SegmentCandidate] = {}
    for c in candidates:
        if c.is_thing:
            out.append(c)
            continue
        prev = stuff.get(c.class_info.id)
        stuff[c.class_info.id] = c if prev is None else SegmentCandidate(
            prev.mask.union(c.mask), c.class_info, max(prev.score, c.score))
    return out + list(stuff.values())


def assemble(
    shape: tuple[int, int],
    candidates: Sequence[SegmentCandidate],
    config: PaintConfig | None = None,
    valid: np.ndarray | None = None,
    rng: np.random.Generator | None = None,
) -> PanopticSegmentation:
    """Label image + segment list from candidates.

    valid: optional (H, W) bool; pixels outside it stay 0 whatever the candidates say.
    rng: when given, segment ids and thing instance ids are a random permutation (ids of a real
    network carry no meaning across frames); otherwise they follow the painting order.
    """
    cfg = config or PaintConfig()
    labels = np.zeros(shape, np.int32)
    merged = merge_stuff(candidates)
    things = sorted((c for c in merged if c.is_thing), key=lambda c: -c.score)
    stuff = sorted((c for c in merged if not c.is_thing), key=lambda c: -c.score)
    painted: list[tuple[SegmentCandidate, tuple[int, int, int, int], int]] = []  # candidate, box, area
    for is_thing, group in ((True, things), (False, stuff)):
        for cand in group:
            m = _clip(cand.mask, shape)
            if m is None:
                continue
            region = labels[m.slices]
            own = m.mask if valid is None else m.mask & valid[m.slices]
            n_own = int(np.count_nonzero(own))
            free = own & (region == 0)
            n_free = int(np.count_nonzero(free))
            if n_free == 0 or n_free < cfg.min_area_px:
                continue
            if is_thing and n_free < cfg.overlap_threshold * n_own:
                continue
            region[free] = len(painted) + 1
            tight = MaskCrop(m.x, m.y, free).tight() or m  # never empty here: n_free > 0
            painted.append((cand, (tight.x, tight.y, tight.width, tight.height), n_free))
    # Later candidates only take free pixels, so each painted area and box is final when painted.
    return _finish(labels, painted, rng)


def _clip(mask: MaskCrop, shape: tuple[int, int]) -> MaskCrop | None:
    """The part of a crop inside the image (spurious blobs and dilations may reach past it)."""
    h, w = shape
    x0, y0 = max(mask.x, 0), max(mask.y, 0)
    x1, y1 = min(mask.x + mask.width, w), min(mask.y + mask.height, h)
    if x1 <= x0 or y1 <= y0:
        return None
    if (x0, y0, x1, y1) == (mask.x, mask.y, mask.x + mask.width, mask.y + mask.height):
        return mask
    return MaskCrop(x0, y0, mask.mask[y0 - mask.y : y1 - mask.y, x0 - mask.x : x1 - mask.x])


def _finish(
    labels: np.ndarray,
    painted: list[tuple[SegmentCandidate, tuple[int, int, int, int], int]],
    rng: np.random.Generator | None,
) -> PanopticSegmentation:
    n = len(painted)
    n_things = sum(c.is_thing for c, _, _ in painted)
    if rng is not None:
        new_ids = rng.permutation(n).astype(np.int32) + 1  # painted k (label k + 1) -> new_ids[k]
        labels = np.take(np.concatenate([[0], new_ids]).astype(np.int32), labels)
        instance_ids = rng.permutation(n_things) + 1
    else:
        new_ids = np.arange(1, n + 1, dtype=np.int32)
        instance_ids = np.arange(1, n_things + 1)
    segments = []
    k_thing = 0
    for k, (cand, box, area) in enumerate(painted):
        inst = 0
        if cand.is_thing:
            inst = int(instance_ids[k_thing])
            k_thing += 1
        info = cand.class_info
        segments.append(Segment(int(new_ids[k]), info.id, info.name, info.is_thing, inst, float(cand.score),
                                box, area))
    segments.sort(key=lambda s: s.id)
    return PanopticSegmentation(labels, segments)
