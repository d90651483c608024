"""Pairing a depth image with the colour image nearest in stamp: the one rule the bag reader
(`bag.BagDataset.iter_pairs`) and the mapper node (`ros_nodes.image_pairing`) share."""

from __future__ import annotations

from collections import deque
from typing import Protocol, TypeVar


class Stamped(Protocol):
    @property
    def stamp(self) -> int: ...


S = TypeVar("S", bound=Stamped)


def take_nearest(waiting: deque[S], stamp_ns: int, slop_ns: int) -> tuple[S | None, int]:
    """(the waiting item nearest `stamp_ns` within `slop_ns`, taken out of `waiting`, or None; how many items
    were dropped first).

    `waiting` is in stamp order, and so are the depth images paired against it: items stamped more than
    `slop_ns` before `stamp_ns` can pair with no depth image from this one on, so they are dropped (their
    partner was lost) and counted.
    """
    dropped = 0
    while waiting and waiting[0].stamp < stamp_ns - slop_ns:
        waiting.popleft()
        dropped += 1
    best = min(waiting, key=lambda w: abs(w.stamp - stamp_ns), default=None)
    if best is None or abs(best.stamp - stamp_ns) > slop_ns:
        return None, dropped
    waiting.remove(best)
    return best, dropped
