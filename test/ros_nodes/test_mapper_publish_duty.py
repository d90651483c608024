"""The mapper node publishes less while frames wait (`MapperNode.PUBLISH_DUTY_BEHIND`, and at most every
`publish_behind_period_s` counted from falling behind): each publication also makes the contact graph and the
CAD replacer rebuild on the same cores, so a mapper that is behind a camera spends its time integrating; with
the queue short it publishes at its normal duty."""

from __future__ import annotations

import threading
import time

from ros_nodes import mapper_node


class _Extracted(Exception):
    """Raised where `_publish` would extract entities: it got past its duty-cycle wait."""


class _Mapper:
    def entities(self, with_meshes: bool = True) -> list:
        raise _Extracted


class _Stub:
    """What `_publish` reads of the node before it extracts entities."""

    PUBLISH_DUTY = mapper_node.MapperNode.PUBLISH_DUTY
    PUBLISH_DUTY_BEHIND = mapper_node.MapperNode.PUBLISH_DUTY_BEHIND
    BEHIND_FRAMES = mapper_node.MapperNode.BEHIND_FRAMES

    def __init__(self, queued: int, since_last: float, last_cost: float, behind_for: float | None = None,
                 behind_period: float = 20.0) -> None:
        self._changed, self._services_waiting = True, False
        self._last_publish = (time.monotonic() - since_last, last_cost)
        self.lock, self.mapper, self.queued = threading.Lock(), _Mapper(), queued
        self._behind_since = None if behind_for is None else time.monotonic() - behind_for
        self.publish_behind_period_s = behind_period
        self._window: list | None = None  # the gravity window mapped while read (None: closed)

    def _queued(self) -> int:
        return self.queued


def _extracts(stub: _Stub) -> bool:
    try:
        mapper_node.MapperNode._publish(stub)  # type: ignore[arg-type]
    except _Extracted:
        return True
    return False


def test_a_short_queue_publishes_at_the_normal_duty() -> None:
    # last publication took 0.2 s and started 1 s ago: 0.2 / 0.3 = 0.67 s have passed
    assert _extracts(_Stub(queued=0, since_last=1.0, last_cost=0.2))
    assert _extracts(_Stub(queued=_Stub.BEHIND_FRAMES - 1, since_last=1.0, last_cost=0.2))


def test_nothing_is_published_while_the_gravity_check_reads_mapped_frames() -> None:
    """Frames mapped while the gravity check reads them may be mapped again in another frame at its verdict
    (`MapperNode._close_window`): consumers get the map after it."""
    stub = _Stub(queued=0, since_last=10.0, last_cost=0.1)
    stub._window = ["a frame"]
    assert not _extracts(stub)
    stub._window = []  # open, nothing mapped yet (nothing to publish either way)
    assert _extracts(stub)
    stub._window, stub._changed = None, True  # (the extraction above took the change)
    assert _extracts(stub)


def test_a_mapper_behind_the_camera_waits_longer_between_publications() -> None:
    behind = _Stub.BEHIND_FRAMES
    # without the period: the duty, 0.2 / 0.05 = 4 s
    assert not _extracts(_Stub(queued=behind, since_last=1.0, last_cost=0.2, behind_period=0.0))
    assert _extracts(_Stub(queued=behind, since_last=4.5, last_cost=0.2, behind_for=10.0, behind_period=0.0))
    assert not _extracts(_Stub(queued=0, since_last=0.3, last_cost=0.2))        # under 0.67 s even when idle


def test_a_mapper_behind_publishes_when_caught_up_or_after_the_period() -> None:
    behind = _Stub.BEHIND_FRAMES
    # fell behind 5 s ago, last publication long before: waits for the period from falling behind
    assert not _extracts(_Stub(queued=behind, since_last=60.0, last_cost=0.2, behind_for=5.0))
    assert _extracts(_Stub(queued=behind, since_last=60.0, last_cost=0.2, behind_for=21.0))
    # behind for long, but published 10 s ago: the period counts from that publication
    assert not _extracts(_Stub(queued=behind, since_last=10.0, last_cost=0.2, behind_for=60.0))
    # just fell behind (first look): the period starts now
    stub = _Stub(queued=behind, since_last=60.0, last_cost=0.2)
    assert not _extracts(stub) and stub._behind_since is not None
    # caught up: published at once, and no longer counted as behind
    stub.queued = behind - 1
    assert _extracts(stub) and stub._behind_since is None


def test_a_publication_under_way_counts_as_unpublished_changes() -> None:
    """`_changed` is cleared when the map is read; the message goes out after the conversions. Meanwhile the
    node must not look idle (`_publishing`, read by `status()`): a status sent in between let `scene-recon
    ros-run` export the scene of an older publication (a loaded CI run)."""
    seen: list[tuple[bool, bool]] = []

    class _Converting(_Stub):
        def __init__(self) -> None:
            super().__init__(queued=0, since_last=10.0, last_cost=0.1)
            self.mapper = self
            self.frames_integrated = 7
            self.include_meshes = False
            self.pub_entities = self
            self.pub_markers = self
            self.counters = {"publications": 0}
            self._publishing = False

        def entities(self, with_meshes: bool = True) -> list:
            return []

        def _entities_msg(self, ents, include, publishing, frames):
            seen.append((self._changed, self._publishing))  # what a status report would read now
            from builtin_interfaces.msg import Time

            class _Msg:
                class header:
                    stamp = Time(sec=3)
            return _Msg()

        def publish(self, msg) -> None:
            seen.append((self._changed, self._publishing))

        def get_subscription_count(self) -> int:
            return 0

    stub = _Converting()
    mapper_node.MapperNode._publish(stub)  # type: ignore[arg-type]
    assert seen == [(False, True), (False, True)]  # converting and publishing: still "unpublished"
    assert not stub._publishing and stub._published_stamp_ns == 3 * 10**9
