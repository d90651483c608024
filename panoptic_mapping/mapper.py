"""The volumetric panoptic mapper (paper Sec. 3): ROS-free core used by the CLI and the node.

Per frame: depth segmentation -> fusion with the panoptic masks (Sec. 3.1) -> association of the
frame segments to global segments and of their instances to global instances (Sec. 3.2) ->
TSDF + label integration and the triple count Phi (Eq. 4, Sec. 3.3); periodically the map is
regularised (segment merging, instance merging by Eq. 5); entities are extracted by Eq. (6).

`mode="baseline"` reproduces Voxblox++-style fusion for the paper's ablation: greedy label
assignment without split or clustering, and separate semantic and instance tracking (instances
are associated and extracted ignoring the class; no instance merging).
"""

from __future__ import annotations

import copy
import hashlib
import io
import json
import logging
import time
import zipfile
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from panoptic_mapping.config import MapperConfig
from panoptic_mapping.depth_segmentation import backproject_planes, segment_depth_planes
from panoptic_mapping.fine_surface import FineSurfaceMap, assign_fine_vertices, fine_coverage
from panoptic_mapping.free_space import FreeSpaceViews
from panoptic_mapping.fusion import BACKGROUND, FrameSegments, PanopticMasks, fuse
from panoptic_mapping.image_ops import downsample_depth, downsample_labels
from panoptic_mapping.panoptic_counts import PanopticCounts
from panoptic_mapping.tsdf_map import LabeledTSDF
from recon_core.entity import Entity
from recon_core.errors import CheckpointError
from recon_core.frame import CameraIntrinsics, RGBDFrame
from recon_core.io import write_bytes_atomic, write_text_atomic

log = logging.getLogger(__name__)
MAP_FORMAT_VERSION = 1
#: Id of the entity holding reconstructed surface no entity claims (class -1, "unknown").
UNKNOWN_ENTITY_ID = 0
#: Farthest a camera may be from the map's origin (m). Past it float32 points lose centimetres
#: (ulp 1 cm at 131 km) and block keys overflow (2^20 blocks of 16 cm: 167 km): recentre the map.
MAX_LOCAL_DISTANCE_M = 100_000.0


@dataclass
class ClassMeta:
    """What the mapper needs to know about a class id."""

    name: str
    is_thing: bool
    category: str
    #: the class table's largest extent (m) of an instance; None: not given
    max_size_m: float | None = None


@dataclass
class FrameStats:
    keyframe: bool
    segments: int
    new_labels: int
    split: int
    clustered_out: int
    timings_ms: dict[str, float] = field(default_factory=dict)


def _pose_change(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Translation (m) and rotation angle (deg) from camera pose ``a`` to ``b`` (4x4, float64)."""
    delta = np.linalg.inv(np.asarray(a, np.float64)) @ np.asarray(b, np.float64)
    angle = np.degrees(np.arccos(np.clip((np.trace(delta[:3, :3]) - 1) / 2, -1.0, 1.0)))
    return float(np.linalg.norm(delta[:3, 3])), float(angle)


class PanopticMapper:
    """Incremental panoptic TSDF map. Call `integrate(frame, masks)` per frame, `entities()` at will."""

    def __init__(self, config: MapperConfig | None = None, classes: dict[int, ClassMeta] | None = None):
        self.config = config or MapperConfig()
        self.classes = classes or {}
        self.tsdf = LabeledTSDF(self.config.tsdf)
        fine = self.config.fine_surface
        self.fine = FineSurfaceMap(fine, self.config.tsdf) if fine.enabled else None
        free = self.config.free_space
        self.free_space = FreeSpaceViews(free, self.config.tsdf.voxel_size_m) if free.enabled else None
        self.counts = PanopticCounts()
        self.merge_votes: dict[tuple[int, int], int] = {}
        self.frames_integrated = 0
        self.keyframes = 0
        self._entity_cache: tuple | None = None
        self._last_key_pose: np.ndarray | None = None
        self._last_key_time: int | None = None
        #: (input pose, stamp) of the last integrated frame and how many frames were integrated from
        #: that viewpoint in a row: a still camera's frames are skipped (`is_static`)
        self._last_integrated: tuple[np.ndarray, int] | None = None
        self._still_views = 0
        #: Position of this map's origin in the input's map frame (m, float64): poses are integrated
        #: relative to it, and every output (voxels, meshes, entities) is in these local coordinates.
        #: Non-zero for recordings far from their frame's origin (UTM-like coordinates), see `recentre`.
        self.origin_offset = np.zeros(3)
        #: Transform from the input's world frame to the gravity-aligned (z up) map frame, applied to
        #: every camera pose before `origin_offset` (identity: the input is z up). See `set_alignment`.
        self.alignment = np.eye(4)
        #: How the alignment was found (mode, estimate, angle): written to map.json.
        self.gravity: dict = {}

    def set_alignment(self, transform: np.ndarray, info: dict | None = None) -> None:
        """Integrate future poses pre-multiplied by `transform` (input world -> gravity-aligned map frame)."""
        t = np.asarray(transform, dtype=np.float64).reshape(4, 4)
        if self.frames_integrated and not np.allclose(t, self.alignment):
            raise ValueError("the gravity alignment can only be chosen before the first frame is integrated")
        self.alignment = t.copy()
        self.gravity = dict(info or {})

    def aligned_pose(self, pose: np.ndarray) -> np.ndarray:
        """Camera pose in the gravity-aligned frame (before recentring)."""
        if np.array_equal(self.alignment, np.eye(4)):
            return pose
        return self.alignment @ np.asarray(pose, dtype=np.float64)

    def recentre(self, offset: np.ndarray) -> None:
        """Integrate future poses relative to `offset` (before the first frame, or when resuming)."""
        if self.frames_integrated and not np.allclose(offset, self.origin_offset):
            raise ValueError("the map origin can only be chosen before the first frame is integrated")
        self.origin_offset = np.asarray(offset, dtype=np.float64).reshape(3).copy()

    def local_pose(self, pose: np.ndarray) -> np.ndarray:
        """Camera-to-map `pose` gravity aligned and expressed relative to the map's origin (float64)."""
        pose = self.aligned_pose(pose)
        if not np.any(self.origin_offset):
            return pose
        out = np.array(pose, dtype=np.float64)
        out[:3, 3] -= self.origin_offset
        return out

    @property
    def full(self) -> bool:
        return self.config.mode == "full"

    # ------------------------------------------------------------------ keyframes
    def is_keyframe(self, frame: RGBDFrame, since: tuple[np.ndarray, int] | None = None) -> bool:
        """Pose moved or time passed enough since the last keyframe (or gating disabled); `since`: the
        (pose, stamp) of a keyframe to test against instead of the last one marked."""
        kc = self.config.keyframes
        key_pose, key_time = since if since is not None else (self._last_key_pose, self._last_key_time)
        if not kc.enabled or key_pose is None or frame.pose is None:
            return True
        moved, angle = _pose_change(key_pose, frame.pose)
        late = (frame.timestamp_ns - (key_time or 0)) * 1e-9 >= kc.max_interval_s
        return bool(moved >= kc.min_translation_m or angle >= kc.min_rotation_deg or late)

    def is_static(self, frame: RGBDFrame) -> bool:
        """The camera stood still since the last integrated frame (``static.*``): the frame adds nothing
        and callers skip it whole, segmentation included; never for longer than ``static.max_interval_s``."""
        sc = self.config.static
        if not sc.enabled or self._last_integrated is None or frame.pose is None or self._still_views < sc.min_views:
            return False
        stamp = self._last_integrated[1]
        return abs(frame.timestamp_ns - stamp) * 1e-9 < sc.max_interval_s and self._still_since_last(frame.pose)

    def _still_since_last(self, pose: np.ndarray) -> bool:
        """``pose`` is within ``static.max_translation_m`` / ``max_rotation_deg`` of the last integrated frame's."""
        if self._last_integrated is None:
            return False
        moved, angle = _pose_change(self._last_integrated[0], pose)
        sc = self.config.static
        return moved < sc.max_translation_m and angle < sc.max_rotation_deg

    def _integrated(self, frame: RGBDFrame) -> None:
        """Bookkeeping after a frame was integrated: the count, and the viewpoint for `is_static`."""
        self.frames_integrated += 1
        pose = np.asarray(frame.pose, np.float64)
        self._still_views = self._still_views + 1 if self._still_since_last(pose) else 1
        self._last_integrated = (pose, frame.timestamp_ns)

    def mark_keyframe(self, frame: RGBDFrame) -> None:
        self._last_key_pose = frame.pose
        self._last_key_time = frame.timestamp_ns
        self.keyframes += 1

    # ------------------------------------------------------------------ per frame
    def _checked_pose(self, frame: RGBDFrame) -> np.ndarray:
        """The frame's camera-to-map pose relative to the map origin; raises when there is none or it is too far."""
        if frame.pose is None:
            raise ValueError("the mapper needs a camera pose for every frame")
        pose = self.local_pose(frame.pose)
        dist = float(np.linalg.norm(pose[:3, 3]))
        if dist > MAX_LOCAL_DISTANCE_M:
            raise ValueError(f"camera is {dist / 1000:.1f} km from the map origin: float32 voxels collapse that far; "
                             "recentre the map on the first pose (PanopticMapper.recentre, done by map_recording)")
        return pose

    def fuses_labels(self, masks: PanopticMasks | None) -> bool:
        """Whether `integrate(frame, masks)` fuses labels now: masks given, or a label-propagation frame
        (every `keyframes.label_every_n_frames`-th frame); all others take the geometry-only path."""
        return masks is not None or self.propagates_labels()

    def propagates_labels(self, frames_from_now: int = 0) -> bool:
        """Whether the frame integrated `frames_from_now` frames after the next one is a label-propagation
        frame (every `keyframes.label_every_n_frames`-th): what the segmentation ahead of time guesses by."""
        n_label = self.config.keyframes.label_every_n_frames
        return n_label > 0 and (self.frames_integrated + frames_from_now) % n_label == 0

    def integrate_geometry(self, frame: RGBDFrame) -> FrameStats:
        """Integrate one posed frame's depth into the TSDF only (the geometry-only fast path).

        No depth segmentation, normals, association, label votes or Phi counts: what mapping without a
        segmenter (`--segmenter none`) does for every frame, and what `integrate` does between keyframes
        on frames that propagate no labels. Costs Open3D's integration plus a depth range threshold
        (and the downsampling when `downsample` > 1); nothing here grows with the map. The voxels'
        labels are left as they are: extraction gives unlabelled surface to the 'unknown' entity.
        """
        pose = self._checked_pose(frame)
        t0 = time.perf_counter()
        ds = self.config.downsample
        intr = frame.intrinsics if ds == 1 else frame.intrinsics.scaled(1.0 / ds)
        self.tsdf.integrate_depth(downsample_depth(frame.depth, ds), intr.matrix, pose)
        self._integrated(frame)
        return FrameStats(False, 0, 0, 0, 0, {"integration": (time.perf_counter() - t0) * 1000})

    def label_depth(self, frame: RGBDFrame) -> tuple[np.ndarray, CameraIntrinsics, float]:
        """What a label frame is segmented from: the in-range depth at the processing resolution (only
        readings within [min_depth_m, max_depth_m] allocate blocks or carry labels), its intrinsics and
        the pixel area scale. A pure function of the frame and the config, like the depth segmentation
        of it (`segment_depth_labels`): both can be computed ahead, on another core (`pipeline`)."""
        ds = self.config.downsample
        depth = self.tsdf.in_range(np.asarray(downsample_depth(frame.depth, ds), np.float32))
        return depth, (frame.intrinsics if ds == 1 else frame.intrinsics.scaled(1.0 / ds)), 1.0 / (ds * ds)

    def integrate(self, frame: RGBDFrame, masks: PanopticMasks | None,
                  depth_segments: tuple[np.ndarray, np.ndarray] | None = None) -> FrameStats:
        """Integrate one posed frame; `masks` (full-resolution panoptic masks) only on keyframes.

        Frames without masks that propagate no labels (see `fuses_labels`) take `integrate_geometry`.
        `depth_segments`: (`label_depth(frame)[0]`, `segment_depth_labels` of it) computed ahead, or None.
        """
        if not self.fuses_labels(masks):
            # geometry only: labels come from keyframes (the extraction fills the fringe)
            return self.integrate_geometry(frame)
        pose = self._checked_pose(frame)
        t0 = time.perf_counter()
        cfg = self.config
        ds = cfg.downsample
        intr, area = (frame.intrinsics if ds == 1 else frame.intrinsics.scaled(1.0 / ds)), 1.0 / (ds * ds)
        t = {}
        if depth_segments is None:
            depth = self.label_depth(frame)[0]
            geo, planes, _normals = segment_depth_planes(depth, intr, cfg.depth_segmentation, pixel_area_scale=area)
        else:  # segmented ahead (the same labels); the points `segment_depth_planes` would return
            depth, geo = depth_segments
            planes = backproject_planes(depth, intr)
        points = cv2.merge(list(planes))
        t["depth_segmentation"] = time.perf_counter()
        if masks is not None:
            masks = PanopticMasks(downsample_labels(masks.labels, ds), masks.class_id, masks.is_thing, masks.score)
        else:
            masks = PanopticMasks.empty(depth.shape)
        min_pts = max(1, round(cfg.fusion.min_segment_points * area))
        segs = fuse(geo, masks, points, cfg.fusion, full=self.full, min_points=min_pts,
                    min_rescue_points=self._min_rescue_points(area))
        t["fusion"] = time.perf_counter()
        # only every `stride`-th pixel (both directions) is associated and voted: transform just those
        # ((N, 3) @ (3, 3) in numpy is slow for this shape; cv2.transform is a tight C loop)
        stride = max(1, cfg.association.pixel_stride)
        sampled = np.ascontiguousarray(points[::stride, ::stride]).reshape(-1, 1, 3)
        world = cv2.transform(sampled, pose[:3, :].astype(np.float32)).reshape(-1, 3)
        segmented = bool(masks.labels.any())
        seg_flat = np.ascontiguousarray(segs.image[::stride, ::stride]).ravel()
        label_of_seg, new_labels, map_labels = self._associate(segs, world, seg_flat, seg_flat.size / segs.image.size,
                                                               count_merges=segmented)
        t["association"] = time.perf_counter()
        if segmented:
            self._vote(segs, label_of_seg, _segment_area(seg_flat, sampled, intr.matrix, stride, segs.count + 1))
        pix_labels = label_of_seg[seg_flat]
        has = pix_labels > 0
        if not segmented:
            # frames without fresh masks fill unknown voxels but never fight labels the map holds
            # (a purely geometric segment may be under-segmented: floor + wall in one piece)
            has &= (map_labels == 0) | (map_labels == pix_labels)
        lut = self.counts.canonical_lut()
        self.tsdf.integrate_labels(world[has], pix_labels[has], lut)
        for label in np.unique(pix_labels[has]).tolist():
            self.counts.last_update[int(label)] = self.frames_integrated
        t["label_integration"] = time.perf_counter()
        self.tsdf.integrate_depth(depth, intr.matrix, pose, in_range=True)
        if self.free_space is not None:
            self.free_space.add(depth, intr.matrix, pose)
        t["integration"] = time.perf_counter()
        if self.fine is not None:
            small = self._small_label_lut(pix_labels)
            if small.any():
                full = label_of_seg[segs.image]
                mask, vote = self.fine.small_pixels(full, small)
                self.fine.integrate(depth, mask, intr.matrix, pose, points, full, lut, vote)
            t["fine_surface"] = time.perf_counter()
        self._integrated(frame)
        every = cfg.regularization.every_n_frames
        if every and self.frames_integrated % every == 0:
            self.regularize()
        t["regularization"] = time.perf_counter()
        timings, prev = {}, t0
        for k, v in t.items():
            timings[k] = (v - prev) * 1000
            prev = v
        return FrameStats(bool(masks.labels.any()), segs.count, new_labels, segs.num_split, segs.num_clustered_out,
                          timings)

    def _min_rescue_points(self, area: float) -> int:
        """Fewest pixels (at processing resolution) a thing mask the depth segmentation left all edge needs
        to become a labelled segment of its own (`fusion.fuse`).

        A cup or a bottle 2-3 m away is 50-150 pixels a frame and every one of them a depth edge: under
        `fusion.min_segment_points` in every frame, however many frames see it, so the map never held a
        vote for it (bench-clutter's cup: 9 876 pixels over 61 frames, 3 of its 5 keyframes with a cup mask;
        docs/STAGE2_MAPPING.md). When a thing is born only from `extraction.min_instance_frames` > 1
        segmented frames, one frame's mask is a vote the birth rule weighs, so the floor drops to the
        association's own (`association.min_overlap_points`: the fewest pixels a segment can be found
        again in the map by); with the paper's birth (one frame) each frame must still be convincing alone.
        """
        cfg = self.config
        floor = cfg.fusion.min_segment_points
        if cfg.extraction.min_instance_frames > 1:
            floor = min(floor, cfg.association.min_overlap_points)
        return max(1, round(floor * area))

    def _small_class(self, class_id: int) -> bool:
        """A rigid thing class small enough for the fine surface (`fine_surface.max_class_size_m`); an
        articulated one (a microwave) keeps the surface its parts were fitted on."""
        meta = self.classes.get(class_id)
        return bool(meta is not None and meta.is_thing and meta.category == "rigid" and meta.max_size_m is not None
                    and meta.max_size_m <= self.config.fine_surface.max_class_size_m)

    def _carved_class(self, class_id: int) -> bool:
        """A thing class whose surface the free-space test applies to (`free_space.max_class_size_m`)."""
        limit = self.config.free_space.max_class_size_m
        if limit <= 0:
            return True
        meta = self.classes.get(class_id)
        return meta is not None and meta.max_size_m is not None and meta.max_size_m <= limit

    def _small_label_lut(self, pix_labels: np.ndarray) -> np.ndarray:
        """Per map label (index) whether its voted class is a small thing, for the labels in a frame."""
        present = np.unique(pix_labels)
        present = present[present > 0]
        lut = np.zeros(int(present.max()) + 1 if len(present) else 1, bool)
        for label in present.tolist():
            lut[label] = self._small_class(self.counts.segment_class(self.counts.canonical(label))[0])
        return lut

    def _associate(self, segs: FrameSegments, world: np.ndarray, flat: np.ndarray, sampled_share: float,
                   count_merges: bool) -> tuple[np.ndarray, int, np.ndarray]:
        """Global segment label of each frame segment (greedy by 3D overlap, Sec. 3.2).

        `flat`: the segment id of each sampled pixel, `world` its map-frame point, `sampled_share` the share of
        the image's pixels sampled. Returns (label per segment id, number of new labels, canonical map
        label per sampled pixel).
        """
        ac = self.config.association
        n = segs.count + 1
        label_of = np.zeros(n, np.int64)
        sel = flat > 0
        pixel_map_labels = np.zeros(flat.size, np.int64)
        if not np.any(sel):
            return label_of, 0, pixel_map_labels
        seg_ids = flat[sel].astype(np.int64)
        lut = self.counts.canonical_lut()
        map_labels = lut[self.tsdf.labels_at(world[sel])]
        pixel_map_labels[sel] = map_labels
        size = np.bincount(seg_ids, minlength=n)
        hit = map_labels > 0
        pairs = seg_ids[hit] * (int(lut.size) + 1) + map_labels[hit]
        keys, counts = np.unique(pairs, return_counts=True)
        p_seg, p_lab = keys // (int(lut.size) + 1), keys % (int(lut.size) + 1)
        share = counts / np.maximum(size[p_seg], 1)
        # merge evidence: a segment overlapping several global segments substantially (counted on
        # segmented frames only, where the split step has separated what the masks tell apart)
        strong = share >= ac.merge_overlap_share
        if count_merges and np.any(strong):
            for s in np.unique(p_seg[strong]):
                labs = sorted(set(p_lab[strong & (p_seg == s)].tolist()))
                for i in range(len(labs)):
                    for j in range(i + 1, len(labs)):
                        key = (labs[i], labs[j])
                        self.merge_votes[key] = self.merge_votes.get(key, 0) + 1
        min_points = max(1, round(ac.min_overlap_points * sampled_share))  # counts are of sampled pixels
        ok = (counts >= min_points) & (share >= ac.min_overlap_share)
        order = np.argsort(-counts[ok], kind="stable")
        taken: set[int] = set()
        for s, lab in zip(p_seg[ok][order].tolist(), p_lab[ok][order].tolist(), strict=True):
            if label_of[s] == 0 and lab not in taken:
                label_of[s] = lab
                taken.add(lab)
        new = 0
        for s in range(1, n):
            if label_of[s] == 0 and size[s] > 0:
                label_of[s] = self.counts.new_label()
                new += 1
        return label_of, new, pixel_map_labels

    def _vote(self, segs: FrameSegments, label_of: np.ndarray, seg_area: np.ndarray | None = None) -> None:
        """Instance association (Sec. 3.2) and the count update (Eq. 4) for a segmented frame; `seg_area`:
        each segment's fronto-parallel surface (m^2, `_segment_area`), for `PanopticCounts.instance_area`."""
        by_mask: dict[int, list[int]] = {}
        for s in range(1, segs.count + 1):
            if segs.class_id[s] == BACKGROUND or label_of[s] == 0:
                continue
            if not segs.is_thing[s]:
                c = int(segs.class_id[s])
                self.counts.add(int(label_of[s]), c, self.counts.instance_for_stuff(c))
                continue
            by_mask.setdefault(int(segs.mask_id[s]), []).append(s)
        # each frame instance picks the global instance with most votes among its segments' past
        # predictions (joint: same class only; baseline: any class); one frame instance per global one
        proposals = []
        for m, ss in by_mask.items():
            c = int(segs.class_id[ss[0]])
            votes: dict[int, int] = {}
            for s in ss:
                for p, v in self.counts.instance_votes(int(label_of[s]), c if self.full else None).items():
                    votes[p] = votes.get(p, 0) + v
            proposals.append((m, c, ss, votes))
        proposals.sort(key=lambda x: -max(x[3].values(), default=0))
        used: set[int] = set()
        for _m, c, ss, votes in proposals:
            choice = next((p for p, _ in sorted(votes.items(), key=lambda kv: -kv[1]) if p not in used), None)
            if choice is None:
                choice = self.counts.new_instance()
            used.add(choice)
            self.counts.instance_frames[choice] = self.counts.instance_frames.get(choice, 0) + 1
            if seg_area is not None:
                area = float(seg_area[ss].sum())
                self.counts.instance_area[choice] = max(self.counts.instance_area.get(choice, 0.0), area)
            for s in ss:
                self.counts.add(int(label_of[s]), c, choice)  # Eq. (4)

    # ------------------------------------------------------------------ regularization
    def regularize(self) -> dict[str, int]:
        """Segment merging (shared voxels seen in >= merge_min_frames frames) and instance merging (Eq. 5)."""
        ac, rc = self.config.association, self.config.regularization
        merged_segments = 0
        for (a, b), n in sorted(self.merge_votes.items(), key=lambda kv: -kv[1]):
            if n < ac.merge_min_frames:
                continue
            ca, cb = self.counts.canonical(a), self.counts.canonical(b)
            if ca == cb:
                continue
            if self.full:
                # joint treatment: never merge segments whose semantics disagree
                cls_a, cls_b = self.counts.segment_class(ca)[0], self.counts.segment_class(cb)[0]
                if BACKGROUND not in (cls_a, cls_b) and cls_a != cls_b:
                    continue
            self.counts.merge_labels(max(ca, cb), min(ca, cb))
            merged_segments += 1
        self.merge_votes = {k: v for k, v in self.merge_votes.items() if v < ac.merge_min_frames}
        merged_instances = 0
        if self.full:
            merged_instances = self._merge_instances(rc.instance_merge_ratio, rc.instance_merge_min_votes)
        return {"segments": merged_segments, "instances": merged_instances}

    def _merge_instances(self, ratio: float, min_votes: int) -> int:
        """Eq. (5): merge p2 into p1 (same class c) when their shared-segment votes dominate."""
        total: dict[tuple[int, int], int] = {}
        shared: dict[tuple[int, int, int], int] = {}
        for counts in self.counts.phi.values():
            by_class: dict[int, list[tuple[int, int]]] = {}
            for (c, p), n in counts.items():
                total[(c, p)] = total.get((c, p), 0) + n
                by_class.setdefault(c, []).append((p, n))
            for c, lst in by_class.items():
                if len(lst) < 2 or c not in self.classes or not self.classes[c].is_thing:
                    continue
                for i in range(len(lst)):
                    for j in range(i + 1, len(lst)):
                        (p1, n1), (p2, n2) = sorted([lst[i], lst[j]])
                        key = (c, p1, p2)
                        shared[key] = shared.get(key, 0) + n1 + n2
        merged = 0
        alias: dict[int, int] = {}

        def root(p: int) -> int:
            while p in alias:
                p = alias[p]
            return p

        for (c, p1, p2), s in sorted(shared.items(), key=lambda kv: -kv[1]):
            denom = total[(c, p1)] + total[(c, p2)]
            if s >= ratio * denom and s > min_votes:
                r1, r2 = root(p1), root(p2)
                if r1 != r2:
                    alias[max(r1, r2)] = min(r1, r2)
                    merged += 1
        for src in sorted(alias, reverse=True):
            self.counts.merge_instances(src, root(src))
        return merged

    # ------------------------------------------------------------------ extraction
    def entities(self, with_meshes: bool = True) -> list[Entity]:
        """Panoptic entities by Eq. (6), each with the mesh of its segments.

        Nothing is recomputed while no frame was integrated since the last call (a node publishing
        at a fixed rate over a paused stream costs nothing).
        """
        key = (self.frames_integrated, with_meshes, self.counts.next_label, self.counts.next_instance)
        if self._entity_cache is not None and self._entity_cache[0] == key:
            return list(self._entity_cache[1])
        ents = self._extract(with_meshes)
        self._entity_cache = (key, ents)
        return list(ents)

    def _extract(self, with_meshes: bool) -> list[Entity]:
        """Entities of the regularised map; the map itself is left as it was.

        Regularising merges labels; done in place, an extraction changed how later frames were
        associated, so the map depended on when (and how often) someone asked for entities: the ROS
        node publishes every few seconds, `scene-recon map` extracts once at the end, and their maps of
        one bag differed (vertex counts 1% apart). The merges are made on a copy of the counts."""
        saved = copy.deepcopy(self.counts), dict(self.merge_votes)
        try:
            return self._extract_regularized(with_meshes)
        finally:
            self.counts, self.merge_votes = saved

    def _extract_regularized(self, with_meshes: bool) -> list[Entity]:
        self.regularize()
        counts = self.counts
        seg_class: dict[int, tuple[int, int]] = {}
        seg_instance: dict[int, int] = {}
        for label in list(counts.phi):
            c, votes_c, _ = counts.segment_class(label)  # Eq. (6), first line
            if c == BACKGROUND or votes_c == 0:
                continue
            # Eq. (6), second line: argmax_p Phi(l, c_l, p); the baseline tracks instances apart from class
            votes = counts.instance_votes(label, c if self.full else None)
            p = max(votes, key=lambda k: (votes[k], -k))
            seg_class[label] = (c, votes_c)
            seg_instance[label] = p
        # group segments per entity: things by instance, stuff by class
        groups: dict[int, list[int]] = {}
        fragments: dict[int, list[int]] = {}
        # a map whose instances were each segmented once (one keyframe so far) has nothing to confirm
        # a detection against: then one frame is enough
        seen_most = max(counts.instance_frames.values(), default=0)
        min_frames = min(self.config.extraction.min_instance_frames, max(seen_most, 1))
        for label, p in seg_instance.items():
            c = seg_class[label][0]
            meta = self.classes.get(c)
            thing = meta is None or meta.is_thing
            if thing and counts.instance_frames.get(p, 0) < min_frames:
                # seen in too few segmented frames: what one bad frame says (a spurious blob, a split-off
                # piece of a mask) is no object; a piece touching its own class's entity joins it
                fragments.setdefault(p, []).append(label)
                continue
            key = p if thing else counts.instance_for_stuff(c)
            groups.setdefault(key, []).append(label)
        ents: list[Entity] = []
        lut_size = counts.next_label
        entity_of_label = np.zeros(lut_size, np.int64)
        for eid, labels in groups.items():
            class_votes: dict[int, int] = {}
            for label in labels:
                for (c, _p), n in counts.phi[label].items():
                    class_votes[c] = class_votes.get(c, 0) + n
            c = max(class_votes, key=lambda k: (class_votes[k], -k))
            meta = self.classes.get(c, ClassMeta(f"class_{c}", True, "rigid"))
            conf = class_votes[c] / max(sum(class_votes.values()), 1)
            revision = max(counts.last_update.get(label, 0) for label in labels)
            ents.append(Entity(eid, meta.name, class_id=c, instance_id=eid if meta.is_thing else 0,
                               is_thing=meta.is_thing, category=meta.category, confidence=float(conf),
                               revision=int(revision)))
            entity_of_label[labels] = eid
        unknown = None
        if with_meshes and self.config.extraction.include_unknown:
            # all reconstructed surface that no entity claims: evaluation must see it as geometry
            unknown = Entity(UNKNOWN_ENTITY_ID, "unknown", class_id=BACKGROUND, is_thing=False, category="unknown",
                             confidence=0.0)
        fragment_of_label = np.zeros(lut_size, np.int64)
        fragment_class: list[int] = []
        if with_meshes and self.config.extraction.merge_fragments:
            for labels in fragments.values():
                fragment_class.append(seg_class[labels[0]][0])
                fragment_of_label[labels] = len(fragment_class)
        areas: dict[int, float] = {}
        if with_meshes:
            areas = self._attach_meshes(ents, entity_of_label, unknown, fragment_of_label,
                                        np.array(fragment_class, np.int64))
        min_v = self.config.extraction.min_entity_voxels
        out = [e for e in ents if not with_meshes or (len(e.vertices) >= min_v and not self._overruled(e, areas))]
        if with_meshes:
            self._attach_observed_space(out)
        if unknown is not None and len(unknown.faces):
            out.append(unknown)
        return out

    def _attach_observed_space(self, ents: list[Entity]) -> None:
        """Each thing entity's grid of observed and unknown space around it (`free_space.observed_grid`):
        over its core's box grown by `observed_grid_margin` of its largest extent (within the configured
        bounds) on every side, from the stored label-frame views. A cell holding another entity's
        surface counts as observed too: the space is taken, whether a view saw it or not."""
        cfg = self.config.free_space
        if self.free_space is None or not cfg.enabled or not cfg.observed_grid or not len(self.free_space):
            return
        owners = [e for e in ents if not e.is_empty]
        surface = np.concatenate([e.vertices for e in owners]) if owners else np.zeros((0, 3))
        owner = np.repeat(np.array([e.id for e in owners], np.int64), [len(e.vertices) for e in owners])
        by_x = np.argsort(surface[:, 0], kind="stable")  # each grid reads the slab of x it spans
        surface, owner = surface[by_x], owner[by_x]
        for e in ents:
            if not e.is_thing or e.is_empty:
                continue
            v = e.core_mesh()[0]
            lo, hi = v.min(axis=0), v.max(axis=0)
            margin = float(np.clip(cfg.observed_grid_margin * float((hi - lo).max()),
                                   cfg.observed_grid_min_margin_m, max(cfg.observed_grid_max_margin_m,
                                                                       cfg.observed_grid_min_margin_m)))
            margin = max(margin, 1e-3)
            space = self.free_space.observed_space(lo - margin, hi + margin, cfg.observed_grid_cells)
            if space is not None:
                a, b = np.searchsorted(surface[:, 0], [space.origin[0], space.upper[0]])
                space = space.with_surface(surface[a:b][owner[a:b] != e.id])
            e.observed_space = space

    def _overruled(self, e: Entity, areas: dict[int, float]) -> bool:
        """A thing entity that owns less of the map than `extraction.min_observed_share` of the surface one
        frame showed of its instance: the map's votes gave what its frames saw to other entities (a wrong
        class the noise put on part of an object in a frame or two, the other frames outvoting it there),
        and what is left of it is a shred along the border, no object."""
        share = self.config.extraction.min_observed_share
        if share <= 0 or not e.is_thing:
            return False
        return areas.get(e.id, 0.0) < share * self.counts.instance_area.get(e.id, 0.0)

    def _attach_meshes(self, ents: list[Entity], entity_of_label: np.ndarray,
                       unknown: Entity | None = None, fragment_of_label: np.ndarray | None = None,
                       fragment_class: np.ndarray | None = None) -> dict[int, float]:
        """Give each entity its mesh (and `unknown` the unclaimed surface); returns each entity's mesh
        area (m^2, on the TSDF's mesh, before any fine surface replaces a small thing's)."""
        v, f, vlab = self.tsdf.extract_mesh()
        if len(f) == 0:
            return {}
        v, f, vlab = canonical_mesh_order(v, f, vlab)
        lut = self.counts.canonical_lut(len(entity_of_label))
        canon = lut[np.clip(vlab, 0, len(lut) - 1)]
        inside = canon < len(entity_of_label)
        clipped = np.clip(canon, 0, len(entity_of_label) - 1)
        ent_v = np.where(inside, entity_of_label[clipped], 0)
        before = ent_v
        if fragment_of_label is not None and fragment_class is not None and len(fragment_class):
            frag_v = np.where(inside, fragment_of_label[clipped], 0)
            ent_v = self._merge_fragments(v, ent_v, frag_v, fragment_class, {e.id: e.class_id for e in ents})
        share = self.config.extraction.merge_touching_share
        if share > 0:
            ent_v = self._merge_touching(v, ent_v, {e.id: e.class_id for e in ents if e.is_thing}, share)
        if ent_v is not before:
            self._revise_merged(ents, ent_v, before, canon)
        voted = ent_v > 0
        ent_v = self._fill_unclaimed(v, ent_v)
        # the surface no label frame measured (the truncation band closing a thing seen from one side) stays
        # the entity's, but as fringe: model fitting reads the core (`Entity.core_mesh`), panoptic quality all
        unmeasured = self._unmeasured(v, ent_v, {e.id for e in ents if e.is_thing and self._carved_class(e.class_id)})
        core = voted if unmeasured is None else voted & ~unmeasured
        ent_v = self._drop_detached(v, ent_v, {e.id for e in ents if e.is_thing})
        ent_f = ent_v[f]
        owner = _face_owner(ent_f, self.config.extraction.face_majority)
        same = owner > 0
        if unknown is not None and np.any(~same):
            used, inv = np.unique(f[~same].ravel(), return_inverse=True)
            unknown.vertices, unknown.faces, unknown.num_voxels = v[used], inv.reshape(-1, 3), len(used)
        f, eid = f[same], owner[same]
        areas = _face_area(v, f, eid)
        order = np.argsort(eid, kind="stable")
        f, eid = f[order], eid[order]
        starts = np.searchsorted(eid, [e.id for e in ents], side="left")
        ends = np.searchsorted(eid, [e.id for e in ents], side="right")
        for e, a, b in zip(ents, starts, ends, strict=True):
            if b <= a:
                continue
            # voted, measured vertices first, the fill's fringe and the unmeasured after them (Entity.core_vertices)
            e.num_voxels = _set_core_first(e, v, f[a:b], core)
        if self.fine is not None:
            self._attach_fine_surfaces([e for e in ents if e.is_thing and self._small_class(e.class_id)],
                                       v, ent_v, voted, canon, lut)
        return areas

    def _attach_fine_surfaces(self, ents: list[Entity], v: np.ndarray, ent_v: np.ndarray,
                              voted: np.ndarray, canon: np.ndarray, lut: np.ndarray) -> None:
        """Small things take the fine TSDF's surface (`panoptic_mapping.fine_surface`): a fine vertex with
        a label belongs to the entity most of that label's coarse surface went to; with `fine_surface.fill`
        the others go to the entity of their nearest coarse vertex (as its fringe:
        `Entity.core_vertices`), else they are left out; an entity whose
        fine surface comes near less than `min_coverage` of its voted coarse vertices (seen in too few
        labelled frames) keeps the coarse one, the others keep it where the fine one has nothing
        (`_join_fine_surface`). Fine surface in a piece beside the thing (`extraction.detached_gap_m`, judged
        with its coarse surface) is left out, as its coarse surface there was."""
        if not ents or self.fine is None:
            return
        cfg = self.config.fine_surface
        fv, ff, fl = self.fine.extract_mesh()
        if len(ff) == 0:
            return
        # Open3D's order follows its hash map, which differs after a reload (as for the coarse mesh)
        fv, ff, fl = canonical_mesh_order(fv, ff, fl)
        # a labelled fine vertex goes where its label's coarse surface went (merges included) ...
        label_entity = _majority_entity(canon[voted], ent_v[voted])
        flab = lut[np.clip(fl, 0, len(lut) - 1)]
        labelled = (flab > 0) & (flab < len(label_entity))
        owner = np.zeros(len(fv), np.int64)
        owner[labelled] = label_entity[flab[labelled]]
        core = owner > 0
        # ... the others, as the fringe fill does (`extraction.fill_radius_m` > 0), to the entity of their
        # nearest coarse vertex (not voted: the fringe), when `fine_surface.fill` says so
        radius = cfg.assign_radius_voxels * self.config.tsdf.voxel_size_m
        if cfg.fill and self.config.extraction.fill_radius_m > 0:
            rest = np.flatnonzero(owner == 0)
            nearest = assign_fine_vertices(fv[rest], v, radius)
            owner[rest] = np.where(nearest >= 0, ent_v[np.maximum(nearest, 0)], 0)
        fit_core = core
        if self.free_space is not None and self.config.free_space.enabled and len(self.free_space):
            # unmeasured: fringe, as on the coarse mesh, within the fine surface's tolerance (`fine_tolerance_m`),
            # and measured by far fewer views than the rest of its thing (`fine_min_seen_share`)
            owned = np.flatnonzero(core & np.isin(owner, [e.id for e in ents if self._carved_class(e.class_id)]))
            fit_core = core.copy()
            free = self.config.free_space
            fit_core[owned[self.free_space.carved(fv[owned], free.fine_tolerance_m, owner[owned],
                                                  free.fine_min_seen_share)]] = False
        gap = self.config.extraction.detached_gap_m
        of = owner[ff]
        same = (of[:, 0] == of[:, 1]) & (of[:, 1] == of[:, 2]) & (of[:, 0] > 0)
        ff, fid = ff[same], of[same, 0]
        for e in ents:
            faces = ff[fid == e.id]
            mine = voted & (ent_v == e.id)
            if len(faces) == 0 or not mine.any():
                continue
            used, inv = np.unique(faces.ravel(), return_inverse=True)
            if gap > 0:  # a mask that spilt onto something beside the thing labelled fine surface there too
                drop = detached_pieces(np.concatenate([fv[used], e.vertices]), gap)[:len(used)]
                if drop.any():
                    faces = faces[~drop[inv.reshape(-1, 3)].any(axis=1)]
                    if len(faces) == 0:
                        continue
                    used, inv = np.unique(faces.ravel(), return_inverse=True)
            # judged on voted vertices alone, so the fringe fill's setting does not decide it
            if fine_coverage(v[mine], fv[used[core[used]]], radius) < cfg.min_coverage:
                continue
            _join_fine_surface(e, fv[used], inv.reshape(-1, 3), core[used], radius, fit_core[used])

    def _revise_merged(self, ents: list[Entity], ent_v: np.ndarray, before: np.ndarray, canon: np.ndarray) -> None:
        """An entity that took in surface of a fragment or a split part carries the newest change of that
        surface in its revision too: a later change of the part alone must reach the consumers that
        re-process an entity only when its revision moves (stage 4 re-matches by revision)."""
        moved = (ent_v != before) & (ent_v > 0)
        if not np.any(moved):
            return
        updates = self.counts.last_update
        labels = np.unique(canon[moved])
        revision = np.zeros(len(labels), np.int64)
        for i, label in enumerate(labels.tolist()):  # distinct labels of the moved surface: a handful
            revision[i] = updates.get(int(label), 0)
        per_vertex = revision[np.searchsorted(labels, canon[moved])]
        newest: dict[int, int] = {}
        for eid, rev in zip(*np.unique(np.stack([ent_v[moved], per_vertex], axis=1), axis=0).T, strict=True):
            newest[int(eid)] = max(newest.get(int(eid), 0), int(rev))
        for e in ents:
            if newest.get(e.id, 0) > e.revision:
                e.revision = newest[e.id]

    def _merge_fragments(self, v: np.ndarray, ent_v: np.ndarray, frag_v: np.ndarray, fragment_class: np.ndarray,
                         class_of_entity: dict[int, int]) -> np.ndarray:
        """Fragments (thing instances below `min_instance_frames`, numbered from 1 in `frag_v`) that touch
        an entity of their own class join it: the entity with the most fragment vertices within 1.5
        voxels of its own. The rest stay unclaimed (the fill, then `unknown`)."""
        fv = np.flatnonzero(frag_v > 0)
        claimed = np.flatnonzero(ent_v > 0)
        if fv.size == 0 or claimed.size == 0:
            return ent_v
        from scipy.spatial import cKDTree

        touch = 1.5 * self.config.tsdf.voxel_size_m
        dist, idx = cKDTree(v[claimed]).query(v[fv], k=1, distance_upper_bound=touch)
        ok = np.isfinite(dist)
        frag, neighbour = frag_v[fv[ok]], ent_v[claimed[idx[ok]]]
        eids = np.array(sorted(class_of_entity), np.int64)
        classes = np.array([class_of_entity[e] for e in eids.tolist()], np.int64)
        neighbour_class = classes[np.searchsorted(eids, neighbour)] if eids.size else np.zeros(0, np.int64)
        same = neighbour_class == fragment_class[frag - 1]
        if not np.any(same):
            return ent_v
        pairs, contacts = np.unique(np.stack([frag[same], neighbour[same]], axis=1), axis=0, return_counts=True)
        # per fragment, the neighbour with the most contacts (ties: the lower entity id, deterministic)
        order = np.lexsort((pairs[:, 1], -contacts, pairs[:, 0]))
        pairs = pairs[order]
        first = np.r_[True, pairs[1:, 0] != pairs[:-1, 0]]
        target = np.zeros(len(fragment_class) + 1, np.int64)
        target[pairs[first, 0]] = pairs[first, 1]
        out = ent_v.copy()
        joins = target[frag_v[fv]]
        out[fv[joins > 0]] = joins[joins > 0]
        return out

    def _merge_touching(self, v: np.ndarray, ent_v: np.ndarray, thing_class: dict[int, int],
                        min_share: float) -> np.ndarray:
        """A thing entity with at least `min_share` of its vertices within 1.5 voxels of a larger entity of
        its own class joins it: one object whose instance tracking split (a table's legs apart from its
        top, a chair in two halves). Two separate objects of one class touch along a small share of their
        surface (side by side cabinets: < 1 %), so they stay apart."""
        eids = np.array(sorted(thing_class), np.int64)
        if eids.size < 2:
            return ent_v
        from scipy.spatial import cKDTree

        idx = np.flatnonzero(np.isin(ent_v, eids))
        owner = ent_v[idx]
        sizes = dict(zip(*np.unique(owner, return_counts=True), strict=True))
        touch = 1.5 * self.config.tsdf.voxel_size_m
        _d, nb = cKDTree(v[idx]).query(v[idx], k=8, distance_upper_bound=touch)
        valid = nb < len(idx)
        rows = np.repeat(np.arange(len(idx)), nb.shape[1])[valid.ravel()]
        other = owner[nb[valid]]
        mine = owner[rows]
        classes = np.array([thing_class[e] for e in eids.tolist()], np.int64)
        keep = (other != mine) & (classes[np.searchsorted(eids, other)] == classes[np.searchsorted(eids, mine)])
        if not np.any(keep):
            return ent_v
        # distinct (vertex, neighbour entity) pairs, then vertices per (entity, neighbour entity)
        vert_pairs = np.unique(np.stack([rows[keep], other[keep]], axis=1), axis=0)
        pairs, counts = np.unique(np.stack([owner[vert_pairs[:, 0]], vert_pairs[:, 1]], axis=1), axis=0,
                                  return_counts=True)
        alias: dict[int, int] = {}

        def root(e: int) -> int:
            while e in alias:
                e = alias[e]
            return e

        for k in np.argsort(-counts / np.array([sizes[int(a)] for a in pairs[:, 0]]), kind="stable").tolist():
            small, big = int(pairs[k, 0]), int(pairs[k, 1])
            if sizes[small] > sizes[big] or counts[k] < min_share * sizes[small]:
                continue  # only the smaller one joins, and only when a real share of it touches
            rs, rb = root(small), root(big)
            if rs != rb:
                alias[rs] = rb
        if not alias:
            return ent_v
        lut = {e: root(e) for e in alias}
        out = ent_v.copy()
        for src, dst in lut.items():
            out[ent_v == src] = dst
        return out

    def _unmeasured(self, v: np.ndarray, ent_v: np.ndarray, things: set[int]) -> np.ndarray | None:
        """Which vertices of the entities `things` the label frames looked through or measured too rarely
        (`panoptic_mapping.free_space`): the truncation band behind a face seen from one side is unknown
        space, not the object's surface. None: none (or the test is off)."""
        if self.free_space is None or not self.config.free_space.enabled or not things or not len(self.free_space):
            return None
        idx = np.flatnonzero(np.isin(ent_v, np.fromiter(things, np.int64)))
        hit = self.free_space.carved(v[idx])
        if not hit.any():
            return None
        out = np.zeros(len(v), bool)
        out[idx[hit]] = True
        return out

    def _drop_detached(self, v: np.ndarray, ent_v: np.ndarray, things: set[int]) -> np.ndarray:
        """Pieces of a thing's surface beside its largest piece leave it (`extraction.detached_gap_m`)."""
        gap = self.config.extraction.detached_gap_m
        if gap <= 0 or not things:
            return ent_v
        out = ent_v
        order = np.argsort(ent_v, kind="stable")
        ids = ent_v[order]
        for eid in sorted(things):  # one KD-tree per thing entity: a few dozen per map
            idx = order[np.searchsorted(ids, eid, "left"):np.searchsorted(ids, eid, "right")]
            drop = detached_pieces(v[idx], gap)
            if drop.any():
                out = out.copy() if out is ent_v else out
                out[idx[drop]] = 0
        return out

    def _fill_unclaimed(self, v: np.ndarray, ent_v: np.ndarray) -> np.ndarray:
        """Unclaimed vertices within `fill_radius_m` of a claimed one join its entity.

        Labels are voted from segment pixels only; the fringe along depth edges (silhouettes,
        sensor dropouts) is reconstructed but rarely voted, and would otherwise be cut off.
        """
        r = self.config.extraction.fill_radius_m
        free = ent_v == 0
        if r <= 0 or not np.any(free) or np.all(free):
            return ent_v
        from scipy.spatial import cKDTree

        claimed = np.flatnonzero(~free)
        dist, idx = cKDTree(v[claimed]).query(v[free], k=1, distance_upper_bound=r)
        ok = np.isfinite(dist)
        out = ent_v.copy()
        out[np.flatnonzero(free)[ok]] = ent_v[claimed[idx[ok]]]
        return out

    def full_mesh(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The whole map's mesh with canonical vertex labels."""
        v, f, vlab = self.tsdf.extract_mesh()
        lut = self.counts.canonical_lut()
        return v, f, lut[np.clip(vlab, 0, len(lut) - 1)]

    # ------------------------------------------------------------------ persistence (no pickle)
    def snapshot(self) -> MapSnapshot:
        """A copy of the map's state (arrays + metadata), cheap next to writing it: take it under the
        lock that guards the mapper, write it (`MapSnapshot.write`, the costly part) outside."""
        arrays = {f"tsdf_{k}": v for k, v in self.tsdf.state().items()}
        if self.fine is not None:
            arrays.update({f"fine_{k}": v for k, v in self.fine.state().items()})
        if self.free_space is not None:
            arrays.update({f"free_{k}": v for k, v in self.free_space.state().items()})
        arrays.update({f"counts_{k}": v for k, v in self.counts.to_arrays().items()})
        mv = np.array([(a, b, n) for (a, b), n in self.merge_votes.items()], np.int64).reshape(-1, 3)
        arrays["merge_votes"] = mv
        if self._last_key_pose is not None:
            arrays["last_key_pose"] = np.asarray(self._last_key_pose, np.float64).copy()
        meta = {"format_version": MAP_FORMAT_VERSION, "config": asdict(self.config),
                "frames_integrated": self.frames_integrated, "keyframes": self.keyframes,
                "last_key_time_ns": self._last_key_time,
                "classes": {str(k): asdict(v) for k, v in self.classes.items()},
                # input map frame = these coordinates + origin_offset_m (non-zero for recentred maps)
                "origin_offset_m": [float(v) for v in self.origin_offset],
                # map point = alignment @ input point - origin_offset_m (alignment: input world -> z up)
                "gravity_alignment": self.alignment.tolist(), "gravity": dict(self.gravity)}
        return MapSnapshot(arrays, meta)

    def save(self, folder: str | Path) -> Path:
        """Write `map.npz` (voxels + counts, numpy arrays only) and `map.json` (config, metadata).

        Each file is replaced atomically, and map.json carries the checksum of the map.npz it goes
        with: an interrupted save leaves either the old pair, or a pair `load` refuses as mismatched.
        (Checkpoints, `panoptic_mapping.checkpoint`, write whole generations and never see that case.)
        """
        return self.snapshot().write(folder)

    @classmethod
    def load(cls, folder: str | Path) -> PanopticMapper:
        """The map saved in `folder`. Raises FileNotFoundError when there is none, CheckpointError
        (naming the file) when map.json or map.npz is damaged or the two do not belong together."""
        from recon_core.config import from_dict

        folder = Path(folder)
        meta_path, npz_path = folder / "map.json", folder / "map.npz"
        if not meta_path.is_file() or not npz_path.is_file():
            raise FileNotFoundError(f"{folder} holds no saved map (map.json + map.npz)")
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8"))
        except (ValueError, UnicodeDecodeError) as exc:
            raise CheckpointError(f"{meta_path}: damaged, not valid JSON ({exc})") from None
        if not isinstance(meta, dict):
            raise CheckpointError(f"{meta_path}: damaged, not a JSON object")
        if meta.get("format_version") != MAP_FORMAT_VERSION:
            raise CheckpointError(f"{meta_path}: unsupported map format {meta.get('format_version')!r}")
        try:
            config = from_dict(MapperConfig, meta["config"])
            classes = {int(k): ClassMeta(**v) for k, v in meta.get("classes", {}).items()}
        except (KeyError, TypeError, ValueError) as exc:
            raise CheckpointError(f"{meta_path}: damaged, bad config or classes ({exc})") from None
        data = npz_path.read_bytes()
        expected = meta.get("npz_sha256")
        if expected is not None and hashlib.sha256(data).hexdigest() != expected:
            raise CheckpointError(
                f"{npz_path} does not belong to {meta_path.name} (checksum mismatch, {len(data)} bytes, "
                f"expected {meta.get('npz_bytes', '?')}): truncated, or the pair was not written together")
        mapper = cls(config, classes)
        try:
            with np.load(io.BytesIO(data), allow_pickle=False) as npz:
                arrays = {k: npz[k] for k in npz.files}
            mapper.tsdf.load_state({k[5:]: v for k, v in arrays.items() if k.startswith("tsdf_")})
            if mapper.fine is not None and "fine_block_keys" in arrays:
                mapper.fine.load_state({k[5:]: v for k, v in arrays.items() if k.startswith("fine_")})
            if mapper.free_space is not None and "free_depth_mm" in arrays:
                mapper.free_space.load_state({k[5:]: v for k, v in arrays.items() if k.startswith("free_")})
            mapper.counts = PanopticCounts.from_arrays(
                {k[7:]: v for k, v in arrays.items() if k.startswith("counts_")})
            mapper.merge_votes = {(int(a), int(b)): int(n) for a, b, n in arrays["merge_votes"]}
            if "last_key_pose" in arrays:
                mapper._last_key_pose = np.asarray(arrays["last_key_pose"], np.float64).reshape(4, 4)
            mapper.frames_integrated = int(meta.get("frames_integrated", 0))
            mapper.keyframes = int(meta.get("keyframes", 0))
            key_time = meta.get("last_key_time_ns")
            mapper._last_key_time = int(key_time) if key_time is not None else None
            mapper.origin_offset = np.asarray(meta.get("origin_offset_m", [0.0, 0.0, 0.0]),
                                              dtype=np.float64).reshape(3)
            mapper.alignment = np.asarray(meta.get("gravity_alignment", np.eye(4).tolist()),
                                          dtype=np.float64).reshape(4, 4)
            mapper.gravity = dict(meta.get("gravity", {}))
        except MemoryError:
            raise
        except Exception as exc:  # zip, zlib, npy-header, shape and key errors: all mean a damaged file
            raise CheckpointError(f"{npz_path}: damaged ({type(exc).__name__}: {exc})") from None
        return mapper


#: zlib level of map.npz: 1 writes 3x faster than numpy's default (6) for 12 % more bytes (3719-block
#: map: 0.18 s / 5.2 MB against 0.53 s / 4.7 MB), which matters for periodic checkpoints.
NPZ_COMPRESSLEVEL = 1


def npz_bytes(arrays: dict[str, np.ndarray], compresslevel: int = NPZ_COMPRESSLEVEL) -> bytes:
    """An .npz file (as `np.load` reads it, no pickle) of `arrays`, deflated at `compresslevel`."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED, compresslevel=compresslevel) as zf:
        for name, value in arrays.items():
            with zf.open(f"{name}.npy", "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asanyarray(value), allow_pickle=False)
    return buf.getvalue()


@dataclass
class MapSnapshot:
    """The saved form of a map: named numpy arrays (map.npz) and JSON metadata (map.json)."""

    arrays: dict[str, np.ndarray]
    meta: dict

    def write(self, folder: str | Path) -> Path:
        """Write map.npz then map.json (each atomically; map.json names map.npz's checksum)."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        data = npz_bytes(self.arrays)
        meta = {**self.meta, "npz_sha256": hashlib.sha256(data).hexdigest(), "npz_bytes": len(data)}
        write_bytes_atomic(folder / "map.npz", data)
        write_text_atomic(folder / "map.json", json.dumps(meta, indent=1))
        return folder / "map.npz"


def _join_fine_surface(e: Entity, fine_v: np.ndarray, fine_f: np.ndarray, fine_core: np.ndarray,
                       radius: float, fit_core: np.ndarray | None = None) -> None:
    """Give `e` its fine surface and keep its coarse surface only where the fine one has nothing within
    `radius` (a part the labelled frames saw too rarely stays as the coarse map has it, so a partial fine
    surface never shrinks the object); voted vertices first (`Entity.core_vertices`), or the `fit_core`
    ones among them (the voted vertices the free-space test left in the core)."""
    from scipy.spatial import cKDTree

    cv, cf = np.asarray(e.vertices, np.float64), np.asarray(e.faces, np.int64)
    ccore = np.arange(len(cv)) < (e.core_vertices if 0 <= e.core_vertices <= len(cv) else len(cv))
    if len(cv) and fine_core.any():  # voted fine vertices only: the fill's setting does not decide it
        dist, _ = cKDTree(fine_v[fine_core]).query(cv, distance_upper_bound=radius)
        uncovered = ~np.isfinite(dist)
        cf = cf[uncovered[cf].all(axis=1)] if len(cf) else cf
    verts = np.concatenate([fine_v, cv])
    is_core = np.concatenate([fine_core if fit_core is None else fit_core, ccore])
    faces = np.concatenate([fine_f, cf + len(fine_v)])
    _set_core_first(e, verts, faces, is_core)


def _segment_area(seg_flat: np.ndarray, sampled: np.ndarray, k: np.ndarray, stride: int, n: int) -> np.ndarray:
    """Per segment id (`n` of them), the surface its pixels show in m^2, fronto-parallel (a pixel at depth z
    covers (z / fx) (z / fy); slanted surface is more): from the sampled pixels only (`seg_flat`, their
    camera-frame points `sampled`, every `stride`-th pixel both ways), so a few hundred microseconds."""
    z = sampled.reshape(-1, 3)[:, 2].astype(np.float64)
    w = z * z * (stride * stride / (float(k[0, 0]) * float(k[1, 1])))
    return np.bincount(seg_flat, weights=w, minlength=n)


def _face_area(v: np.ndarray, f: np.ndarray, owner: np.ndarray) -> dict[int, float]:
    """Mesh area (m^2) per owner id of the faces `f` (rows of vertex indices into `v`)."""
    if len(f) == 0:
        return {}
    a, b, c = (v[f[:, i]].astype(np.float64) for i in range(3))
    tri = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    ids, inv = np.unique(owner, return_inverse=True)
    return dict(zip(ids.tolist(), np.bincount(inv, weights=tri).tolist(), strict=True))


def _set_core_first(e: Entity, vertices: np.ndarray, faces: np.ndarray, is_core: np.ndarray) -> int:
    """Give `e` the vertices `faces` use (indices into `vertices`), the `is_core` ones first
    (`Entity.core_vertices`); returns how many vertices it got."""
    used, inv = np.unique(faces.ravel(), return_inverse=True)
    order = np.argsort(~is_core[used], kind="stable")
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    e.set_geometry(vertices[used[order]], rank[inv].reshape(-1, 3), int(is_core[used].sum()))
    return len(used)


def _face_owner(ent_f: np.ndarray, majority: bool) -> np.ndarray:
    """The entity each face (rows: its three vertices' entities) belongs to, 0 for none.

    `majority`: the entity of at least two of its vertices. Along every border between two entities
    the marching-cubes faces mix the voxel labels of both sides; giving those faces to neither strips a
    band about one voxel wide off every entity, which is little of a cabinet and most of a cup mapped at
    2 cm voxels (bench-clutter's cup: 42 vertices). False: only faces whose three vertices agree.
    """
    a, b, c = ent_f[:, 0], ent_f[:, 1], ent_f[:, 2]
    if not majority:
        return np.where((a == b) & (b == c), a, 0)
    return np.where((a == b) | (a == c), a, np.where(b == c, b, 0))


def _majority_entity(labels: np.ndarray, entities: np.ndarray) -> np.ndarray:
    """Per label (index), the entity most of its vertices belong to (0: none)."""
    keep = (labels > 0) & (entities > 0)
    labels, entities = labels[keep].astype(np.int64), entities[keep].astype(np.int64)
    if len(labels) == 0:
        return np.zeros(1, np.int64)
    pairs, counts = np.unique(np.stack([labels, entities], axis=1), axis=0, return_counts=True)
    order = np.lexsort((-counts, pairs[:, 0]))  # by label, the most frequent entity first
    pairs = pairs[order]
    first = np.r_[True, pairs[1:, 0] != pairs[:-1, 0]]
    out = np.zeros(int(labels.max()) + 1, np.int64)
    out[pairs[first, 0]] = pairs[first, 1]
    return out


def detached_pieces(points: np.ndarray, gap: float) -> np.ndarray:
    """Boolean per point: in a piece (points linked within `gap`) other than the largest whose points lie
    mostly outside the largest piece's footprint from above (its x-y bounds grown by `gap`) and which,
    with every such piece, holds less than half of the points.

    Pieces are linked on cells of a quarter of `gap` (centres within `gap`, so points closer than 0.57
    `gap` are always linked and points farther than 1.43 `gap` never): a surface's points have hundreds
    of neighbours within 20 cm, its cells a few dozen."""
    if len(points) < 2:
        return np.zeros(len(points), bool)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    cell = gap / 4.0
    cells, of_point = np.unique(np.floor(points / cell).astype(np.int64), axis=0, return_inverse=True)
    of_point = of_point.reshape(-1)
    pairs = cKDTree((cells + 0.5) * cell).query_pairs(gap, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(len(cells),) * 2)
    n, cell_piece = connected_components(graph, directed=False)
    piece = cell_piece[of_point]
    if n == 1:
        return np.zeros(len(points), bool)
    main = int(np.argmax(np.bincount(piece, minlength=n)))
    lo = points[piece == main, :2].min(axis=0) - gap
    hi = points[piece == main, :2].max(axis=0) + gap
    inside = np.all((points[:, :2] >= lo) & (points[:, :2] <= hi), axis=1)
    share_inside = np.bincount(piece, weights=inside, minlength=n) / np.bincount(piece, minlength=n)
    beside = share_inside < 0.5
    beside[main] = False
    drop = beside[piece]
    return drop if drop.sum() * 2 < len(points) else np.zeros(len(points), bool)


def canonical_mesh_order(vertices: np.ndarray, faces: np.ndarray,
                         vertex_labels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The extracted mesh with its vertices sorted by (x, y, z) and its faces sorted (winding kept).

    Open3D's block hash map emits vertices in an order that varies from run to run and between
    processes, and the later stages (box fits, CAD alignment sampling) depend on that order: two runs
    on the same frames (`scene-recon run` twice, or `run` and the ROS graph) picked different CAD
    models. In this order the same surface always gives the same arrays.
    """
    order = np.lexsort((vertices[:, 2], vertices[:, 1], vertices[:, 0]))
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    f = rank[faces]
    shift = np.argmin(f, axis=1)  # rotate each face to start at its smallest index: same winding
    f = np.take_along_axis(f, (shift[:, None] + np.arange(3)[None, :]) % 3, axis=1)
    f = f[np.lexsort((f[:, 2], f[:, 1], f[:, 0]))]
    return vertices[order], f, vertex_labels[order]
