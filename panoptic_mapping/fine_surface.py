"""A finer TSDF for small things (issue 22, item 3): the surface of books, cups, bottles and monitor
stands at a resolution their size needs, beside the room-scale labelled TSDF (Sec. 3.3).

At the map's 2 cm voxels an 11 mm book was mapped 26 mm thick, a cup lost its rim (10 cm high for
12.4 cm), and a monitor's 1 cm base plate vanished into the desk, so its box was 9 cm deep for 23 cm:
the CAD fit then chose models 20-70 % off in size. Multi-resolution submap mappers (ethz-asl
panoptic_mapping keeps one resolution per submap, by class) solve this by giving small objects their
own finer volume; so does this module, in the simplest form that costs little:

* one more Open3D voxel-block grid (geometry only: tsdf and weight), ``voxel_size_m`` (1 cm);
* it integrates, on the frames that carry labels, only the depth pixels of small things (the thing
  classes whose class-table ``max_size_m`` is at most ``max_class_size_m``), their silhouette grown by
  ``dilate_px`` pixels: cost follows what small things the camera sees, not the room;
* at extraction the fine mesh replaces the coarse surface of those entities: each fine vertex belongs
  to the entity of the nearest coarse vertex (within ``assign_radius_voxels`` coarse voxels), and an
  entity takes the fine surface only where it covers most of what the coarse map had of it.
"""

from __future__ import annotations

import cv2
import numpy as np
import open3d as o3d
import open3d.core as o3c

from panoptic_mapping.config import FineSurfaceConfig

_CPU = o3c.Device("CPU:0")
_EMPTY = (np.zeros((0, 3)), np.zeros((0, 3), np.int64))


class FineSurfaceMap:
    """The finer geometry-only TSDF of small things (module doc)."""

    def __init__(self, cfg: FineSurfaceConfig, max_depth_m: float, initial_block_count: int = 4000):
        self.cfg = cfg
        self.max_depth_m = float(max_depth_m)
        self._blocks = int(initial_block_count)
        self.vbg = self._grid(self._blocks)

    def _grid(self, block_count: int) -> o3d.t.geometry.VoxelBlockGrid:
        return o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight"), attr_dtypes=(o3c.float32, o3c.float32),
            attr_channels=((1), (1)),  # type: ignore[arg-type]  # ints are accepted
            voxel_size=float(self.cfg.voxel_size_m), block_resolution=int(self.cfg.block_resolution),
            block_count=block_count, device=_CPU)

    def small_pixels(self, labels: np.ndarray, small_label: np.ndarray) -> np.ndarray:
        """Mask of the pixels of small things (``small_label[label]`` true), grown by ``dilate_px``."""
        lab = np.asarray(labels)
        inside = (lab >= 0) & (lab < len(small_label))
        mask = np.zeros(lab.shape, np.uint8)
        mask[inside] = small_label[lab[inside]]
        if self.cfg.dilate_px > 0 and mask.any():
            size = 2 * int(self.cfg.dilate_px) + 1
            mask = cv2.dilate(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size)))
        return mask.astype(bool)

    def integrate(self, depth: np.ndarray, mask: np.ndarray, intrinsic: np.ndarray, pose: np.ndarray) -> int:
        """Fuse the ``mask`` pixels of ``depth`` (metres, in range, 0 = invalid) seen from camera-to-map
        ``pose``; returns the number of blocks touched (0: nothing small in view)."""
        if not mask.any():
            return 0
        masked = np.where(mask, np.asarray(depth, np.float32), np.float32(0))
        if not np.any(masked > 0):
            return 0
        dt = o3d.t.geometry.Image(o3c.Tensor.from_numpy(np.ascontiguousarray(masked, np.float32)))
        k = o3c.Tensor(np.asarray(intrinsic, np.float64))
        e = o3c.Tensor(np.linalg.inv(np.asarray(pose, np.float64)))
        trunc = float(self.cfg.truncation_voxels)
        try:
            blocks = self.vbg.compute_unique_block_coordinates(dt, k, e, 1.0, self.max_depth_m, trunc)
        except RuntimeError as exc:  # Open3D raises "No block is touched" instead of returning none
            if "No block is touched" in str(exc):
                return 0
            raise
        if blocks.shape[0] == 0:
            return 0
        self.vbg.integrate(blocks, dt, k, e, 1.0, self.max_depth_m, trunc)
        return int(blocks.shape[0])

    def extract_mesh(self, weight_threshold: float) -> tuple[np.ndarray, np.ndarray]:
        """(vertices, faces) of the fine surface (float64, int64); empty when nothing is confident."""
        if self.vbg.hashmap().size() == 0:
            return _EMPTY
        try:
            mesh = self.vbg.extract_triangle_mesh(weight_threshold=float(weight_threshold))
        except RuntimeError:  # no confident surface: Open3D raises instead of returning an empty mesh
            return _EMPTY
        if mesh.vertex.positions.shape[0] == 0:
            return _EMPTY
        return mesh.vertex.positions.numpy().astype(np.float64), mesh.triangle.indices.numpy().astype(np.int64)

    @property
    def num_blocks(self) -> int:
        return int(self.vbg.hashmap().size())

    def memory_bytes(self) -> int:
        return self.num_blocks * int(self.cfg.block_resolution) ** 3 * 8  # tsdf + weight, float32

    # ------------------------------------------------------------------ persistence (no pickle)
    def state(self) -> dict[str, np.ndarray]:
        hm = self.vbg.hashmap()
        active = hm.active_buf_indices().numpy().astype(np.int64)
        out = {"block_keys": hm.key_tensor().numpy()[active].astype(np.int32)}
        for name in ("tsdf", "weight"):
            out[name] = self.vbg.attribute(name).numpy()[active].copy()
        return out

    def load_state(self, state: dict[str, np.ndarray]) -> None:
        keys = np.asarray(state["block_keys"]).astype(np.int32).reshape(-1, 3)
        self.vbg = self._grid(max(self._blocks, 2 * len(keys)))
        if len(keys) == 0:
            return
        hm = self.vbg.hashmap()
        hm.activate(o3c.Tensor(keys))
        buf, _ = hm.find(o3c.Tensor(keys))
        buf = buf.numpy().astype(np.int64)
        for name in ("tsdf", "weight"):
            self.vbg.attribute(name).numpy()[buf] = state[name]


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

    if len(coarse_v) == 0:
        return 0.0
    if len(fine_v) == 0:
        return 0.0
    dist, _ = cKDTree(fine_v).query(coarse_v, distance_upper_bound=radius)
    return float(np.isfinite(dist).mean())


__all__ = ["FineSurfaceMap", "assign_fine_vertices", "fine_coverage"]
