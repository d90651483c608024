"""Peer process B: calls SegmentImage and waits for a TFMessage; prints what it got as JSON."""

from __future__ import annotations

import json
import sys
import time

import numpy as np
import rclpy
from rclpy.node import Node
from scene_recon_interfaces.srv import SegmentImage
from tf2_msgs.msg import TFMessage

from ros_nodes.conversions import image_to_labels, rgb_to_image, transform_to_matrix


def main() -> int:
    rclpy.init()
    node = Node("client_peer")
    received: list[TFMessage] = []
    node.create_subscription(TFMessage, "/tf", received.append, 10)
    client = node.create_client(SegmentImage, "segment_image")
    deadline = time.monotonic() + 30.0
    while not client.wait_for_service(timeout_sec=0.5):
        if time.monotonic() > deadline:
            print(json.dumps({"error": "service not available"}), flush=True)
            return 1
    rgb = np.zeros((48, 64, 3), np.uint8)
    rgb[:, 40:] = 200  # bright right part: columns 40..63
    request = SegmentImage.Request(color=rgb_to_image(rgb, frame_id="camera", encoding="bgr8"))
    future = client.call_async(request)
    rclpy.spin_until_future_complete(node, future, timeout_sec=20.0)
    response = future.result()
    while not received and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    out = {"success": False}
    if response is not None:
        labels = image_to_labels(response.labels)
        out = {
            "success": response.success,
            "message": response.message,
            "label_counts": {int(k): int(v) for k, v in zip(*np.unique(labels, return_counts=True), strict=False)},
            "segments": [{"id": s.id, "class_name": s.class_name, "is_thing": s.is_thing,
                          "box": [s.box.x_offset, s.box.y_offset, s.box.width, s.box.height]}
                         for s in response.segments],
        }
    if received:
        tf = received[0].transforms[0]
        out["tf"] = {"parent": tf.header.frame_id, "child": tf.child_frame_id,
                     "matrix": transform_to_matrix(tf.transform).tolist()}
    print(json.dumps(out), flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
