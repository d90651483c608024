"""TSDF volume with a per-voxel global segment label (Sec. 3.3), on Open3D's hashed voxel blocks.

Geometry is integrated by Open3D's native `VoxelBlockGrid.integrate` (fast C++); labels are
integrated from the pixels: each labelled pixel votes for the voxel at its surface point, with
a Voxblox++-style confidence count per voxel (agreeing votes raise it, disagreeing ones lower it;
at zero the voxel takes the new label). Voting at the observed surface only is what matters: the
mesh's vertices lie on the zero crossing, next to those voxels. Work per frame scales with the
pixels and blocks the frame touches, never with the map size.
"""

from __future__ import annotations

import cv2
import numpy as np
import open3d as o3d
import open3d.core as o3c

from panoptic_mapping.config import TSDFConfig

#: What Open3D's extract_triangle_mesh raises when no voxel is confident enough for a surface.
_EMPTY_MESH_ERROR = "has shape {0}"


_CPU = o3c.Device("CPU:0")
_BIAS = 1 << 20  # block coordinates are packed into 21 bits each (+-2^20 blocks: far beyond any room)
_MASK21 = (1 << 21) - 1


class LabeledTSDF:
    def __init__(self, cfg: TSDFConfig):
        self.cfg = cfg
        self.vs = float(cfg.voxel_size_m)
        self.res = int(cfg.block_resolution)
        if self.res & (self.res - 1):
            raise ValueError(f"block_resolution must be a power of two, got {self.res}")
        self._shift = self.res.bit_length() - 1
        self.vbg = o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "label", "conf"),
            attr_dtypes=(o3c.float32, o3c.float32, o3c.int32, o3c.int32),
            attr_channels=((1), (1), (1), (1)),  # type: ignore[arg-type]  # ints are accepted
            voxel_size=self.vs, block_resolution=self.res, block_count=int(cfg.initial_block_count), device=_CPU,
        )
        self.label_conf_max = 64

    # ------------------------------------------------------------------ geometry
    def in_range(self, depth: np.ndarray) -> np.ndarray:
        """`depth` with readings outside [min_depth_m, max_depth_m] set to 0 (float32; NaN stays NaN).

        Two SIMD threshold passes (OpenCV), ~15x faster than the numpy mask + where it replaces.
        """
        depth = np.asarray(depth, np.float32)
        lo, hi = float(self.cfg.min_depth_m), float(self.cfg.max_depth_m)
        if depth.ndim != 2 or depth.size == 0:
            bad = depth > hi if hi > 0 else np.zeros(depth.shape, bool)
            if lo > 0:
                bad |= depth < lo
            return np.where(bad, np.float32(0), depth) if bad.any() else depth
        if hi > 0:  # d > hi -> 0
            depth = cv2.threshold(depth, float(np.float32(hi)), 0.0, cv2.THRESH_TOZERO_INV)[1]
        if lo > 0:  # d < lo -> 0: keep d > (the float32 just below lo), i.e. d >= lo as `depth < lo` tests it
            below = float(np.nextafter(np.float32(lo), np.float32(-np.inf)))
            depth = cv2.threshold(depth, below, 0.0, cv2.THRESH_TOZERO)[1]
        return depth

    def integrate_depth(self, depth: np.ndarray, intrinsic: np.ndarray, pose: np.ndarray,
                        in_range: bool = False) -> int:
        """Fuse one depth image (metres, 0 = invalid) seen from camera-to-map `pose`.

        Only readings within [min_depth_m, max_depth_m] allocate and update blocks (`in_range=True`:
        the caller has already applied `in_range`). Returns the number of blocks touched (0 when no
        reading is in range: nothing is integrated, nothing raised). Per-frame cost: the frame's
        pixels and the blocks it touches (Open3D's native integration), never the map size.
        """
        depth = np.ascontiguousarray(depth if in_range else self.in_range(depth), np.float32)
        if not np.any(depth > 0):
            return 0
        # zero copy: Open3D reads the numpy buffer, which outlives these calls
        dt = o3d.t.geometry.Image(o3c.Tensor.from_numpy(depth))
        k = o3c.Tensor(np.asarray(intrinsic, np.float64))
        e = o3c.Tensor(np.linalg.inv(np.asarray(pose, np.float64)))
        depth_max, trunc = float(self.cfg.max_depth_m), float(self.cfg.truncation_voxels)
        try:
            blocks = self.vbg.compute_unique_block_coordinates(dt, k, e, 1.0, depth_max, trunc)
        except RuntimeError as exc:  # Open3D raises "No block is touched" instead of returning none
            if "No block is touched" in str(exc):
                return 0
            raise
        if blocks.shape[0] == 0:
            return 0
        self.vbg.integrate(blocks, dt, k, e, 1.0, depth_max, trunc)
        return int(blocks.shape[0])

    # ------------------------------------------------------------------ voxel lookup
    def _flat_indices(self, points: np.ndarray, activate: bool = False) -> np.ndarray:
        """Flattened voxel-attribute index of the voxel nearest each point; -1 where no block exists."""
        if len(points) == 0:
            return np.zeros(0, np.int64)
        vox = np.round(points * (1.0 / self.vs)).astype(np.int64)
        blk = vox >> self._shift  # floor division by the (power of two) block resolution
        off = vox & (self.res - 1)
        # unique on one packed int64 key per block (np.unique on rows is ~10x slower)
        packed = ((blk[:, 0] + _BIAS) << 42) | ((blk[:, 1] + _BIAS) << 21) | (blk[:, 2] + _BIAS)
        upacked, inv = np.unique(packed, return_inverse=True)
        ublk = np.stack([(upacked >> 42) - _BIAS, ((upacked >> 21) & _MASK21) - _BIAS, (upacked & _MASK21) - _BIAS],
                        axis=1)
        keys = o3c.Tensor(ublk.astype(np.int32))
        hashmap = self.vbg.hashmap()
        if activate:
            hashmap.activate(keys)
        buf, found = hashmap.find(keys)
        buf = buf.numpy().astype(np.int64)
        found = found.numpy()
        buf[~found] = -1
        b = buf[inv.reshape(-1)]
        flat = b * self.res**3 + off[:, 2] * self.res**2 + off[:, 1] * self.res + off[:, 0]
        return np.where(b >= 0, flat, -1)

    def labels_around(self, points: np.ndarray) -> np.ndarray:
        """Most frequent non-zero label among the 8 voxels around each point (0 if none).

        Mesh vertices lie on the zero crossing *between* voxels; the nearest voxel alone is often
        one that was never voted (votes land where the noisy depth points fell).
        """
        if len(points) == 0:
            return np.zeros(0, np.int32)
        base = np.floor(points / self.vs)
        corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], np.float64)
        q = ((base[:, None, :] + corners[None]) * self.vs).reshape(-1, 3)
        lab = self.labels_at(q).reshape(len(points), 8).astype(np.int64)
        lab_sorted = np.sort(lab, axis=1)
        # run lengths of equal labels per row; pick the longest non-zero run
        best = np.zeros(len(points), np.int64)
        best_n = np.zeros(len(points), np.int64)
        run = np.ones(len(points), np.int64)
        for c in range(8):
            if c > 0:
                same = lab_sorted[:, c] == lab_sorted[:, c - 1]
                run = np.where(same, run + 1, 1)
            better = (lab_sorted[:, c] > 0) & (run > best_n)
            best = np.where(better, lab_sorted[:, c], best)
            best_n = np.where(better, run, best_n)
        return best.astype(np.int32)

    def labels_at(self, points: np.ndarray) -> np.ndarray:
        """Global segment label of the voxel nearest each point (0 where unknown)."""
        flat = self._flat_indices(points)
        out = np.zeros(len(points), np.int32)
        ok = flat >= 0
        if np.any(ok):
            out[ok] = self.vbg.attribute("label").numpy().reshape(-1)[flat[ok]]
        return out

    # ------------------------------------------------------------------ labels
    def integrate_labels(self, points: np.ndarray, labels: np.ndarray, lut: np.ndarray | None = None) -> np.ndarray:
        """Vote `labels` (> 0, canonical) into the voxels at the surface `points` (map frame).

        `lut` maps stored (possibly merged-away) labels to canonical ones. Returns the flattened
        voxel indices touched (for change tracking).
        """
        sel = labels > 0
        points, labels = points[sel], labels[sel].astype(np.int32)
        flat = self._flat_indices(points, activate=True)
        ok = flat >= 0
        flat, labels = flat[ok], labels[ok]
        if flat.size == 0:
            return flat
        # one vote per voxel and frame: the majority label among the pixels hitting it (ties: the
        # largest label). One sort of a packed (voxel, label) key, then per-voxel maxima by reduceat.
        span = int(labels.max()) + 1
        keys, pc = np.unique(flat * span + labels, return_counts=True)
        pf, pl = keys // span, keys % span
        vox_start = np.r_[True, pf[1:] != pf[:-1]]
        starts = np.flatnonzero(vox_start)
        group = np.cumsum(vox_start) - 1
        top = np.maximum.reduceat(pc, starts)
        best = np.maximum.reduceat(np.where(pc == top[group], np.arange(pc.size), -1), starts)
        vf, vl = pf[best], pl[best].astype(np.int32)
        lab = self.vbg.attribute("label").numpy().reshape(-1)
        conf = self.vbg.attribute("conf").numpy().reshape(-1)
        cur, c = lab[vf], conf[vf]
        same = (lut[cur] if lut is not None else cur) == vl
        c = np.where(same, np.minimum(c + 1, self.label_conf_max), c - 1)
        switch = c <= 0
        lab[vf] = np.where(switch, vl, cur)
        conf[vf] = np.where(switch, 1, c)
        return vf

    def relabel(self, lut: dict[int, int]) -> None:
        """Rename voxel labels (segment merging): every voxel labelled k becomes lut[k]."""
        if not lut:
            return
        lab = self.vbg.attribute("label").numpy().reshape(-1)
        src = np.fromiter(lut.keys(), np.int64)
        dst = np.fromiter(lut.values(), np.int64)
        hit = np.isin(lab, src)
        if np.any(hit):
            order = np.argsort(src)
            lab[hit] = dst[order][np.searchsorted(src[order], lab[hit])]

    # ------------------------------------------------------------------ output
    def extract_mesh(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(vertices, faces, vertex segment labels) of the whole map; labels 0 where unknown."""
        if self.vbg.hashmap().size() == 0:
            return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int32)
        try:
            mesh = self.vbg.extract_triangle_mesh(weight_threshold=float(self.cfg.mesh_weight_threshold))
        except RuntimeError as exc:
            # Open3D raises instead of returning an empty mesh when no surface is confident ("Tensor has shape
            # {0}, but is expected ..." from setting the empty mesh's attributes). Any other failure is raised:
            # read as "no surface", it had a node publish an empty map to its consumers.
            if _EMPTY_MESH_ERROR not in str(exc):
                raise
            return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int32)
        if mesh.vertex.positions.shape[0] == 0:
            return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int32)
        v = mesh.vertex.positions.numpy().astype(np.float64)
        f = mesh.triangle.indices.numpy().astype(np.int64)
        return v, f, self.labels_around(v)

    @property
    def num_blocks(self) -> int:
        return int(self.vbg.hashmap().size())

    def memory_bytes(self) -> int:
        per_voxel = 4 * 4  # tsdf, weight, label, conf
        return self.num_blocks * self.res**3 * per_voxel

    # ------------------------------------------------------------------ persistence (no pickle)
    def state(self) -> dict[str, np.ndarray]:
        hm = self.vbg.hashmap()
        active = hm.active_buf_indices().numpy().astype(np.int64)
        keys = hm.key_tensor().numpy()[active]
        out = {"block_keys": keys.astype(np.int32)}
        for name in ("tsdf", "weight", "label", "conf"):
            out[name] = self.vbg.attribute(name).numpy()[active].copy()
        return out

    def load_state(self, state: dict[str, np.ndarray]) -> None:
        keys = state["block_keys"].astype(np.int32)
        self.vbg = o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "label", "conf"),
            attr_dtypes=(o3c.float32, o3c.float32, o3c.int32, o3c.int32),
            attr_channels=((1), (1), (1), (1)),  # type: ignore[arg-type]  # ints are accepted
            voxel_size=self.vs, block_resolution=self.res,
            block_count=max(int(self.cfg.initial_block_count), 2 * len(keys)), device=_CPU,
        )
        if len(keys) == 0:
            return
        hm = self.vbg.hashmap()
        hm.activate(o3c.Tensor(keys))
        buf, _ = hm.find(o3c.Tensor(keys))
        buf = buf.numpy().astype(np.int64)
        for name in ("tsdf", "weight", "label", "conf"):
            self.vbg.attribute(name).numpy()[buf] = state[name]
