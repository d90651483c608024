"""Bag reading throughput: synchronised, decoded, posed 640x480 frame pairs per second.

Writes a bag per storage (mcap, db3) with realistic image content, then times
(a) the baseline: rosbags deserialising every color/depth message, nothing else, and
(b) our RosbagLoader: pairing, decoding to RGB/metres, TF chain lookup, frame validation.
The ratio b/a shows what our layer costs on top of reading the bag.

    .venv/bin/python benchmarks/bench_bag_reading.py [--frames 300]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import best_of, write_result
from panoptic_mapping.dataio import CameraIntrinsics
from panoptic_mapping.dataio.bag import RosbagLoader
from panoptic_mapping.dataio.bag_writer import RGBDBagWriter
from panoptic_mapping.dataio.transforms import make_transform


def make_bag(path: Path, storage: str, n: int, width: int = 640, height: int = 480) -> None:
    rng = np.random.default_rng(0)
    intr = CameraIntrinsics(525, 525, (width - 1) / 2, (height - 1) / 2, width, height)
    yy, xx = np.mgrid[0:height, 0:width]
    base = np.stack([xx * 255 // width, yy * 255 // height, (xx + yy) * 255 // (width + height)], -1)
    with RGBDBagWriter(path, storage=storage) as w:
        for i in range(n):
            color = np.clip(base + rng.integers(-8, 8, base.shape), 0, 255).astype(np.uint8)
            depth = (1.0 + 2.0 * yy / height + 0.01 * rng.standard_normal((height, width))).astype(np.float32)
            pose = make_transform([0.01 * i, 0.0, 1.5], [0.0, 0.0, np.sin(0.005 * i), np.cos(0.005 * i)])
            w.write_frame(10**9 + i * 33_333_333, color, depth, intr, pose)


def baseline(path: Path) -> int:
    from rosbags.highlevel import AnyReader

    n = 0
    with AnyReader([path]) as reader:
        conns = [c for c in reader.connections if c.msgtype == "sensor_msgs/msg/Image"]
        for conn, _t, raw in reader.messages(connections=conns):
            reader.deserialize(raw, conn.msgtype)
            n += 1
    return n // 2


def ours(path: Path) -> int:
    with RosbagLoader(path) as loader:
        return sum(1 for _ in loader)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench_bag_"))
    results = {}
    try:
        for storage in ("mcap", "db3"):
            path = tmp / storage
            make_bag(path, storage, args.frames)
            assert ours(path) == args.frames  # warm-up + sanity
            t_base = best_of(lambda p=path: baseline(p), args.repeats)
            t_ours = best_of(lambda p=path: ours(p), args.repeats)
            results[storage] = {
                "frames": args.frames,
                "baseline_deserialize_pairs_per_s": round(args.frames / t_base, 1),
                "loader_pairs_per_s": round(args.frames / t_ours, 1),
                "ratio_loader_over_baseline_time": round(t_ours / t_base, 3),
            }
            r = results[storage]
            print(f"{storage:5s} 640x480: loader {r['loader_pairs_per_s']:7.1f} pairs/s | rosbags deserialize "
                  f"only {r['baseline_deserialize_pairs_per_s']:7.1f} pairs/s | time ratio "
                  f"{r['ratio_loader_over_baseline_time']:.2f}x  (goal >= 300 pairs/s)")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    out = write_result("bag_reading", {"resolution": [640, 480], "results": results})
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
