"""Per-frame fusion of 2D panoptic masks with geometric segments (Sec. 3.1).

Input: geometric segments G_j (a label image from `depth_segmentation`), panoptic masks M_i
(a label image + per-mask class/instance/score), the frame's 3D points.
Output: per-frame point-cloud segments (P_k, c_k, o_k) as a segment image plus per-segment arrays.

Full method (the paper's):
1. split: a segment G_j that fully contains a mask M_i (the mask lies > 0.9 inside G_j while
   covering < 0.5 of G_j) gives the mask's pixels their own segment, so instances that geometry
   cannot separate (a keyboard on a desk) survive;
2. label assignment as in Voxblox++: each segment takes the mask covering most of it, if that
   mask covers at least `min_label_share` of it, else it is background;
   (extension: a mask lying mostly on depth-edge pixels, typically a small object, gets its
   valid-depth pixels as a segment of its own, `rescue_edge_masks`);
3. Euclidean clustering: the segments of one thing instance are clustered by 3D distance; only
   the largest cluster keeps the instance, the rest become background (a chair mask bleeding onto
   the far floor).
   (extension, `stuff_front_ratio`: a stuff mask's depth-edge pixels lying in front of the plane of
   that mask around them get no label: a wall mask bleeding over a cup in front of the wall.)
Baseline (Voxblox++): step 2 only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from panoptic_mapping.config import FusionConfig

BACKGROUND = -1
#: Grid step (pixels) of the stuff-surface fit in `_drop_stuff_foreground`.
_FRONT_STEP = 4


@dataclass
class PanopticMasks:
    """A 2D panoptic segmentation at processing resolution.

    `labels`: (H, W) int32 mask ids (0 = none); arrays indexed by mask id: class id, thing flag,
    score. Mask ids are per-frame instance ids (a network's instance numbering is not stable).
    """

    labels: np.ndarray
    class_id: np.ndarray
    is_thing: np.ndarray
    score: np.ndarray

    @classmethod
    def empty(cls, shape: tuple[int, int]) -> PanopticMasks:
        return cls(np.zeros(shape, np.int32), np.full(1, BACKGROUND, np.int32), np.zeros(1, bool), np.zeros(1))


@dataclass
class FrameSegments:
    """Per-frame segments (P_k, c_k, o_k): `image` holds segment ids 1..K (0 = none); arrays indexed
    by segment id give the mask (instance) id (0 = background), class id (-1 = background), thing
    flag and score."""

    image: np.ndarray
    mask_id: np.ndarray
    class_id: np.ndarray
    is_thing: np.ndarray
    score: np.ndarray
    num_split: int = 0
    num_clustered_out: int = 0

    @property
    def count(self) -> int:
        return len(self.mask_id) - 1


def _overlap(a: np.ndarray, b: np.ndarray, na: int, nb: int) -> np.ndarray:
    return np.bincount((a.astype(np.int64) * nb + b).ravel(), minlength=na * nb).reshape(na, nb)


def fuse(geo: np.ndarray, masks: PanopticMasks, points: np.ndarray, cfg: FusionConfig, full: bool,
         min_points: int, min_rescue_points: int | None = None) -> FrameSegments:
    """Fuse geometric segments `geo` (0 = none) with `masks`; `points` (H, W, 3) for clustering.

    `min_points`: the fewest pixels a segment needs to carry a label. `min_rescue_points` (default: the
    same): the fewest a mask rescued from the depth edges needs, as its own segment, to carry its label.
    A small object far away is a mask of a few dozen pixels that the convexity segmentation leaves all
    edge; when a thing is born only from repeated observations (`extraction.min_instance_frames` > 1),
    one frame's few pixels are a vote, not a verdict, and the mapper passes the association's floor here.
    """
    geo = geo.astype(np.int64)
    geo_in = geo
    n_g = int(geo.max()) + 1
    n_g_geometric = n_g
    min_rescue = min_points if min_rescue_points is None else min_rescue_points
    n_m = len(masks.class_id)
    pan = masks.labels.astype(np.int64)
    num_split = 0
    rescued_floor = np.zeros(0, np.int64)  # per rescued segment (ids from n_g_geometric on)
    if full and cfg.rescue_edge_masks and n_m > 1:
        # small objects are mostly edge pixels for the depth segmentation (a cup a few metres away):
        # a mask lying mostly outside every segment gets its valid-depth pixels as a segment
        valid = points[..., 2] > 0
        # one pass: per mask, its pixels inside segments (column 1) and its valid edge pixels (column 0)
        cat = np.where(geo > 0, 1, np.where(valid, 0, 2)).astype(np.int64)
        per_mask = np.bincount((pan * 3 + cat).ravel(), minlength=n_m * 3).reshape(n_m, 3)
        in_seg, on_edge = per_mask[:, 1], per_mask[:, 0]
        # a thing's mask (the birth rule weighs it across frames) down to `min_rescue`; stuff as any segment
        need = np.where(masks.is_thing[:n_m], min_rescue, min_points)
        rescue = (on_edge > in_seg) & (on_edge >= need)
        rescue[0] = False
        ms = np.flatnonzero(rescue)
        if ms.size:
            lut = np.zeros(n_m, np.int64)
            lut[ms] = n_g + np.arange(ms.size)
            lut_pan = lut[pan]
            geo = np.where((cat == 0) & (lut_pan > 0), lut_pan, geo)
            n_g += ms.size
            num_split += int(ms.size)
            rescued_floor = need[ms]
    if full and cfg.split and n_m > 1 and n_g > 1:
        ov = _overlap(geo, pan, n_g, n_m)
        size_m = np.maximum(ov.sum(axis=0), 1)
        size_g = np.maximum(ov.sum(axis=1), 1)
        minority = ov / size_g[:, None] < cfg.split_segment_share
        if cfg.split_across_segments:
            # extension: the mask lies > coverage inside segments it is a minority of (e.g. a book
            # on a shelf seen across the board and the back panel): carve each piece out
            minority[0, :] = False
            covered = np.where(minority, ov, 0).sum(axis=0) / size_m
            cand = minority & (covered[None, :] > cfg.split_mask_coverage) & (ov >= max(min_points // 4, 1))
        else:  # the paper: one segment fully contains the mask
            cand = (ov / size_m[None, :] > cfg.split_mask_coverage) & minority
        cand[0, :] = False
        cand[:, 0] = False
        gs, ms = np.nonzero(cand)
        if gs.size:
            lut = np.arange(n_g, dtype=np.int64)[:, None].repeat(n_m, axis=1)
            lut[gs, ms] = n_g + np.arange(gs.size)
            geo = np.where(geo > 0, lut[geo, pan], 0)
            n_g += gs.size
            num_split += int(gs.size)
    # label assignment (Voxblox++): majority mask if it covers enough of the segment
    ov = _overlap(geo, pan, n_g, n_m)
    size_g = ov.sum(axis=1)
    ov_masks = ov.copy()
    ov_masks[:, 0] = 0
    best = np.argmax(ov_masks, axis=1)
    share = ov_masks[np.arange(n_g), best] / np.maximum(size_g, 1)
    mask_of = np.where(share >= cfg.min_label_share, best, 0)
    mask_of[0] = 0
    # tiny segments carry no label (not enough evidence), and segments absent from the image vanish;
    # a rescued mask's segment (ids from n_g_geometric on, before any split) has its own floor
    floor = np.full(n_g, min_points, np.int64)
    floor[n_g_geometric:n_g_geometric + len(rescued_floor)] = rescued_floor
    small = size_g < floor
    mask_of[small] = 0
    num_out = 0
    if full and cfg.cluster:
        num_out = _cluster_instances(geo, mask_of, masks, points, size_g, cfg)
    if full and cfg.absorb_edge_pixels:
        geo, size_g = _absorb_edge_pixels(geo, pan, mask_of, points, n_g, cfg, ov)
    if full and cfg.stuff_front_ratio > 0:
        geo, size_g = _drop_stuff_foreground(geo, geo_in == 0, mask_of, pan, masks.is_thing, points, n_g, cfg,
                                             size_g)
    present = size_g > 0
    present[0] = False
    new_id = np.zeros(n_g, np.int32)
    new_id[present] = np.arange(1, int(present.sum()) + 1)
    image = new_id[geo]
    keep = np.r_[0, np.flatnonzero(present)]
    mid = mask_of[keep]
    cls = np.where(mid > 0, masks.class_id[mid], BACKGROUND).astype(np.int32)
    cls[0] = BACKGROUND
    return FrameSegments(image, mid.astype(np.int32), cls, np.where(mid > 0, masks.is_thing[mid], False),
                         np.where(mid > 0, masks.score[mid], 0.0), num_split, num_out)


def _absorb_edge_pixels(geo: np.ndarray, pan: np.ndarray, mask_of: np.ndarray, points: np.ndarray, n_g: int,
                        cfg: FusionConfig, ov: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Depth-edge pixels inside a mask join the mask's largest segment (thin legs, silhouettes).

    The convexity segmentation leaves a band of edge pixels around every object and swallows thin
    parts whole; the mask says whom they belong to. Pixels farther than `absorb_depth_margin_m`
    in depth from the segment's range are left out (a mask bleeding onto far background).
    `ov`: the (segment, mask) overlap of `geo` and `pan` when the caller has it (any number of mask
    columns >= pan.max() + 1; the extra ones are empty).
    """
    n_m = int(pan.max()) + 1
    if n_m <= 1:
        return geo, np.bincount(geo.ravel(), minlength=n_g)
    ov = _overlap(geo, pan, n_g, n_m) if ov is None else ov[:, :n_m].copy()
    ov[:, 0] = 0
    labelled = np.zeros(n_g, bool)
    labelled[mask_of > 0] = True
    ov[~labelled, :] = 0
    ov[0, :] = 0
    # the host of mask m: its largest segment that was labelled with m
    host_ok = np.zeros_like(ov, bool)
    g_idx = np.flatnonzero(mask_of > 0)
    host_ok[g_idx, mask_of[g_idx]] = True
    ov = np.where(host_ok, ov, 0)
    host = np.argmax(ov, axis=0)
    host[ov.max(axis=0) == 0] = 0
    z = points[..., 2]
    edge = (geo == 0) & (z > 0) & (host > 0)[pan]
    if not np.any(edge):
        return geo, np.bincount(geo.ravel(), minlength=n_g)
    # depth range of the host segments only (exact min / max: the same values as a full per-label scan)
    is_host = np.zeros(n_g, bool)
    is_host[host[host > 0]] = True
    on_host = is_host[geo]
    g_host, z_host = geo[on_host], z[on_host]
    zmin32 = np.full(n_g, np.inf, z.dtype)
    zmax32 = np.full(n_g, -np.inf, z.dtype)
    np.minimum.at(zmin32, g_host, z_host)
    np.maximum.at(zmax32, g_host, z_host)
    zmin, zmax = zmin32.astype(np.float64), zmax32.astype(np.float64)
    ys, xs = np.nonzero(edge)
    cand = host[pan[ys, xs]]
    ze = z[ys, xs]
    margin = cfg.absorb_depth_margin_m
    ok = (ze >= zmin[cand] - margin) & (ze <= zmax[cand] + margin)
    geo = geo.copy()
    geo[ys[ok], xs[ok]] = cand[ok]
    return geo, np.bincount(geo.ravel(), minlength=n_g)


def _drop_stuff_foreground(geo: np.ndarray, was_edge: np.ndarray, mask_of: np.ndarray, pan: np.ndarray,
                           is_thing: np.ndarray, points: np.ndarray, n_g: int, cfg: FusionConfig,
                           size_g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth-edge pixels that joined a stuff mask's segment (rescue, absorption) but lie in front of that
    mask's surface leave it.

    A far wall is mostly depth-edge pixels for the convexity segmentation (its depth steps by the
    sensor's quantisation there), so its mask is rescued or absorbs its edge pixels whole; where the mask
    bleeds over a small thing in front of the wall (a cup on a shelf 3 cm from it, itself all edge pixels
    at 2.5 m), the cup's pixels voted *wall* into the cup's voxels and the map gave the cup's surface to
    the wall (bench-clutter draw 0). The mask's own surface around each such pixel is a plane in inverse
    depth (exact for a plane seen by a pinhole camera), fitted by least squares to the mask's valid pixels
    within `stuff_front_window_px`; an edge pixel more than `stuff_front_ratio` x its depth (at least
    `stuff_front_min_m`) nearer than that plane is no wall. The few pixels of a small thing barely move a
    fit over the window's hundreds of wall pixels (a thing wider than about half the window is not caught).

    The fit is smooth across the image, so it is made on every `_FRONT_STEP`-th pixel in both directions
    (box-filtered moments, Cramer's rule per grid pixel: no loop over pixels) and its inverse depth
    interpolated bilinearly to the full image: a few ms a frame where the full-resolution fit took 0.3 s.
    """
    import cv2

    # the stuff masks labelling a segment; an edge pixel in one joined it through `pan` (rescue, absorption)
    thing = np.asarray(is_thing, bool)
    stuff_masks = np.unique(mask_of[mask_of > 0])
    stuff_masks = stuff_masks[~thing[stuff_masks]]
    if stuff_masks.size == 0:
        return geo, size_g
    joined = was_edge & (geo > 0)
    if not np.any(joined):
        return geo, size_g
    step = _FRONT_STEP
    z = points[..., 2]
    h, w = z.shape
    zc = z[::step, ::step].astype(np.float64)
    hc, wc = zc.shape
    vv, uu = np.mgrid[0:hc, 0:wc].astype(np.float64)
    k = max(3, round(cfg.stuff_front_window_px / step) | 1)  # odd, in grid pixels
    win = (k, k)
    min_ref = max(6.0, 0.25 * k * k)  # a fit needs a real patch of the mask around the pixel
    thr = np.maximum(np.float32(cfg.stuff_front_ratio) * z, np.float32(cfg.stuff_front_min_m))
    drop = np.zeros(geo.shape, bool)

    def box(img: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(img, cv2.CV_64F, win, normalize=False, borderType=cv2.BORDER_CONSTANT)

    for m in stuff_masks.tolist():
        here = joined & (pan == m)
        if not np.any(here):
            continue
        ref = ((pan[::step, ::step] == m) & (zc > 0)).astype(np.float64)
        d = np.where(ref > 0, 1.0 / np.maximum(zc, 1e-6), 0.0)
        s1, su, sv = box(ref), box(ref * uu), box(ref * vv)
        suu, suv, svv = box(ref * uu * uu), box(ref * uu * vv), box(ref * vv * vv)
        sd, sud, svd = box(d), box(d * uu), box(d * vv)
        # moments about each grid pixel, so the fitted intercept is the plane's inverse depth there
        a12, a13 = su - uu * s1, sv - vv * s1
        a22 = suu - 2 * uu * su + uu * uu * s1 + 1e-6 * s1
        a33 = svv - 2 * vv * sv + vv * vv * s1 + 1e-6 * s1
        a23 = suv - uu * sv - vv * su + uu * vv * s1
        b2, b3 = sud - uu * sd, svd - vv * sd
        # the 3x3 normal equations, solved by Cramer's rule (symmetric: cofactors by row = by column)
        c11, c12, c13 = a22 * a33 - a23 * a23, a13 * a23 - a12 * a33, a12 * a23 - a13 * a22
        det = s1 * c11 + a12 * c12 + a13 * c13
        good = (s1 >= min_ref) & (det > 0)
        d_fit = np.where(good, (sd * c11 + b2 * c12 + b3 * c13) / np.where(good, det, 1.0), 0.0)
        good &= d_fit > 0
        # to full resolution: grid pixel (i, j) is image pixel (i * step, j * step)
        full_fit = cv2.resize(d_fit.astype(np.float32), (wc * step, hc * step), interpolation=cv2.INTER_LINEAR)
        full_ok = cv2.resize(good.astype(np.uint8), (wc * step, hc * step), interpolation=cv2.INTER_NEAREST)
        shift = np.array([[1, 0, (step - 1) / 2], [0, 1, (step - 1) / 2]], np.float32)  # resize centres cells; undo it
        full_fit = cv2.warpAffine(full_fit, shift, (wc * step, hc * step),
                                  flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                  borderMode=cv2.BORDER_REPLICATE)[:h, :w]
        full_ok = full_ok[:h, :w] > 0
        # z < 1 / fit - thr, with fit > 0: no division over the image
        drop |= here & full_ok & (full_fit > 0) & (z * full_fit < 1 - thr * full_fit)
    if not np.any(drop):
        return geo, size_g
    geo = np.where(drop, 0, geo)
    return geo, np.bincount(geo.ravel(), minlength=n_g)


def _find(parent: list[int], i: int) -> int:
    """Union-find root with path halving."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


def _cluster_instances(geo: np.ndarray, mask_of: np.ndarray, masks: PanopticMasks, points: np.ndarray,
                       size_g: np.ndarray, cfg: FusionConfig) -> int:
    """Keep only the largest 3D cluster of each thing instance's segments (in place on `mask_of`)."""
    removed = 0
    segs_by_mask: dict[int, list[int]] = {}
    for g in np.flatnonzero(mask_of > 0).tolist():
        m = int(mask_of[g])
        if masks.is_thing[m]:
            segs_by_mask.setdefault(m, []).append(int(g))
    multi = {m: s for m, s in segs_by_mask.items() if len(s) > 1}
    if not multi:
        return 0
    flat_geo = geo.ravel()
    flat_pts = points.reshape(-1, 3)
    # pixel indices of the segments clustered, grouped by segment in raster order (a stable sort of
    # those pixels only: the same index lists as a stable sort of the whole image)
    wanted = np.zeros(len(size_g), bool)
    wanted[[g for segs in multi.values() for g in segs]] = True
    pix = np.flatnonzero(wanted[flat_geo])
    order = pix[np.argsort(flat_geo[pix], kind="stable")]
    bounds = np.searchsorted(flat_geo[order], np.arange(len(size_g) + 1))
    rng = np.random.default_rng(0)
    for segs in multi.values():
        clouds, trees = [], []
        for g in segs:
            idx = order[bounds[g]: bounds[g + 1]]
            if idx.size > cfg.cluster_max_points:
                idx = rng.choice(idx, cfg.cluster_max_points, replace=False)
            cloud = flat_pts[idx]
            clouds.append(cloud)
            trees.append(cKDTree(cloud))
        n = len(segs)
        parent = list(range(n))
        for i in range(n):
            for j in range(i + 1, n):
                d, _ = trees[j].query(clouds[i], k=1, distance_upper_bound=cfg.cluster_distance_m)
                if np.isfinite(d).any():
                    parent[_find(parent, i)] = _find(parent, j)
        roots = np.array([_find(parent, i) for i in range(n)])
        sizes = {r: int(size_g[np.array(segs)[roots == r]].sum()) for r in set(roots.tolist())}
        keep_root = max(sizes, key=lambda r: sizes[r])
        for i, g in enumerate(segs):
            if roots[i] != keep_root:
                mask_of[g] = 0
                removed += 1
    return removed
