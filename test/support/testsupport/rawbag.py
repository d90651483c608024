"""Builders of small, real ROS 2 bags written with rosbags directly (independent of our writer)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

TS = get_typestore(Stores.ROS2_KILTED)
T = TS.types


def header(stamp_ns: int, frame: str):
    return T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9), frame_id=frame)


def image(stamp_ns: int, frame: str, encoding: str, arr: np.ndarray, step_pad: int = 0, bigendian: int = 0):
    arr = np.ascontiguousarray(arr)
    h, w = arr.shape[:2]
    row = arr.reshape(h, -1).view(np.uint8)
    if step_pad:
        row = np.concatenate([row, np.zeros((h, step_pad), np.uint8)], axis=1)
    return T["sensor_msgs/msg/Image"](header=header(stamp_ns, frame), height=h, width=w, encoding=encoding,
                                      is_bigendian=bigendian, step=row.shape[1],
                                      data=np.ascontiguousarray(row).reshape(-1))


def camera_info(stamp_ns: int, frame: str, k: tuple[float, float, float, float], w: int, h: int):
    fx, fy, cx, cy = k
    roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return T["sensor_msgs/msg/CameraInfo"](
        header=header(stamp_ns, frame), height=h, width=w, distortion_model="plumb_bob", d=np.zeros(5),
        k=np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1.0]), r=np.eye(3).reshape(-1),
        p=np.array([fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1.0, 0]), binning_x=0, binning_y=0, roi=roi)


def tf_message(items: list[tuple[int, str, str, np.ndarray, np.ndarray]]):
    """items: (stamp_ns, parent, child, translation, quaternion xyzw)."""
    out = []
    for stamp, parent, child, t, q in items:
        out.append(T["geometry_msgs/msg/TransformStamped"](
            header=header(stamp, parent), child_frame_id=child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=float(t[0]), y=float(t[1]), z=float(t[2])),
                rotation=T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]),
                                                           w=float(q[3])))))
    return T["tf2_msgs/msg/TFMessage"](transforms=out)


class RawBag:
    """Collects (topic, msgtype, log_time, msg) and writes a bag in either storage."""

    def __init__(self) -> None:
        self.records: list[tuple[str, str, int, object]] = []

    def add(self, topic: str, msg: object, log_time: int | None = None) -> None:
        msgtype = msg.__msgtype__
        if log_time is None:
            log_time = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec if hasattr(msg, "header") else 0
        self.records.append((topic, msgtype, log_time, msg))

    def write(self, path: Path, storage: str = "mcap") -> Path:
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        with Writer(path, version=9, storage_plugin=plugin) as w:
            conns = {}
            for topic, msgtype, log_time, msg in sorted(self.records, key=lambda r: r[2]):
                if topic not in conns:
                    conns[topic] = w.add_connection(topic, msgtype, typestore=TS)
                w.write(conns[topic], log_time, TS.serialize_cdr(msg, msgtype))
        return path
