"""Peer process A: serves SegmentImage (threshold segmentation) and publishes /tf until stopped."""

from __future__ import annotations

import signal
import sys

import numpy as np
import rclpy
from rclpy.node import Node
from scene_recon_interfaces.msg import SegmentInfo
from scene_recon_interfaces.srv import SegmentImage
from sensor_msgs.msg import RegionOfInterest
from tf2_msgs.msg import TFMessage

from panoptic_mapping.dataio.transforms import make_transform
from ros_nodes.conversions import image_to_rgb, labels_to_image, make_transform_stamped

#: The transform the peer publishes; the test checks it arrives intact.
T_MAP_CAMERA = make_transform([1.0, 2.0, 3.0], [0.0, 0.0, np.sin(0.25), np.cos(0.25)])


class SegmentationPeer(Node):
    def __init__(self) -> None:
        super().__init__("segmentation_peer")
        self.create_service(SegmentImage, "segment_image", self.on_request)
        self.tf_pub = self.create_publisher(TFMessage, "/tf", 10)
        self.create_timer(0.05, self.publish_tf)

    def on_request(self, request: SegmentImage.Request, response: SegmentImage.Response) -> SegmentImage.Response:
        rgb = image_to_rgb(request.color)
        labels = 1 + (rgb.mean(axis=2) > 127).astype(np.int32)  # 1: dark, 2: bright
        response.labels = labels_to_image(labels, frame_id=request.color.header.frame_id)
        for seg_id, name in ((1, "floor"), (2, "table")):
            ys, xs = np.nonzero(labels == seg_id)
            roi = RegionOfInterest(x_offset=int(xs.min()), y_offset=int(ys.min()),
                                   width=int(xs.max() - xs.min() + 1), height=int(ys.max() - ys.min() + 1))
            response.segments.append(SegmentInfo(id=seg_id, class_id=seg_id, class_name=name,
                                                 is_thing=seg_id == 2, instance_id=seg_id - 1, score=0.9, box=roi))
        response.success = True
        response.message = "threshold peer"
        return response

    def publish_tf(self) -> None:
        stamp = self.get_clock().now().nanoseconds
        self.tf_pub.publish(TFMessage(transforms=[make_transform_stamped(T_MAP_CAMERA, "map", "camera_link", stamp)]))


def main() -> int:
    rclpy.init()
    node = SegmentationPeer()
    signal.signal(signal.SIGTERM, lambda *_: rclpy.try_shutdown())
    print("peer ready", flush=True)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
