"""Convexity-based geometric segmentation of a depth image (Furrer et al. 2018; Tateno et al. 2015).

A pixel is an edge when, against some neighbour j (several offsets, 4 directions):
* depth discontinuity: the neighbour is off the tangent plane by more than a depth-relative margin
  |(p_j - p_i) . n_i| > max(ratio * z_i, floor), or
* concavity: the neighbour lies in front of the tangent plane ((p_j - p_i) . n_i > 0, an inside
  corner such as floor meets wall) and the normals differ: n_i . n_j < min_convexity.
Convex edges (a table's rim) do not cut, so one convex object stays one segment. The remaining
pixels form segments by 4-connected components.

Speed (issue 26): everything runs on planar float32 images (one contiguous (H, W) array per
coordinate), so every step is a contiguous SIMD pass (numpy) or a native OpenCV kernel (box
filters, connected components); no (H, W, 3) strided arithmetic and no shifted copies. The two
directions of one neighbour offset share the point difference and the normal agreement. The
arithmetic (and its float32 rounding) is the same, operation by operation, as the straightforward
(H, W, 3) formulation it replaced, so the segments are bit-identical (test_depth_segmentation.py).
"""

from __future__ import annotations

import dataclasses
import io
import json
import logging
import os
import queue
import signal
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import cv2
import numpy as np

from panoptic_mapping.config import DepthSegmentationConfig
from recon_core.config import from_dict, to_dict
from recon_core.frame import CameraIntrinsics

log = logging.getLogger(__name__)
_EPS = 1e-9
Planes = tuple[np.ndarray, np.ndarray, np.ndarray]


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-pixel dot product of two (H, W, 3) images."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _dot3(a: Planes, b: Planes, out: np.ndarray | None = None, tmp: np.ndarray | None = None) -> np.ndarray:
    """a . b of planar images: a0*b0 + a1*b1 + a2*b2 (this order, float32), into `out` if given."""
    out = np.multiply(a[0], b[0], out=out)
    tmp = np.multiply(a[1], b[1], out=tmp)
    out += tmp
    np.multiply(a[2], b[2], out=tmp)
    out += tmp
    return out


def backproject_planes(depth: np.ndarray, intr: CameraIntrinsics) -> Planes:
    """Camera-frame point coordinates (x, y, z) as three contiguous (H, W) float32 images."""
    h, w = depth.shape
    u = (np.arange(w, dtype=np.float32) - np.float32(intr.cx)) / np.float32(intr.fx)
    v = (np.arange(h, dtype=np.float32) - np.float32(intr.cy)) / np.float32(intr.fy)
    x = np.multiply(depth, u[None, :], dtype=np.float32) if depth.dtype == np.float32 else \
        (depth * u[None, :]).astype(np.float32)
    y = np.multiply(depth, v[:, None], dtype=np.float32) if depth.dtype == np.float32 else \
        (depth * v[:, None]).astype(np.float32)
    z = np.array(depth, np.float32)
    return x, y, z


def backproject(depth: np.ndarray, intr: CameraIntrinsics) -> np.ndarray:
    """(H, W, 3) float32 camera-frame points (x right, y down, z forward); z = 0 where invalid."""
    return cv2.merge(list(backproject_planes(depth, intr)))


def _smooth_planes(points: Planes, vf: np.ndarray, valid: np.ndarray, smoothing: int,
                   masked: Planes | None = None) -> Planes:
    """Mean of the valid points in a (2s+1)^2 window (planar); `masked`: the points times `vf`."""
    if smoothing <= 0:
        return points
    k = (2 * smoothing + 1, 2 * smoothing + 1)
    weight = cv2.boxFilter(vf, -1, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
    np.maximum(weight, 1.0, out=weight)
    invalid = ~valid
    if masked is None:
        masked = (points[0] * vf, points[1] * vf, points[2] * vf)
    out: list[np.ndarray] = []
    for p in masked:
        s: np.ndarray = cv2.boxFilter(p, -1, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
        np.divide(s, weight, out=s)
        np.copyto(s, 0.0, where=invalid)
        out.append(s)
    return out[0], out[1], out[2]


def smooth_points(points: np.ndarray, valid: np.ndarray, smoothing: int) -> np.ndarray:
    """Mean of the valid points in a (2s+1)^2 window: suppresses sensor noise before the edge tests."""
    if smoothing <= 0:
        return points
    planes = tuple(np.ascontiguousarray(points[..., c], np.float32) for c in range(3))
    return cv2.merge(list(_smooth_planes(planes, valid.astype(np.float32), valid, smoothing)))  # type: ignore[arg-type]


def _normal_band(points: Planes, smooth: Planes, valid: np.ndarray, step: int, r0: int, r1: int,
                 n_out: Planes, ok_out: np.ndarray) -> None:
    """`_normal_planes` for the image rows [r0, r1), into those rows of `n_out` and `ok_out`."""
    h, w = valid.shape
    s, rows = step, r1 - r0
    a, b = max(r0, s), min(r1, h - s)  # rows with a vertical difference
    dx: list[np.ndarray] = []
    dy: list[np.ndarray] = []
    for sc in smooth:
        gx = np.zeros((rows, w), np.float32)
        np.subtract(sc[r0:r1, 2 * s:], sc[r0:r1, : -2 * s], out=gx[:, s:-s])
        dx.append(gx)
        gy = np.zeros((rows, w), np.float32)
        if b > a:
            np.subtract(sc[a + s:b + s], sc[a - s:b - s], out=gy[a - r0:b - r0])
        dy.append(gy)
    tmp = np.empty((rows, w), np.float32)
    n = [c[r0:r1] for c in n_out]
    for k, (i, j) in enumerate(((1, 2), (2, 0), (0, 1))):  # n = dx x dy, as numpy's cross computes it
        np.multiply(dx[i], dy[j], out=n[k])
        np.multiply(dx[j], dy[i], out=tmp)
        n[k] -= tmp
    sq = np.multiply(n[0], n[0])
    np.multiply(n[1], n[1], out=tmp)
    sq += tmp
    np.multiply(n[2], n[2], out=tmp)
    sq += tmp
    norm = np.sqrt(sq, out=sq)
    ok = ok_out[r0:r1]
    np.greater(norm, _EPS, out=ok)
    ok &= valid[r0:r1]
    ok[:, :s] = ok[:, -s:] = False
    ok[: max(0, min(rows, s - r0)), :] = False
    ok[max(0, h - s - r0):, :] = False
    np.maximum(norm, _EPS, out=norm)
    bad = ~ok
    for nc in n:
        np.divide(nc, norm, out=nc)
        np.copyto(nc, 0.0, where=bad)
    # face the camera: n . p < 0
    flip = _dot3((n[0], n[1], n[2]), (points[0][r0:r1], points[1][r0:r1], points[2][r0:r1]), out=norm,
                 tmp=tmp) > 0
    for nc in n:
        np.negative(nc, out=nc, where=flip)


def _normal_planes(points: Planes, smooth: Planes, valid: np.ndarray, step: int) -> tuple[Planes, np.ndarray]:
    """Unit normals facing the camera (planar; 0 where unknown) from central differences of the
    smoothed points, and the mask of pixels that have one; by row bands (`_run_bands`: the same
    arithmetic per pixel, the same result)."""
    h, w = valid.shape
    n_out = (np.empty((h, w), np.float32), np.empty((h, w), np.float32), np.empty((h, w), np.float32))
    ok = np.empty((h, w), bool)
    _run_bands(lambda r0, r1: _normal_band(points, smooth, valid, step, r0, r1, n_out, ok), h)
    return n_out, ok


def estimate_normals(points: np.ndarray, valid: np.ndarray, step: int = 2, smoothing: int = 2) -> np.ndarray:
    """Unit normals facing the camera from central differences of box-smoothed points (0 where unknown)."""
    planes = tuple(np.ascontiguousarray(points[..., c], np.float32) for c in range(3))
    smooth = _smooth_planes(planes, valid.astype(np.float32), valid, smoothing)  # type: ignore[arg-type]
    n, _ok = _normal_planes(planes, smooth, valid, step)  # type: ignore[arg-type]
    return cv2.merge(list(n))


def _edge_band(points: Planes, normals: Planes, valid: np.ndarray, margin: np.ndarray, neg_margin: np.ndarray,
               conv: np.float32, combos: list[tuple[int, int]], edge: np.ndarray, r0: int, r1: int) -> None:
    """OR into rows [r0, r1) of `edge` the cuts against the neighbours at the (offset, axis) `combos`,
    both directions (writes no other row: bands can run on different threads)."""
    h, w = valid.shape
    for off, axis in combos:  # the neighbour below / to the right (+off) and above / to the left (-off)
        if axis == 1:
            lo, hi = (slice(r0, r1), slice(0, w - off)), (slice(r0, r1), slice(off, w))
            plus, minus = (slice(None), lo, hi), (slice(None), hi, lo)  # (local rows, pixels, neighbours)
        else:  # differences of rows [a, b): the band's pixels and, `off` rows up, their upper neighbours
            a, b = max(r0 - off, 0), min(r1, h - off)
            if b <= a:
                continue
            lo, hi = (slice(a, b), slice(None)), (slice(a + off, b + off), slice(None))
            p0, q1 = max(a, r0) - a, min(b, r1 - off) - a
            plus = (slice(p0, b - a), (slice(a + p0, b), slice(None)), (slice(a + p0 + off, b + off), slice(None)))
            minus = (slice(0, max(q1, 0)), (slice(a + off, a + off + max(q1, 0)), slice(None)),
                     (slice(a, a + max(q1, 0)), slice(None)))
        diff = (np.subtract(points[0][hi], points[0][lo]), np.subtract(points[1][hi], points[1][lo]),
                np.subtract(points[2][hi], points[2][lo]))  # p(x + off) - p(x)
        tmp = np.empty(diff[0].shape, np.float32)
        nlo = (normals[0][lo], normals[1][lo], normals[2][lo])
        nhi = (normals[0][hi], normals[1][hi], normals[2][hi])
        # normals disagree: n(x) . n(x + off) < min_convexity (the same for both directions)
        concave_pair = _dot3(nlo, nhi, tmp=tmp) < conv
        for sign, (rows, pix, nbr) in ((1, plus), (-1, minus)):
            if rows.stop is not None and rows.stop <= (rows.start or 0):
                continue
            dl = (diff[0][rows], diff[1][rows], diff[2][rows])
            # + direction: pixel x, neighbour x + off: d = (p(x+off) - p(x)) . n(x)
            # - direction: pixel x + off, neighbour x: d = (p(x) - p(x+off)) . n(x+off) = -e, e = diff . n(x+off)
            nl = (nlo[0][rows], nlo[1][rows], nlo[2][rows]) if sign > 0 else (nhi[0][rows], nhi[1][rows], nhi[2][rows])
            d = _dot3(dl, nl, tmp=tmp[rows])
            if sign > 0:
                cut = (d > margin[pix]) | (d < neg_margin[pix]) | ((d > 0) & concave_pair[rows])
            else:
                cut = (d < neg_margin[pix]) | (d > margin[pix]) | ((d < 0) & concave_pair[rows])
            cut &= valid[nbr]
            edge[pix] |= cut


def _bands(h: int) -> list[tuple[int, int]]:
    """Row bands of about `BAND_ROWS` rows: each step's arrays of one band stay in the core's cache
    (a chain of numpy passes over 64-row bands took a third of the CPU time of whole-image passes)."""
    n = max(1, round(h / BAND_ROWS))
    edges = [round(i * h / n) for i in range(n + 1)]
    return [(edges[i], edges[i + 1]) for i in range(n) if edges[i + 1] > edges[i]]


def _run_bands(fn: Callable[[int, int], None], h: int) -> None:
    """fn(r0, r1) over the row bands of an image of `h` rows; with `THREADS` > 1 the lower half of the
    bands on a second thread (numpy releases the interpreter lock in its loops). Bands write disjoint rows."""
    bands = _bands(h)
    if THREADS < 2 or len(bands) < 2:
        for r0, r1 in bands:
            fn(r0, r1)
        return
    half = len(bands) // 2

    def lower() -> None:
        for r0, r1 in bands[half:]:
            fn(r0, r1)

    other = _pool().submit(lower)
    try:
        for r0, r1 in bands[:half]:
            fn(r0, r1)
    finally:
        other.result()


def _edge_planes(points: Planes, normals: Planes, valid: np.ndarray, has_normal: np.ndarray,
                 cfg: DepthSegmentationConfig, scale: float = 1.0) -> np.ndarray:
    """Boolean (H, W) edge map from planar smoothed points and normals (see `edge_map`), by row bands."""
    edge = ~(valid & has_normal)
    z = points[2]
    margin = np.maximum(np.float32(cfg.max_discontinuity_ratio) * z, np.float32(cfg.min_discontinuity_m))
    neg_margin = -margin
    conv = np.float32(cfg.min_convexity)
    h, w = valid.shape
    combos = []
    for off in cfg.neighbour_offsets:
        off = max(1, round(off * scale))
        combos += [(off, axis) for axis in (0, 1) if off < (h if axis == 0 else w)]
    _run_bands(lambda r0, r1: _edge_band(points, normals, valid, margin, neg_margin, conv, combos, edge, r0, r1), h)
    return edge


#: Rows per band of the normal and edge passes (see `_bands`).
BAND_ROWS = 64
#: Threads of the normal and edge passes (1: all on the calling thread). Two use both cores of a 2-core
#: computer while the rest of the mapper waits on the segmentation; results are the same for any number.
THREADS = min(2, os.cpu_count() or 1)
_POOL: ThreadPoolExecutor | None = None


def _pool() -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=1, thread_name_prefix="depth-seg")
    return _POOL


def edge_map(points: np.ndarray, normals: np.ndarray, valid: np.ndarray, cfg: DepthSegmentationConfig,
             scale: float = 1.0) -> np.ndarray:
    """Boolean (H, W): True on depth-discontinuity and concave edges and on invalid pixels."""
    p = tuple(np.ascontiguousarray(points[..., c], np.float32) for c in range(3))
    n = tuple(np.ascontiguousarray(normals[..., c], np.float32) for c in range(3))
    has_n = np.any(normals != 0, axis=2)
    return _edge_planes(p, n, valid, has_n, cfg, scale)  # type: ignore[arg-type]


def segment_depth(
    depth: np.ndarray, intr: CameraIntrinsics, cfg: DepthSegmentationConfig, pixel_area_scale: float = 1.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Geometric segments of a depth image.

    Returns (labels (H, W) int32 with 0 = no segment and segments 1..K, camera points, normals).
    `pixel_area_scale` converts the full-resolution min segment size to this image (1/4 at half size).
    """
    labels, points, normals = segment_depth_planes(depth, intr, cfg, pixel_area_scale)
    return labels, cv2.merge(list(points)), cv2.merge(list(normals))


def segment_depth_planes(
    depth: np.ndarray, intr: CameraIntrinsics, cfg: DepthSegmentationConfig, pixel_area_scale: float = 1.0,
) -> tuple[np.ndarray, Planes, Planes]:
    """`segment_depth` with the camera points and normals as planar (x, y, z) float32 images."""
    valid = depth > 0
    points = backproject_planes(depth, intr)
    vf = valid.astype(np.float32)
    masked = tuple(p * vf for p in points)
    smooth_n = _smooth_planes(points, vf, valid, cfg.normal_smoothing, masked)  # type: ignore[arg-type]
    normals, has_n = _normal_planes(points, smooth_n, valid, cfg.normal_step)
    smooth_e = _smooth_planes(points, vf, valid, cfg.edge_smoothing, masked)  # type: ignore[arg-type]
    edges = _edge_planes(smooth_e, normals, valid, has_n, cfg, scale=float(np.sqrt(pixel_area_scale)))
    n, labels, stats, _ = cv2.connectedComponentsWithStats((~edges).view(np.uint8), connectivity=4)
    min_px = max(1, round(cfg.min_segment_pixels * pixel_area_scale))
    keep = stats[:, cv2.CC_STAT_AREA] >= min_px
    keep[0] = False
    # relabel kept components 1..K (0 = edge, invalid or too small)
    lut = np.zeros(n, np.int32)
    lut[keep] = np.arange(1, int(keep.sum()) + 1, dtype=np.int32)
    return lut[labels], points, normals


def segment_depth_labels(depth: np.ndarray, intr: CameraIntrinsics, cfg: DepthSegmentationConfig,
                         pixel_area_scale: float = 1.0) -> np.ndarray:
    """The segment labels of `segment_depth_planes` alone (what `SegmentationWorker` computes)."""
    return segment_depth_planes(depth, intr, cfg, pixel_area_scale)[0]


# ------------------------------------------------------------------------------ a second process
_HEADER = struct.Struct("<Q")


def _send(stream: Any, header: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
    """One message: an uncompressed npz of ``arrays`` and a JSON ``header`` (no pickle), length-prefixed."""
    buf = io.BytesIO()
    np.savez(buf, _header=np.frombuffer(json.dumps(header).encode(), np.uint8), **arrays)  # type: ignore[arg-type]
    data = buf.getvalue()
    stream.write(_HEADER.pack(len(data)))
    stream.write(data)
    stream.flush()


def _receive(stream: Any) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    head = stream.read(_HEADER.size)
    if len(head) < _HEADER.size:
        raise EOFError
    (n,) = _HEADER.unpack(head)
    data = stream.read(n)
    if len(data) < n:
        raise EOFError
    with np.load(io.BytesIO(data), allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    return json.loads(arrays.pop("_header").tobytes()), arrays


def _job(depth: np.ndarray, intr: CameraIntrinsics, cfg: DepthSegmentationConfig,
         pixel_area_scale: float) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """A job as a message (JSON floats round-trip exactly, so the worker computes what this process would)."""
    header = {"intr": dataclasses.asdict(intr), "cfg": to_dict(cfg), "area": float(pixel_area_scale)}
    return header, {"depth": np.asarray(depth)}


def worker_main() -> None:
    """The worker process: (depth, intrinsics, config, pixel area scale) in on stdin, (labels, CPU seconds)
    out on stdout, in order, until stdin closes. Interrupts are the parent's to handle (it closes stdin)."""
    global THREADS
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    THREADS = 1  # the other core maps the frames before: a second thread here would only contend with it
    src, dst = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr  # nothing else may write into the result stream
    while True:
        try:
            header, arrays = _receive(src)
        except EOFError:
            return
        c0 = time.process_time()
        try:
            cfg = from_dict(DepthSegmentationConfig, header["cfg"])
            labels = segment_depth_labels(arrays["depth"], CameraIntrinsics(**header["intr"]), cfg, header["area"])
            _send(dst, {"cpu_s": time.process_time() - c0}, {"labels": labels})
        except Exception as exc:  # sent back: the parent segments that frame itself
            _send(dst, {"error": repr(exc)}, {})


class SegmentationWorker:
    """Depth segmentation of frames ahead, on another core (issue 26): a process of its own, because the
    mapper's Open3D integration holds the interpreter lock for its whole call. Jobs run in submission
    order; each `submit` returns a Future of (labels, the worker's CPU seconds), bit-identical to
    `segment_depth_labels` here (the same code on the same input). Falls back to segmenting on the
    calling thread when the process cannot start or dies (the Future then holds the error and the caller
    segments the frame itself)."""

    def __init__(self) -> None:
        self._proc: subprocess.Popen[bytes] | None = None
        self._pending: list[Future] = []
        self._lock = threading.Lock()
        self._reader: threading.Thread | None = None
        # jobs go to the process from a thread of their own: a pipe holds 64 KiB, so writing a depth image
        # blocks until the worker reads it, i.e. until it has finished the job before (seen in the node)
        self._jobs: queue.SimpleQueue[tuple | None] = queue.SimpleQueue()
        self._writer: threading.Thread | None = None
        self.broken = False
        #: CPU seconds of the worker's segmentations so far (its process's, not the caller's CPU time)
        self.cpu_s = 0.0

    def _start(self) -> subprocess.Popen[bytes]:
        if self._proc is None:
            code = "from panoptic_mapping.depth_segmentation import worker_main; worker_main()"
            self._proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                          close_fds=True)
            self._reader = threading.Thread(target=self._read, args=(self._proc,), name="depth-seg-reader",
                                            daemon=True)
            self._reader.start()
            self._jobs = queue.SimpleQueue()
            self._writer = threading.Thread(target=self._write, args=(self._proc, self._jobs),
                                            name="depth-seg-writer", daemon=True)
            self._writer.start()
        return self._proc

    def _write(self, proc: subprocess.Popen[bytes], jobs: queue.SimpleQueue[tuple | None]) -> None:
        while (job := jobs.get()) is not None:
            try:
                _send(proc.stdin, *job)
            except (OSError, ValueError) as exc:  # the process is gone: the reader fails what is pending
                log.debug("depth segmentation worker: job not sent (%s)", exc)
                return

    def _read(self, proc: subprocess.Popen[bytes]) -> None:
        while True:
            try:
                header, arrays = _receive(proc.stdout)
            except (EOFError, OSError, ValueError, KeyError) as exc:
                if self._proc is proc:  # not closed by us
                    log.warning("the depth segmentation worker process ended (%r): segmenting on the mapper's "
                                "thread from now on", exc)
                self._fail(RuntimeError(f"depth segmentation worker ended ({exc!r})"))
                return
            with self._lock:
                fut = self._pending.pop(0) if self._pending else None
                self.cpu_s += float(header.get("cpu_s", 0.0))
            if fut is None:
                continue
            if "error" in header:
                fut.set_exception(RuntimeError(f"depth segmentation in the worker failed: {header['error']}"))
            else:
                fut.set_result((arrays["labels"], float(header["cpu_s"])))

    def _fail(self, exc: BaseException) -> None:
        with self._lock:
            pending, self._pending = self._pending, []
            self.broken = True
        for fut in pending:
            fut.set_exception(exc)

    def start(self) -> bool:
        """Start the process now rather than with the first job (a Python process importing the mapper takes
        seconds on a loaded machine; a node starts it while it waits for the camera). False, and the worker
        marked broken, when it cannot start: the caller then segments on its own thread."""
        if self.broken:
            return False
        try:
            self._start()
        except (OSError, ValueError) as exc:
            log.warning("depth segmentation worker unavailable (%s): segmenting on the mapper's thread", exc)
            self._fail(exc)
            return False
        return True

    def submit(self, depth: np.ndarray, intr: CameraIntrinsics, cfg: DepthSegmentationConfig,
               pixel_area_scale: float = 1.0) -> Future:
        fut: Future = Future()
        fut.set_running_or_notify_cancel()  # runs in order, never cancelled
        if self.broken:
            fut.set_exception(RuntimeError("depth segmentation worker unavailable"))
            return fut
        try:
            self._start()
            with self._lock:
                self._pending.append(fut)
            self._jobs.put(_job(depth, intr, cfg, pixel_area_scale))
        except (OSError, ValueError) as exc:
            log.warning("depth segmentation worker unavailable (%s): segmenting on the mapper's thread", exc)
            self._fail(exc)
        return fut

    def drain(self) -> None:
        """Wait until every job submitted so far is done."""
        with self._lock:
            pending = list(self._pending)
        for fut in pending:
            fut.exception()

    def close(self) -> None:
        """Stop the process (it exits when its input closes) and fail what is still pending."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        self._jobs.put(None)
        if self._writer is not None:
            self._writer.join(timeout=30)
        try:
            if proc.stdin is not None:
                proc.stdin.close()
            proc.wait(timeout=5)
        except (OSError, subprocess.TimeoutExpired):
            proc.kill()
            proc.wait()
        if self._reader is not None:
            self._reader.join(timeout=5)
        self._fail(RuntimeError("depth segmentation worker closed"))
        self.broken = False
