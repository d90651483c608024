"""ROS 2 bag loader (`.mcap` and `.db3`, via rosbags; no ROS install needed).

Reading happens in two passes over disjoint topics:
1. TF (`/tf`, `/tf_static`) and camera info are small: they are read completely first, so every
   image can be posed by interpolation between its neighbouring TF samples.
2. Images stream once, in log-time order. Color and depth are paired by an approximate-time
   policy on their header stamps; only paired messages are decoded.

A truncated bag (recorder killed: no MCAP summary/footer, no metadata.yaml) or one that breaks off
mid-stream yields the frames before the cut, with a warning (`truncated`, `damage`): see
`panoptic_mapping.dataio.salvage`. Colour and depth of different sizes are brought onto the depth
grid (`panoptic_mapping.dataio.align`), with the depth stream's own camera info when there is one.
"""

from __future__ import annotations

import logging
import struct
from collections import Counter, deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from panoptic_mapping.dataio.align import register_to_depth
from panoptic_mapping.dataio.config import DataInputConfig
from panoptic_mapping.dataio.image_codec import decode_color, decode_depth
from panoptic_mapping.dataio.intrinsics import read_intrinsics_file
from panoptic_mapping.dataio.pairing import take_nearest
from panoptic_mapping.dataio.salvage import SalvagedBag, storage_files
from panoptic_mapping.dataio.transforms import TransformBuffer, TransformLookupError
from recon_core.frame import CameraIntrinsics, DatasetError, RGBDFrame, sanitize_depth

log = logging.getLogger(__name__)

IMAGE_TYPE = "sensor_msgs/msg/Image"
INFO_TYPE = "sensor_msgs/msg/CameraInfo"
TF_TYPE = "tf2_msgs/msg/TFMessage"
BAG_SUFFIXES = (".mcap", ".db3")


def is_bag(path: Path) -> bool:
    """A rosbag2 folder (metadata.yaml, or storage files only: a recording cut short), or a bare .mcap/.db3 file."""
    path = Path(path)
    if path.is_file():
        return path.suffix in BAG_SUFFIXES
    if not path.is_dir():
        return False
    return (path / "metadata.yaml").is_file() or any(
        p.suffix in BAG_SUFFIXES and p.is_file() for p in path.iterdir())


def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_KILTED)


def header_stamp_ns(raw: bytes | memoryview) -> int:
    """Header stamp of a CDR-serialised message that starts with std_msgs/Header, without decoding it.

    CDR layout: 4-byte encapsulation (byte 1: 0/1 = big/little endian), int32 sec, uint32 nanosec.
    """
    if len(raw) < 12:
        raise DatasetError("message too short to hold a header")
    fmt = "<iI" if raw[1] & 1 else ">iI"
    sec, nanosec = struct.unpack_from(fmt, raw, 4)
    return sec * 1_000_000_000 + nanosec


@dataclass
class SkipCounts:
    """Why messages or frames were not turned into frames; reported by `inspect` and the CLI."""

    unpaired_color: int = 0
    unpaired_depth: int = 0
    non_monotonic: int = 0
    no_pose: int = 0
    bad_image: int = 0
    all_depth_invalid: int = 0
    tf_conflicts: int = 0
    reasons: Counter = field(default_factory=Counter)

    def as_dict(self) -> dict[str, int]:
        return {
            "unpaired_color": self.unpaired_color,
            "unpaired_depth": self.unpaired_depth,
            "non_monotonic": self.non_monotonic,
            "no_pose": self.no_pose,
            "bad_image": self.bad_image,
            "all_depth_invalid": self.all_depth_invalid,
            "tf_conflicts": self.tf_conflicts,
        }


@dataclass
class _Pending:
    stamp: int
    raw: bytes


class RosbagLoader:
    """Iterates synchronised, posed `RGBDFrame`s of a ROS 2 bag.

    Example:
        loader = RosbagLoader("scene.mcap")
        for frame in loader:
            ...
        print(loader.skips.as_dict())
    """

    def __init__(self, path: str | Path, config: DataInputConfig | None = None):
        from rosbags.highlevel import AnyReader

        self.path = Path(path)
        self.config = config or DataInputConfig()
        if not self.path.exists():
            raise DatasetError(f"bag {self.path} does not exist")
        self._typestore = _typestore()
        #: True when the bag ends early (cut-off file, damaged index or chunk): frames before the cut are read.
        self.truncated = False
        #: What was damaged, one line per file (for warnings and `inspect`).
        self.damage: list[str] = []
        self._reader = self._open_reader(AnyReader)
        self.skips = SkipCounts()
        self.resampled_frames = 0
        #: Colour/depth pairs met by the last iteration (before stride, pose and image checks).
        self.pairs = 0
        self._camera_frame_seen = ""
        self.topics = self._resolve_topics()
        self.tf = TransformBuffer(
            max_extrapolation_ns=int(self.config.tf_max_extrapolation_s * 1e9),
            max_gap_ns=int(self.config.tf_max_gap_s * 1e9),
        )
        self._infos: list[tuple[int, CameraIntrinsics, str]] = []
        self._depth_infos: list[tuple[int, CameraIntrinsics, str]] = []
        self._override: tuple[float, float, float, float] | None = None
        if self.config.intrinsics:
            if len(self.config.intrinsics) != 4:
                raise DatasetError("intrinsics override must be [fx, fy, cx, cy]")
            fx, fy, cx, cy = (float(v) for v in self.config.intrinsics)
            self._override = (fx, fy, cx, cy)
        elif self.config.intrinsics_file:
            self._override = read_intrinsics_file(self.config.intrinsics_file)
        self._read_tf_and_info()
        self._warned_frames = False

    def _open_reader(self, any_reader: type) -> Any:
        """rosbags' reader; for a cut-off or damaged bag, the salvaging reader (with a warning)."""
        first: Exception | None = None
        attempts: list[list[Path]] = [[self.path]]
        if self.path.is_dir() and not (self.path / "metadata.yaml").is_file():
            attempts = [storage_files(self.path)]  # a recording cut short: no metadata.yaml was written
        for paths in attempts:
            try:
                reader = any_reader(paths, default_typestore=self._typestore)
                reader.open()
                return reader
            except Exception as exc:  # rosbags raises several error types for unreadable bags
                first = first or exc
        files = storage_files(self.path)
        try:
            salvaged = SalvagedBag(files, self._typestore) if files else None
        except Exception as exc:
            log.debug("salvaging %s failed: %s", self.path, exc)
            salvaged = None
        if salvaged is None or not salvaged.connections:
            raise DatasetError(
                f"cannot open bag {self.path}: {str(first).rstrip('.')}. Is it a rosbag2 (.mcap/.db3) recording?"
            ) from first
        self._mark_truncated(f"cannot be opened as a complete bag ({first})", salvaged.damage)
        return salvaged

    def _mark_truncated(self, what: str, damage: list[str] | None = None) -> None:
        if not self.truncated:
            log.warning("%s %s: reading the frames before the cut%s", self.path, what,
                        f" ({'; '.join(damage)})" if damage else "")
        self.truncated = True
        for line in damage or [what]:
            if line not in self.damage:
                self.damage.append(line)

    # ------------------------------------------------------------------ set-up
    def close(self) -> None:
        self._reader.close()

    def __enter__(self) -> RosbagLoader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def connections(self):
        return self._reader.connections

    def _salvage_damage(self) -> list[str]:
        return list(getattr(self._reader, "damage", []))

    def _resolve_topics(self) -> dict[str, str]:
        cfg = self.config.topics
        by_topic = {c.topic: c.msgtype for c in self._reader.connections}
        images = sorted(t for t, m in by_topic.items() if m == IMAGE_TYPE)
        infos = sorted(t for t, m in by_topic.items() if m == INFO_TYPE)

        def check(topic: str, msgtype: str, what: str) -> str:
            if topic not in by_topic:
                raise DatasetError(
                    f"{what} topic {topic!r} is not in {self.path}; topics: {sorted(by_topic) or 'none'}"
                )
            if by_topic[topic] != msgtype:
                raise DatasetError(f"{what} topic {topic!r} has type {by_topic[topic]}, expected {msgtype}")
            return topic

        def pick(cands: list[str], what: str, option: str) -> str:
            if len(cands) == 1:
                return cands[0]
            if not cands:
                raise DatasetError(
                    f"no {what} topic found in {self.path} (image topics: {images or 'none'}); "
                    f"set it with {option}"
                )
            raise DatasetError(f"several candidate {what} topics {cands}; choose one with {option}")

        if cfg.depth:
            depth = check(cfg.depth, IMAGE_TYPE, "depth")
        else:
            cands = [t for t in images if "depth" in t.lower()]
            aligned = [t for t in cands if "align" in t.lower() or "registered" in t.lower()]
            depth = pick(aligned or cands, "depth", "--depth-topic (topics.depth)")
        if cfg.color:
            color = check(cfg.color, IMAGE_TYPE, "color")
        else:
            rest = [t for t in images if t != depth and "depth" not in t.lower() and "label" not in t.lower()]
            named = [t for t in rest if any(k in t.lower() for k in ("color", "rgb"))]
            color = pick(named or rest, "color", "--color-topic (topics.color)")
        if cfg.camera_info:
            info = check(cfg.camera_info, INFO_TYPE, "camera info")
        elif self.config.intrinsics:
            info = ""
        else:
            ns = color.rsplit("/", 1)[0]
            beside = [t for t in infos if t.rsplit("/", 1)[0] == ns]
            named = [t for t in infos if "color" in t.lower() or "rgb" in t.lower()]
            if not infos:
                raise DatasetError(
                    f"{self.path} has no sensor_msgs/CameraInfo topic; record the camera info or give "
                    "intrinsics [fx, fy, cx, cy] (--intrinsics)"
                )
            info = pick(beside or named or infos, "camera info", "--camera-info-topic (topics.camera_info)")
        # the depth stream's own calibration: used only when depth and colour differ in size
        depth_ns = depth.rsplit("/", 1)[0]
        depth_info = next((t for t in infos if t.rsplit("/", 1)[0] == depth_ns and t != info), "")
        labels = check(cfg.labels, IMAGE_TYPE, "labels") if cfg.labels else ""
        tf = cfg.tf if by_topic.get(cfg.tf) == TF_TYPE else ""
        tf_static = cfg.tf_static if by_topic.get(cfg.tf_static) == TF_TYPE else ""
        return {"color": color, "depth": depth, "camera_info": info, "depth_camera_info": depth_info,
                "labels": labels, "tf": tf, "tf_static": tf_static}

    def _read_tf_and_info(self) -> None:
        topics = {self.topics["tf"], self.topics["tf_static"], self.topics["camera_info"],
                  self.topics["depth_camera_info"]} - {""}
        conns = [c for c in self._reader.connections if c.topic in topics]
        try:
            # rosbags reads every topic when given no connection: guard the empty case.
            for conn, _t, raw in self._reader.messages(connections=conns) if conns else ():
                msg = self._reader.deserialize(raw, conn.msgtype)
                if conn.msgtype == INFO_TYPE:
                    self._add_info(msg, depth=conn.topic == self.topics["depth_camera_info"])
                    continue
                static = conn.topic == self.topics["tf_static"]
                for tr in msg.transforms:  # a deserialised TFMessage
                    st = tr.header.stamp
                    t, q = tr.transform.translation, tr.transform.rotation
                    self.tf.add(
                        tr.header.frame_id, tr.child_frame_id, st.sec * 1_000_000_000 + st.nanosec,
                        np.array([t.x, t.y, t.z]), np.array([q.x, q.y, q.z, q.w]), static=static,
                    )
        except DatasetError:
            raise
        except Exception as exc:  # keep the TF and calibration read before the damage
            self._mark_truncated(f"breaks off while reading TF/camera info ({exc})")
        self.skips.tf_conflicts = self.tf.conflicts
        if self.topics["camera_info"] and not self._infos:
            raise DatasetError(f"{self.path}: camera info topic {self.topics['camera_info']} holds no valid message")
        self._infos.sort(key=lambda x: x[0])
        self._depth_infos.sort(key=lambda x: x[0])

    def _add_info(self, msg, depth: bool = False) -> None:
        st = msg.header.stamp
        try:
            intr = CameraIntrinsics.from_matrix(np.asarray(msg.k, dtype=np.float64), msg.width, msg.height)
        except DatasetError as exc:
            self.skips.reasons["bad_camera_info"] += 1
            log.warning("skipping camera info: %s", exc)
            return
        (self._depth_infos if depth else self._infos).append(
            (st.sec * 1_000_000_000 + st.nanosec, intr, msg.header.frame_id))

    @staticmethod
    def _info_at(infos: list[tuple[int, CameraIntrinsics, str]], stamp_ns: int) -> CameraIntrinsics | None:
        if not infos:
            return None
        stamps = [s for s, _, _ in infos]
        i = max(int(np.searchsorted(stamps, stamp_ns, side="right")) - 1, 0)
        return infos[i][1]

    def intrinsics_at(self, stamp_ns: int, width: int, height: int) -> CameraIntrinsics:
        """Colour camera intrinsics at `stamp_ns` (the override at width x height when one is given)."""
        if self._override is not None:
            return CameraIntrinsics(*self._override, width=width, height=height)
        info = self._info_at(self._infos, stamp_ns)
        assert info is not None
        return info

    def register(self, stamp_ns: int, color: np.ndarray, depth: np.ndarray, labels: np.ndarray | None
                 ) -> tuple[np.ndarray, CameraIntrinsics, np.ndarray | None]:
        """Colour (and labels) on the depth grid with the matching intrinsics; raises DatasetError."""
        hd, wd = depth.shape[:2]
        hc, wc = color.shape[:2]
        same = (hc, wc) == (hd, wd)
        k_color: tuple[float, float, float, float] | None
        k_depth: tuple[float, float, float, float] | None = None
        describes = "color"
        if self._override is not None:
            k_color, describes = self._override, "auto"
        else:
            info = self._info_at(self._infos, stamp_ns)
            assert info is not None
            k_color = (info.fx, info.fy, info.cx, info.cy)
            if same and (info.width, info.height) != (wd, hd):
                raise DatasetError(f"camera info says {info.width}x{info.height} but images are {wd}x{hd}")
            if not same:
                if (info.width, info.height) == (wd, hd):  # the chosen info describes the depth image
                    k_color, k_depth = None, k_color
                elif (info.width, info.height) != (wc, hc):
                    raise DatasetError(f"camera info says {info.width}x{info.height} but color is {wc}x{hc} "
                                       f"and depth {wd}x{hd}")
                dinfo = self._info_at(self._depth_infos, stamp_ns)
                if k_depth is None and dinfo is not None and (dinfo.width, dinfo.height) == (wd, hd):
                    k_depth = (dinfo.fx, dinfo.fy, dinfo.cx, dinfo.cy)
                if k_color is None:
                    describes = "depth"
        color, intr, labels, resampled = register_to_depth(color, depth, k_color, k_depth, labels, describes)
        if resampled:
            if not self.resampled_frames:
                log.warning("%s: colour %dx%d and depth %dx%d differ in size; colour is resampled onto the depth grid",
                            self.path, wc, hc, wd, hd)
            self.resampled_frames += 1
        return color, intr, labels

    # ------------------------------------------------------------------ pairing
    def iter_pairs(self) -> Iterator[tuple[int, _Pending, _Pending, _Pending | None]]:
        """Yield (depth_stamp, color, depth, labels) raw messages paired by approximate time."""
        color_t, depth_t, label_t = self.topics["color"], self.topics["depth"], self.topics["labels"]
        conns = [c for c in self._reader.connections if c.topic in {color_t, depth_t, label_t}]
        slop = int(self.config.sync_slop_s * 1e9)
        colors: deque[_Pending] = deque()
        depths: deque[_Pending] = deque()
        labels: dict[int, _Pending] = {}
        last: dict[str, int | None] = {color_t: None, depth_t: None, label_t: None}
        newest_color = newest_label = newest = -(2**62)
        last_emitted = -(2**62)
        # A depth waits for a color stamped at or after it (a closer one may still come), but not
        # longer than `horizon` of stream time, so a dead color stream cannot pile up memory.
        horizon = max(4 * slop, 500_000_000)

        def finalize(force: bool) -> Iterator[tuple[int, _Pending, _Pending, _Pending | None]]:
            nonlocal last_emitted
            while depths:
                d = depths[0]
                waiting = newest_color < d.stamp or (label_t and newest_label < d.stamp)
                if not force and waiting and newest - d.stamp < horizon:
                    return  # a closer color (or the frame's labels) may still arrive
                depths.popleft()
                for k in [k for k in labels if k < d.stamp]:
                    del labels[k]
                best, dropped = take_nearest(colors, d.stamp, slop)
                self.skips.unpaired_color += dropped
                if best is None:
                    self.skips.unpaired_depth += 1
                    continue
                if d.stamp <= last_emitted:
                    self.skips.non_monotonic += 1
                    continue
                last_emitted = d.stamp
                yield d.stamp, best, d, labels.pop(d.stamp, None)

        try:
            for conn, _t, raw in self._reader.messages(connections=conns):
                stamp = header_stamp_ns(raw)
                prev = last[conn.topic]
                if prev is not None and stamp <= prev and conn.topic != label_t:
                    self.skips.non_monotonic += 1
                    log.warning("%s: header stamp %.6f s is not after %.6f s; message skipped",
                                conn.topic, stamp * 1e-9, prev * 1e-9)
                    continue
                last[conn.topic] = stamp
                newest = max(newest, stamp)
                item = _Pending(stamp, bytes(raw))
                if conn.topic == depth_t:
                    depths.append(item)
                elif conn.topic == color_t:
                    colors.append(item)
                    newest_color = stamp
                else:
                    labels[stamp] = item
                    newest_label = max(newest_label, stamp)
                yield from finalize(force=False)
        except DatasetError:
            raise
        except Exception as exc:  # a cut-off or damaged file: keep the frames before the damage
            self._mark_truncated(
                f"breaks off after {last_emitted * 1e-9 if last_emitted > 0 else 0:.3f} s of images ({exc})")
        for line in self._salvage_damage():
            if line not in self.damage:
                self.damage.append(line)
        yield from finalize(force=True)
        self.skips.unpaired_color += len(colors)

    # ------------------------------------------------------------------ frames
    def pose_at(self, frame_id: str, stamp_ns: int) -> np.ndarray:
        """T_map_camera at `stamp_ns`; raises TransformLookupError."""
        return self.tf.lookup(self.config.map_frame, frame_id, stamp_ns)

    def pose_hint(self, camera_frame: str = "") -> str:
        """Why camera poses cannot be looked up, and what to pass instead ("" when they can)."""
        cam = (camera_frame or self.config.camera_frame or self._camera_frame_seen).lstrip("/")
        target = self.config.map_frame.lstrip("/")
        frames = self.tf.frames
        tf_topics = " and ".join(t for t in (self.topics["tf"], self.topics["tf_static"]) if t)
        if not frames:
            return (f"the bag has no TF data ({tf_topics or 'no /tf or /tf_static topic'}): camera poses come "
                    "from /tf + /tf_static; record them (or map a frame folder with poses)")
        shown = ", ".join(sorted(frames)[:12]) + (", ..." if len(frames) > 12 else "")
        if cam and cam not in frames:
            return (f"the camera frame '{cam}' (the images' frame_id) is not in the TF tree (frames: {shown}); "
                    "pass --camera-frame FRAME")
        roots = self.tf.roots()
        if target not in frames:
            root = self.tf.root_of(cam) if cam else (roots[0] if len(roots) == 1 else "")
            if root:
                return f"TF root is '{root}', not '{target}': pass --map-frame {root}"
            return f"'{target}' is not in the TF tree (roots: {', '.join(roots)}): pass --map-frame ROOT"
        if cam and not self.tf.can_connect(target, cam):
            return (f"'{target}' and '{cam}' are in different TF trees (roots: {', '.join(roots)}; the camera's is "
                    f"'{self.tf.root_of(cam)}'): pass --map-frame {self.tf.root_of(cam)} or record the missing link")
        no_pose = [(n, r) for r, n in self.skips.reasons.items() if r.startswith("no pose")]
        if no_pose:
            n, reason = max(no_pose)
            return f"{reason[len('no pose: '):]} ({n} frames)"
        return ""

    def _decode(self, msgtype: str, raw: bytes):
        return self._reader.deserialize(raw, msgtype)

    def __iter__(self) -> Iterator[RGBDFrame]:
        cfg = self.config
        emitted = 0
        index = -1
        for stamp, c_raw, d_raw, l_raw in self.iter_pairs():
            index += 1
            self.pairs = index + 1
            if index < cfg.start or (index - cfg.start) % max(cfg.stride, 1):
                continue
            try:
                cmsg = self._decode(IMAGE_TYPE, c_raw.raw)
                dmsg = self._decode(IMAGE_TYPE, d_raw.raw)
                color = decode_color(cmsg.encoding, cmsg.height, cmsg.width, cmsg.step, cmsg.data,
                                     cmsg.is_bigendian)
                depth, n_bad = sanitize_depth(
                    decode_depth(dmsg.encoding, dmsg.height, dmsg.width, dmsg.step, dmsg.data, dmsg.is_bigendian)
                )
                labels = decode_labels(self._decode(IMAGE_TYPE, l_raw.raw)) if l_raw is not None else None
                if labels is not None and labels.shape != color.shape[:2]:
                    raise DatasetError(f"label image {labels.shape[1]}x{labels.shape[0]} differs in size from "
                                       f"color {color.shape[1]}x{color.shape[0]}")
                color, intr, labels = self.register(stamp, color, depth, labels)
                extras = {"labels": labels} if labels is not None else {}
            except DatasetError as exc:
                self.skips.bad_image += 1
                self.skips.reasons[str(exc)[:160]] += 1
                log.error("frame at %.3f s skipped: %s", stamp * 1e-9, exc)
                continue
            if not np.any(depth > 0):
                self.skips.all_depth_invalid += 1
                log.warning("frame at %.3f s skipped: no valid depth pixel", stamp * 1e-9)
                continue
            frame_id = cfg.camera_frame or cmsg.header.frame_id
            self._camera_frame_seen = self._camera_frame_seen or frame_id
            if not self._warned_frames and dmsg.header.frame_id and dmsg.header.frame_id != frame_id:
                self._warned_frames = True
                log.warning("depth frame %r differs from camera frame %r: assuming depth is registered "
                            "to color", dmsg.header.frame_id, frame_id)
            try:
                pose = self.pose_at(frame_id, stamp)
            except TransformLookupError as exc:
                self.skips.no_pose += 1
                self.skips.reasons[f"no pose: {str(exc)[:100]}"] += 1
                if cfg.require_pose:
                    log.warning("frame at %.3f s skipped: %s", stamp * 1e-9, exc)
                    continue
                pose = None
            try:
                frame = RGBDFrame(color=color, depth=depth, intrinsics=intr, pose=pose, timestamp_ns=stamp,
                                  index=emitted, frame_id=frame_id, invalid_depth_pixels=n_bad, extras=extras)
            except DatasetError as exc:
                self.skips.bad_image += 1
                self.skips.reasons[str(exc)[:160]] += 1
                log.error("frame at %.3f s skipped: %s", stamp * 1e-9, exc)
                continue
            yield frame
            emitted += 1
            if cfg.max_frames and emitted >= cfg.max_frames:
                return


def decode_labels(msg) -> np.ndarray:
    """Label image (32SC1, 16UC1 or mono16) -> (H, W) int32."""
    from panoptic_mapping.dataio.image_codec import _rows

    dtypes = {"32SC1": "i4", "16UC1": "u2", "mono16": "u2", "32UC1": "u4"}
    if msg.encoding not in dtypes:
        raise DatasetError(f"unsupported label encoding {msg.encoding!r}; use 32SC1")
    dt = np.dtype((">" if msg.is_bigendian else "<") + dtypes[msg.encoding])
    rows = _rows(msg.data, msg.height, msg.width, msg.step, msg.width * dt.itemsize, "label image")
    return np.ascontiguousarray(rows).view(dt).reshape(msg.height, msg.width).astype(np.int32)
