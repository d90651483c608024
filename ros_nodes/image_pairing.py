"""Colour and depth images, two topics, paired by stamp as they arrive (no ROS here: testable without DDS).

The mapper node takes the two camera topics on separate subscriptions, and under load one callback can
run seconds behind the other (two busy loops on two cores: 22 of 90 depth images waited for their colour
image longer than the 10 the node used to keep, and were dropped although every colour image came).
So an image waits for its partner until the partner can no longer arrive, not for a fixed count:

- each topic arrives in stamp order, so once a colour image stamped at or after a depth image has
  come, no closer colour image can follow; the depth image is then paired with the nearest waiting
  colour image within `slop_ns`, or counted unpaired (its colour image was lost). This is the rule of
  the offline bag reader (`panoptic_mapping.dataio.bag`, `iter_pairs`), so a played recording pairs as
  `scene-recon map` pairs it;
- colour images stamped more than `slop_ns` before the depth image being paired can pair with no later
  depth image either: they are counted unpaired (their depth image was lost);
- memory is bounded: an image that waited `max_wait_s` (wall time, a stalled callback) or beyond
  `max_waiting` images of its topic is decided with what has come (paired or counted);
- a topic whose stamps go back (a recording played again in a loop) first decides everything waiting.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Generic, TypeVar

from panoptic_mapping.dataio.pairing import take_nearest

T = TypeVar("T")


@dataclass
class _Waiting(Generic[T]):
    stamp: int
    item: T
    arrived: float


@dataclass
class PairCounts:
    """Images that found no partner (truly lost: the partner could no longer arrive or waited too long)."""

    unpaired_color: int = 0
    unpaired_depth: int = 0
    #: images decided early because the wait or the count bound was reached (a stalled callback)
    expired: int = 0


@dataclass
class ImagePairer(Generic[T]):
    """Pairs colour and depth items by stamp (ns); `add_color`/`add_depth` return the pairs completed,
    (colour, depth), in depth-stamp order. Not thread-safe: call from one callback group."""

    slop_ns: int
    #: the longest an image waits for its partner (s of wall time): a partner's callback stalled this long
    #: is taken as lost. 5 s is 150 frames of a 30 Hz camera (about 90 MB of 640x480 depth images).
    max_wait_s: float = 5.0
    #: and at most this many images of one topic wait (10 s of a 30 Hz camera)
    max_waiting: int = 300
    clock: Callable[[], float] = time.monotonic
    counts: PairCounts = field(default_factory=PairCounts)

    def __post_init__(self) -> None:
        self._colors: collections.deque[_Waiting[T]] = collections.deque()
        self._depths: collections.deque[_Waiting[T]] = collections.deque()
        self._newest_color: int | None = None
        self._newest_depth: int | None = None

    @property
    def waiting(self) -> tuple[int, int]:
        """(colour images, depth images) waiting for their partner."""
        return len(self._colors), len(self._depths)

    def add_color(self, stamp_ns: int, item: T) -> list[tuple[T, T]]:
        out: list[tuple[T, T]] = []
        if self._newest_color is not None and stamp_ns < self._newest_color:
            out += self.flush()  # the stream went back in time: nothing waiting can pair any more
        self._newest_color = stamp_ns
        self._colors.append(_Waiting(stamp_ns, item, self.clock()))
        out += self._settle()
        return out

    def add_depth(self, stamp_ns: int, item: T) -> list[tuple[T, T]]:
        out: list[tuple[T, T]] = []
        if self._newest_depth is not None and stamp_ns < self._newest_depth:
            out += self.flush()
        self._newest_depth = stamp_ns
        self._depths.append(_Waiting(stamp_ns, item, self.clock()))
        out += self._settle()
        return out

    def flush(self) -> list[tuple[T, T]]:
        """Decide everything waiting with what has come (pairs returned, the rest counted)."""
        out = self._settle(force=True)
        self.counts.unpaired_color += len(self._colors)
        self._colors.clear()
        self._newest_color = self._newest_depth = None
        return out

    def _settle(self, force: bool = False) -> list[tuple[T, T]]:
        out: list[tuple[T, T]] = []
        now = self.clock()
        while self._depths:
            d = self._depths[0]
            decided = self._newest_color is not None and self._newest_color >= d.stamp
            if not (decided or force):
                if now - d.arrived < self.max_wait_s and len(self._depths) <= self.max_waiting:
                    break  # a closer colour image may still come
                self.counts.expired += 1
            self._depths.popleft()
            pair = self._pair(d)
            if pair is None:
                self.counts.unpaired_depth += 1
            else:
                out.append(pair)
        # colour images no depth image still to pair can take (the oldest waiting one, or, none waiting, any
        # later than the newest received: depth arrives in order), or waiting too long
        oldest = self._depths[0].stamp if self._depths else self._newest_depth
        while self._colors:
            c = self._colors[0]
            if oldest is None or c.stamp >= oldest - self.slop_ns:
                if now - c.arrived < self.max_wait_s and len(self._colors) <= self.max_waiting:
                    break
                self.counts.expired += 1
            self._colors.popleft()
            self.counts.unpaired_color += 1
        return out

    def _pair(self, d: _Waiting[T]) -> tuple[T, T] | None:
        """The depth image `d` with the nearest waiting colour image within the slop (that one is taken)."""
        best, dropped = take_nearest(self._colors, d.stamp, self.slop_ns)
        self.counts.unpaired_color += dropped  # older than any depth image from `d` on can take
        return None if best is None else (best.item, d.item)
