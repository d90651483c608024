"""Serialized (CDR) sizes of the messages the nodes exchange, built with the nodes' own conversions.

    python -m ros_nodes.message_sizes --map MAP_DIR [--urdf SCENE.urdf] [--width 640 --height 480]

Prints one JSON object (bytes): `color` (rgb8), `depth` (16UC1), `labels` (32SC1, the segmentation
service's label image), `entities_with_meshes` / `entities_without_meshes` (the mapper's
PanopticEntityArray of the map's entities, as it publishes it), `urdf` (the replacer's
`robot_description` String). The benchmark suite (`scene_recon.bench`) starts it as a child process
(the tools and the ROS adapters do not import each other) for its DDS projection.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def _image(width: int, height: int, encoding: str, channels: int, itemsize: int):
    from sensor_msgs.msg import Image

    msg = Image(height=height, width=width, encoding=encoding, is_bigendian=0, step=width * channels * itemsize)
    msg.header.frame_id = "camera_color_optical_frame"
    msg.data = np.zeros(height * width * channels * itemsize, np.uint8).tobytes()
    return msg


def sizes(map_dir: Path | None, urdf: Path | None, width: int = 640, height: int = 480) -> dict[str, int]:
    from rclpy.serialization import serialize_message
    from std_msgs.msg import String

    out = {"color": len(serialize_message(_image(width, height, "rgb8", 3, 1))),
           "depth": len(serialize_message(_image(width, height, "16UC1", 1, 2))),
           "labels": len(serialize_message(_image(width, height, "32SC1", 1, 4)))}
    if map_dir is not None:
        from scene_recon_interfaces.msg import PanopticEntityArray

        from recon_core.entity import load_entities
        from ros_nodes.entity_conversions import entity_to_msg

        entities = load_entities(map_dir)
        for key, meshes in (("entities_with_meshes", True), ("entities_without_meshes", False)):
            msg = PanopticEntityArray()
            msg.header.frame_id = "map"
            msg.entities = [entity_to_msg(e, meshes) for e in entities]
            out[key] = len(serialize_message(msg))
        out["entities"] = len(entities)
    if urdf is not None:
        out["urdf"] = len(serialize_message(String(data=urdf.read_text(encoding="utf-8"))))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--map", type=Path, help="mapped-scene folder (entities.json + meshes)")
    p.add_argument("--urdf", type=Path, help="scene.urdf of a replaced scene")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    args = p.parse_args(argv)
    print(json.dumps(sizes(args.map, args.urdf, args.width, args.height)))
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
