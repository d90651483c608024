"""The mapper node integrates on a thread of its own (`MapperNode._mapping_loop`), not on an executor timer, so the
events executor's one thread is never held by an integration and no step waits to be handed a timer. The loop
must outlive a failing step (counted `loop_errors`, reported as the last error), wake for a queued frame without
waiting out its idle period, and stop when the node is destroyed."""

from __future__ import annotations

import os
import time

import pytest
from testsupport.ros import domain_id

pytestmark = pytest.mark.ros


def test_the_mapping_loop_outlives_a_failing_step_and_stops_with_the_node(tmp_path):
    import rclpy

    from ros_nodes.mapper_node import MapperNode

    os.environ["ROS_DOMAIN_ID"] = str(domain_id("spare2"))
    rclpy.init(args=["--ros-args", "-p", f"data_root:={tmp_path}", "-p", "use_segmentation:=false",
                     "-p", "gravity_check:=false"])
    try:
        node = MapperNode()
        steps: list[float] = []
        original = node._process

        def failing_once() -> None:
            steps.append(time.monotonic())
            if len(steps) == 1:
                raise RuntimeError("a broken step")
            original()

        node._process = failing_once  # type: ignore[method-assign]
        deadline = time.monotonic() + 10
        while len(steps) < 5 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert len(steps) >= 5, steps  # stepping on after the failure
        assert node.counters["loop_errors"] == 1
        assert "a broken step" in node.last_error
        # idle, the loop sleeps (here up to 5 s) between steps; a frame that arrives wakes it at once
        node.LOOP_IDLE_S = 5.0  # type: ignore[misc]
        time.sleep(0.3)
        n = len(steps)
        from sensor_msgs.msg import Image

        frame = Image()
        frame.header.stamp.sec = 1
        node._enqueue(frame, frame)
        deadline = time.monotonic() + 2.0
        while len(steps) == n and time.monotonic() < deadline:
            time.sleep(0.005)
        assert len(steps) > n and steps[n] - steps[n - 1] < 4.0
        thread = node._loop_thread
        assert thread is not None and thread.is_alive() and thread.name == "mapping-loop"
        node.destroy_node()
        assert not thread.is_alive()
    finally:
        rclpy.shutdown()


def test_a_keyframe_sent_for_labels_is_never_read_as_done_by_the_status(tmp_path):
    """`status()` runs on another thread without the map's lock. It read a keyframe counted before it was
    pending as a keyframe with nothing left to do (keyframes 9, segmented 8, pending 0, queue 0): the bag-launch
    test took that for a settled map once on a loaded CI machine. The frame in hand counts as queued until the
    step is over, and a keyframe is counted once it is pending."""
    import numpy as np
    import rclpy
    from sensor_msgs.msg import Image

    from recon_core.frame import CameraIntrinsics, RGBDFrame
    from ros_nodes.mapper_node import MapperNode

    os.environ["ROS_DOMAIN_ID"] = str(domain_id("spare2"))
    rclpy.init(args=["--ros-args", "-p", f"data_root:={tmp_path}", "-p", "gravity_check:=false"])
    try:
        node = MapperNode()
        seen: list[dict] = []

        waiting: list = []  # done-callbacks of calls whose answer never comes in this test

        class _Answer:
            def add_done_callback(self, cb) -> None:
                waiting.append(cb)

            def done(self) -> bool:
                return False

        def call_async(_request):
            seen.append(node.status())  # what another thread reading the status now would see
            return _Answer()

        node.seg_client.service_is_ready = lambda: True  # type: ignore[method-assign]
        node.seg_client.call_async = call_async  # type: ignore[method-assign]
        depth = np.full((24, 32), 1.5, np.float32)
        frame = RGBDFrame(np.zeros((24, 32, 3), np.uint8), depth, CameraIntrinsics(30.0, 30.0, 16.0, 12.0, 32, 24),
                          np.eye(4), 1_000_000_000)
        with node.lock:
            node._released.append((frame, Image(), Image()))
            node._process_locked()
        (during,) = seen
        assert len(waiting) == 1  # the answer wakes the mapping loop when it comes
        assert during["queue"] == 1 and during["keyframes"] == 0, during  # in hand: not done
        after = node.status()
        assert after["keyframes"] == 1 and after["pending_segmentations"] == 1 and after["queue"] == 0, after
        node.destroy_node()
    finally:
        rclpy.shutdown()
