"""Write RGB-D recordings as real ROS 2 bags (`.mcap` or `.db3`) with rosbags, no ROS install needed.

Topics follow the RealSense driver's names, so bags written here and bags recorded on a robot
read back through the same loader. The camera pose is written as a two-hop TF chain, like a
real robot: `map -> camera_link` on `/tf` and the fixed `camera_link -> <optical frame>` rotation
on `/tf_static`.

MCAP bags are written with chunk compression (`compression`, default `lz4`): the storage's own
compression, which every MCAP reader (rosbags, rosbag2's mcap plugin, Foxglove) decompresses, so
nothing about reading changes. lz4 is the default because reading must stay fast: on the demo
bag it takes 830 MB to about 360 MB (depth 2.4x, label images 75x; noisy colour does not compress
losslessly) and adds about 1 ms of decompression per colour/depth pair; `zstd` makes the bag a
third smaller again (about 275 MB) at about 3 ms per pair (docs/DATA_SOURCES.md). Every image
message gets a chunk of its own and TF and camera info share one per frame: readers pick chunks
by channel, so the pass over TF and a pass over colour and depth decompress nothing else (rosbags'
writer closed a chunk every 1 MB, mixing all topics). SQLite (`.db3`)
bags are written uncompressed (rosbag2's per-message compression there needs a plugin many readers
lack).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from panoptic_mapping.dataio.image_codec import encode_color, encode_depth
from panoptic_mapping.dataio.transforms import invert_transform, matrix_to_quat
from recon_core.frame import CameraIntrinsics

#: Rotation from a ROS body frame (x forward, y left, z up) to its optical frame (z forward, x right, y down).
T_LINK_OPTICAL = np.array(
    [[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)


#: Chunk compressions of MCAP bags; "none" writes plain chunks (the format before issue 25).
MCAP_COMPRESSIONS = ("lz4", "zstd", "none")


@dataclass
class BagTopics:
    color: str = "/camera/color/image_raw"
    depth: str = "/camera/depth/image_rect_raw"
    camera_info: str = "/camera/color/camera_info"
    labels: str = "/ground_truth/panoptic_labels"
    tf: str = "/tf"
    tf_static: str = "/tf_static"


class RGBDBagWriter:
    """Context manager writing frames, TF and camera info into a rosbag2 folder at `path`."""

    def __init__(
        self,
        path: str | Path,
        storage: str = "mcap",
        topics: BagTopics | None = None,
        map_frame: str = "map",
        camera_link: str = "camera_link",
        optical_frame: str = "camera_color_optical_frame",
        color_encoding: str = "rgb8",
        depth_encoding: str = "16UC1",
        compression: str | None = None,
    ):
        """`compression`: MCAP chunk compression, one of MCAP_COMPRESSIONS (None: lz4 for mcap,
        "none" for db3, whose only valid value it is)."""
        from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
        from rosbags.typesys import Stores, get_typestore

        if storage not in ("mcap", "db3"):
            raise ValueError(f"storage must be 'mcap' or 'db3', not {storage!r}")
        if compression is None:
            compression = "lz4" if storage == "mcap" else "none"
        if storage == "db3" and compression != "none":
            raise ValueError(f"db3 bags are written uncompressed (compression 'none'), not {compression!r}")
        if compression not in MCAP_COMPRESSIONS:
            raise ValueError(f"compression must be one of {', '.join(MCAP_COMPRESSIONS)}, not {compression!r}")
        self.storage, self.compression = storage, compression
        self.path = Path(path)
        if self.path.exists():
            raise FileExistsError(f"{self.path} exists; remove it or choose another output path")
        self.topics = topics or BagTopics()
        self.map_frame, self.camera_link, self.optical_frame = map_frame, camera_link, optical_frame
        self.color_encoding, self.depth_encoding = color_encoding, depth_encoding
        self.ts = get_typestore(Stores.ROS2_KILTED)
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        self._writer = Writer(self.path, version=9, storage_plugin=plugin)
        if compression != "none":
            # MCAP chunk compression: rosbags' STORAGE mode (zstd; metadata.yaml says none, as rosbag2's
            # mcap plugin writes it); lz4 swaps the chunk compressor once the storage is open.
            self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self._conns: dict[str, object] = {}
        self._static_written = False
        self.frames_written = 0

    def __enter__(self) -> RGBDBagWriter:
        self._writer.open()
        if self.compression == "lz4":
            from lz4.frame import compress as lz4_compress  # type: ignore[import-untyped, unused-ignore]

            storage: Any = self._writer.storage  # rosbags' McapWriter: its chunk compressor is swapped
            if getattr(storage, "compression", None) != "zstd" or not hasattr(storage, "compressor"):
                self._writer.close()
                raise RuntimeError("this rosbags version's MCAP writer cannot take lz4 chunks; use compression='zstd'")
            storage.compression = "lz4"
            storage.compressor = lz4_compress
        return self

    def __exit__(self, *exc: object) -> None:
        self._writer.close()

    # -------------------------------------------------------------- messages
    def _conn(self, topic: str, msgtype: str):
        if topic not in self._conns:
            self._conns[topic] = self._writer.add_connection(topic, msgtype, typestore=self.ts)
        return self._conns[topic]

    def write_msg(self, topic: str, msgtype: str, msg: object, log_time_ns: int) -> None:
        self._writer.write(self._conn(topic, msgtype), log_time_ns, self.ts.serialize_cdr(msg, msgtype))

    def close_chunk(self) -> None:
        """MCAP: end the pending chunk here (when it holds messages), so what follows starts a new one."""
        storage: Any = self._writer.storage
        chunk = getattr(storage, "chunk", None)
        if chunk is not None and getattr(chunk, "msgs", None) and hasattr(storage, "close_chunk"):
            storage.close_chunk()

    def _header(self, stamp_ns: int, frame_id: str):
        t = self.ts.types
        return t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=int(stamp_ns // 1_000_000_000),
                                                   nanosec=int(stamp_ns % 1_000_000_000)),
            frame_id=frame_id,
        )

    def image_msg(self, stamp_ns: int, frame_id: str, encoded: tuple) -> object:
        encoding, h, w, step, data = encoded
        return self.ts.types["sensor_msgs/msg/Image"](
            header=self._header(stamp_ns, frame_id), height=h, width=w, encoding=encoding,
            is_bigendian=0, step=step, data=np.ascontiguousarray(data, dtype=np.uint8),
        )

    def camera_info_msg(self, stamp_ns: int, intr: CameraIntrinsics) -> object:
        t = self.ts.types
        k = intr.matrix.reshape(-1)
        p = np.zeros(12)
        p[[0, 2, 5, 6, 10]] = [intr.fx, intr.cx, intr.fy, intr.cy, 1.0]
        roi = t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        return t["sensor_msgs/msg/CameraInfo"](
            header=self._header(stamp_ns, self.optical_frame), height=intr.height, width=intr.width,
            distortion_model="plumb_bob", d=np.zeros(5), k=k, r=np.eye(3).reshape(-1), p=p,
            binning_x=0, binning_y=0, roi=roi,
        )

    def transform_msg(self, stamp_ns: int, parent: str, child: str, t_parent_child: np.ndarray) -> object:
        t = self.ts.types
        q = matrix_to_quat(t_parent_child[:3, :3])
        tr = t_parent_child[:3, 3]
        return t["geometry_msgs/msg/TransformStamped"](
            header=self._header(stamp_ns, parent), child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=float(tr[0]), y=float(tr[1]), z=float(tr[2])),
                rotation=t["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]),
                                                           w=float(q[3])),
            ),
        )

    def write_tf(self, stamp_ns: int, transforms: list[tuple[str, str, np.ndarray]], static: bool = False) -> None:
        msgs = [self.transform_msg(stamp_ns, p, c, T) for p, c, T in transforms]
        msg = self.ts.types["tf2_msgs/msg/TFMessage"](transforms=msgs)  # type: ignore[arg-type]
        topic = self.topics.tf_static if static else self.topics.tf
        self.write_msg(topic, "tf2_msgs/msg/TFMessage", msg, stamp_ns)

    # -------------------------------------------------------------- frames
    def write_frame(
        self,
        stamp_ns: int,
        color: np.ndarray,
        depth_m: np.ndarray,
        intrinsics: CameraIntrinsics,
        pose: np.ndarray | None,
        labels: np.ndarray | None = None,
    ) -> None:
        """Write one frame; `pose` is the optical-frame-to-map transform (None: no TF this frame)."""
        if not self._static_written:
            self.write_tf(stamp_ns, [(self.camera_link, self.optical_frame, T_LINK_OPTICAL)], static=True)
            self._static_written = True
        if pose is not None:
            t_map_link = np.asarray(pose, dtype=np.float64) @ invert_transform(T_LINK_OPTICAL)
            self.write_tf(stamp_ns, [(self.map_frame, self.camera_link, t_map_link)])
        self.write_msg(self.topics.camera_info, "sensor_msgs/msg/CameraInfo",
                       self.camera_info_msg(stamp_ns, intrinsics), stamp_ns)
        self.close_chunk()  # TF and camera info of this frame in one small chunk, each image in its own
        self.write_msg(self.topics.color, "sensor_msgs/msg/Image",
                       self.image_msg(stamp_ns, self.optical_frame, encode_color(color, self.color_encoding)),
                       stamp_ns)
        self.close_chunk()
        self.write_msg(self.topics.depth, "sensor_msgs/msg/Image",
                       self.image_msg(stamp_ns, self.optical_frame, encode_depth(depth_m, self.depth_encoding)),
                       stamp_ns)
        self.close_chunk()
        if labels is not None:
            lab = np.ascontiguousarray(labels, dtype="<i4")
            enc = ("32SC1", lab.shape[0], lab.shape[1], lab.strides[0], lab.reshape(-1).view(np.uint8))
            self.write_msg(self.topics.labels, "sensor_msgs/msg/Image",
                           self.image_msg(stamp_ns, self.optical_frame, enc), stamp_ns)
            self.close_chunk()
        self.frames_written += 1
