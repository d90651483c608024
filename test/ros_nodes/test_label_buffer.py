"""The oracle segmentation service's label buffer (`ros_nodes.segmentation_service.LabelBuffer`), without DDS:
a request whose label image can no longer come (the label topic, in stamp order, has passed its stamp)
fails at once instead of after the whole wait (a mapper integrating in order waited 0.5 s per such
keyframe, issue 26), one still to come is waited for, and the labels come back as they were put."""

from __future__ import annotations

import threading
import time

import numpy as np

from ros_nodes.segmentation_service import LabelBuffer


def _labels(value: int) -> np.ndarray:
    out = np.full((4, 5), value, np.int32)
    out[0, 0] = 0
    return out


def test_labels_come_back_as_put_in_16_and_32_bits():
    buf = LabelBuffer(4)
    buf.put(1, _labels(7))
    buf.put(2, _labels(70_000))  # does not fit 16 bits
    buf.put(3, _labels(-1))
    for stamp, value in ((1, 7), (2, 70_000), (3, -1)):
        got = buf.wait_for(stamp, 0.0)
        assert got is not None and got.dtype == np.int32
        assert np.array_equal(got, _labels(value))


def test_a_label_image_the_topic_has_passed_fails_at_once():
    buf = LabelBuffer(2)
    for stamp in (1, 2, 3):
        buf.put(stamp, _labels(stamp))
    t0 = time.monotonic()
    assert buf.wait_for(1, 5.0) is None  # evicted: stamps 2 and 3 came after it
    assert buf.wait_for(2, 5.0) is not None
    assert time.monotonic() - t0 < 1.0


def test_a_label_image_still_to_come_is_waited_for():
    buf = LabelBuffer(2)
    buf.put(1, _labels(1))
    t0 = time.monotonic()
    assert buf.wait_for(2, 0.2) is None  # not there: waited the whole time
    assert time.monotonic() - t0 >= 0.19
    threading.Timer(0.1, buf.put, (2, _labels(2))).start()
    got = buf.wait_for(2, 5.0)
    assert got is not None and np.array_equal(got, _labels(2))
