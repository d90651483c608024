"""A finer TSDF for small things (issue 22, item 3): the surface of books, cups, bottles and monitor
stands at a resolution their size needs, beside the room-scale labelled TSDF (Sec. 3.3).

At the map's 2 cm voxels an 11 mm book was mapped 26 mm thick, a cup lost its rim (10 cm high for
12.4 cm), and a monitor's 1 cm base plate vanished into the desk, so its box was 9 cm deep for 23 cm:
the CAD fit then chose models 20-70 % off in size. Multi-resolution submap mappers (ethz-asl
panoptic_mapping keeps one resolution per submap, by class) solve this by giving small objects their
own finer volume; so does this module, in the simplest form that costs little:

* one more labelled voxel-block grid (`LabeledTSDF`) at ``voxel_size_m`` (5 mm by default since 2026-11-29,
  with `free_space`: at 1 cm books stayed 1.5-2x too thick; docs/STAGE2_MAPPING.md);
* it integrates, on the frames that carry labels, only the depth pixels of small things (the thing
  classes whose class-table ``max_size_m`` is at most ``max_class_size_m``), their silhouette grown by
  ``dilate_px`` pixels, and those pixels' map labels: cost follows what small things the camera sees,
  not the room;
* at extraction the fine mesh replaces the coarse surface of those entities: a fine vertex belongs to
  the entity its own label went to (so a monitor's 1 cm base plate, merged into the desk at 2 cm, is
  the monitor's again), else to the entity of the nearest coarse vertex (within
  ``assign_radius_voxels`` coarse voxels); an entity takes the fine surface only where it comes near
  most of what the coarse map had of it.
"""

from __future__ import annotations

import cv2
import numpy as np

from panoptic_mapping.config import FineSurfaceConfig, TSDFConfig
from panoptic_mapping.tsdf_map import LabeledTSDF


class FineSurfaceMap:
    """The finer labelled TSDF of small things (module doc): a `LabeledTSDF` at the fine resolution that
    only the pixels of small things (and the ring around them) reach."""

    def __init__(self, cfg: FineSurfaceConfig, room: TSDFConfig, initial_block_count: int = 4000):
        self.cfg = cfg
        self.tsdf = LabeledTSDF(TSDFConfig(
            voxel_size_m=cfg.voxel_size_m, truncation_voxels=cfg.truncation_voxels,
            block_resolution=cfg.block_resolution, initial_block_count=initial_block_count,
            min_depth_m=room.min_depth_m, max_depth_m=room.max_depth_m, max_weight=room.max_weight,
            mesh_weight_threshold=room.mesh_weight_threshold))

    def small_pixels(self, labels: np.ndarray, small_label: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(pixels fused, pixels whose label votes): the pixels of small things (``small_label[label]``
        true) grown by ``dilate_px`` are fused; their own labels vote only ``label_erode_px`` pixels
        inside their silhouette (0, the default: all of them; see the config field), the ring's other
        labels vote as they are."""
        lab = np.asarray(labels)
        inside = (lab >= 0) & (lab < len(small_label))
        base = np.zeros(lab.shape, np.uint8)
        base[inside] = small_label[lab[inside]]
        if not base.any():
            return base.astype(bool), base.astype(bool)
        grown, interior = base, base
        if self.cfg.dilate_px > 0:
            size = 2 * int(self.cfg.dilate_px) + 1
            grown = np.asarray(cv2.dilate(base, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))))
        if self.cfg.label_erode_px > 0:
            size = 2 * int(self.cfg.label_erode_px) + 1
            interior = np.asarray(cv2.erode(base, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))))
        fused = grown.astype(bool)
        vote = fused & (lab > 0) & ((base == 0) | (interior > 0))
        return fused, vote

    def integrate(self, depth: np.ndarray, mask: np.ndarray, intrinsic: np.ndarray, pose: np.ndarray,
                  points: np.ndarray, labels: np.ndarray, lut: np.ndarray, vote: np.ndarray | None = None) -> int:
        """Fuse the ``mask`` pixels of ``depth`` (metres, in range, 0 = invalid) seen from camera-to-map
        ``pose``, and the labels of the ``vote`` pixels (default: the mask's labelled ones): ``points``
        (H, W, 3) in the camera frame, ``labels`` (H, W) map labels (0: none), ``lut`` the canonical label
        table. Returns the blocks touched (0: nothing small)."""
        if not mask.any():
            return 0
        vote = mask & (labels > 0) if vote is None else vote
        if vote.any():
            cam = np.ascontiguousarray(points[vote], np.float32).reshape(-1, 1, 3)
            world = cv2.transform(cam, np.asarray(pose, np.float64)[:3, :].astype(np.float32)).reshape(-1, 3)
            self.tsdf.integrate_labels(world, labels[vote], lut)
        masked = np.where(mask, np.asarray(depth, np.float32), np.float32(0))
        return self.tsdf.integrate_depth(masked, intrinsic, pose, in_range=True)

    def extract_mesh(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(vertices, faces, vertex labels) of the fine surface; empty when nothing is confident."""
        return self.tsdf.extract_mesh()

    @property
    def num_blocks(self) -> int:
        return self.tsdf.num_blocks

    def memory_bytes(self) -> int:
        return self.tsdf.memory_bytes()

    def state(self) -> dict[str, np.ndarray]:
        return self.tsdf.state()

    def load_state(self, state: dict[str, np.ndarray]) -> None:
        self.tsdf.load_state(state)


def assign_fine_vertices(fine_v: np.ndarray, coarse_v: np.ndarray, radius: float) -> np.ndarray:
    """Index of the nearest coarse vertex of each fine vertex within ``radius`` (-1: none)."""
    from scipy.spatial import cKDTree

    out = np.full(len(fine_v), -1, np.int64)
    if len(fine_v) == 0 or len(coarse_v) == 0:
        return out
    lo, hi = fine_v.min(axis=0) - radius, fine_v.max(axis=0) + radius
    near = np.flatnonzero(np.all((coarse_v >= lo) & (coarse_v <= hi), axis=1))
    if len(near) == 0:
        return out
    dist, j = cKDTree(coarse_v[near]).query(fine_v, distance_upper_bound=radius)
    hit = np.isfinite(dist)
    out[hit] = near[j[hit]]
    return out


def fine_coverage(coarse_v: np.ndarray, fine_v: np.ndarray, radius: float) -> float:
    """Share of an entity's coarse vertices with one of its fine vertices within ``radius``: how much of
    what the coarse map has of it the fine surface reproduces (a thin book's coarse surface lies within
    a coarse voxel of its fine one, so the blur itself does not lower it)."""
    from scipy.spatial import cKDTree

    if len(coarse_v) == 0 or len(fine_v) == 0:
        return 0.0
    dist, _ = cKDTree(fine_v).query(coarse_v, distance_upper_bound=radius)
    return float(np.isfinite(dist).mean())


__all__ = ["FineSurfaceMap", "assign_fine_vertices", "fine_coverage"]
