"""The mapper node's colour/depth pairing (`ros_nodes.image_pairing`), without DDS: an image waits until its
partner comes or can no longer come, however late the other topic's callback runs (a CI run with two busy
loops lost 22 of 90 depth images to a fixed wait of 10), and only images whose partner is truly missing
are counted unpaired."""

from __future__ import annotations

import random

from ros_nodes.image_pairing import ImagePairer

PERIOD = 33_333_333  # 30 Hz
SLOP = 20_000_000


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def _feed(pairer: ImagePairer, events: list[tuple[str, int]]) -> list[tuple]:
    out: list[tuple] = []
    for kind, stamp in events:
        add = pairer.add_color if kind == "c" else pairer.add_depth
        out += add(stamp, (kind, stamp))
    return out


def _stamps(pairs: list[tuple]) -> list[tuple[int, int]]:
    return [(c[1], d[1]) for c, d in pairs]


def test_a_colour_callback_seconds_late_loses_no_frame():
    """Depth images of 3 s (90 frames) arrive before any colour image, then the colour images: all pair."""
    stamps = [i * PERIOD for i in range(90)]
    pairer = ImagePairer(SLOP, clock=Clock())
    pairs = _feed(pairer, [("d", t) for t in stamps] + [("c", t) for t in stamps])
    assert _stamps(pairs) == [(t, t) for t in stamps]
    assert (pairer.counts.unpaired_color, pairer.counts.unpaired_depth, pairer.counts.expired) == (0, 0, 0)
    assert pairer.waiting == (0, 0)


def test_a_depth_callback_seconds_late_loses_no_frame():
    stamps = [i * PERIOD for i in range(90)]
    pairer = ImagePairer(SLOP, clock=Clock())
    pairs = _feed(pairer, [("c", t) for t in stamps] + [("d", t) for t in stamps])
    assert _stamps(pairs) == [(t, t) for t in stamps]
    assert (pairer.counts.unpaired_color, pairer.counts.unpaired_depth) == (0, 0)


def test_randomly_interleaved_delayed_streams_pair_every_frame_in_order():
    """Each topic in order, the two interleaved at random with bursts of either (stalled callbacks), the
    colour stamps a few ms off the depth stamps: every frame pairs, in depth order."""
    rng = random.Random(7)
    n = 300
    depth = [i * PERIOD for i in range(n)]
    color = [t + rng.randint(-5_000_000, 5_000_000) for t in depth]
    events, ic, idp = [], 0, 0
    while ic < n or idp < n:
        burst = rng.randint(1, 40)
        kind = rng.choice("cd")
        for _ in range(burst):
            if kind == "c" and ic < n:
                events.append(("c", color[ic]))
                ic += 1
            elif kind == "d" and idp < n:
                events.append(("d", depth[idp]))
                idp += 1
    pairer = ImagePairer(SLOP, clock=Clock())
    pairs = _feed(pairer, events) + pairer.flush()
    assert _stamps(pairs) == list(zip(color, depth, strict=True))
    assert (pairer.counts.unpaired_color, pairer.counts.unpaired_depth) == (0, 0)


def test_truly_missing_partners_are_counted_once_they_can_no_longer_come():
    stamps = [i * PERIOD for i in range(10)]
    lost_color, lost_depth = {3, 4}, {7}
    events = [("d", t) for i, t in enumerate(stamps) if i not in lost_depth]
    events += [("c", t) for i, t in enumerate(stamps) if i not in lost_color]
    pairer = ImagePairer(SLOP, clock=Clock())
    pairs = _feed(pairer, events)
    assert _stamps(pairs) == [(t, t) for i, t in enumerate(stamps) if i not in lost_color | lost_depth]
    # depth 3 and 4 were decided when colour 5 came; colour 7 when depth 8 (the next) was paired
    assert (pairer.counts.unpaired_depth, pairer.counts.unpaired_color) == (2, 1)
    assert pairer.waiting == (0, 0)


def test_a_depth_image_waits_for_a_closer_colour_image_like_the_bag_reader():
    """A colour image 15 ms before the depth image is within the slop, but one at the same stamp may follow:
    the depth image waits for the next colour image and takes the nearest (what `scene-recon map` pairs)."""
    pairer = ImagePairer(SLOP, clock=Clock())
    assert pairer.add_color(985_000_000, "early") == []
    assert pairer.add_depth(1_000_000_000, "depth") == []
    assert pairer.add_color(1_000_000_000, "exact") == [("exact", "depth")]
    assert pairer.counts.unpaired_color == 0  # "early" can still pair with a depth image up to 1.005 s
    assert pairer.add_depth(1_033_000_000, "depth2") == []  # "early" is now too old for it and any later one
    assert pairer.counts.unpaired_color == 1


def test_waiting_is_bounded_by_time_and_count():
    clock = Clock()
    pairer = ImagePairer(SLOP, max_wait_s=5.0, max_waiting=50, clock=clock)
    for i in range(40):  # a dead colour topic: depth images wait ...
        clock.t = i / 30
        assert pairer.add_depth(i * PERIOD, i) == []
    assert pairer.waiting == (0, 40)
    clock.t = 6.5  # ... until they waited 5 s (all 40 arrived in the first 1.3 s)
    pairer.add_depth(40 * PERIOD, 40)
    assert pairer.counts.unpaired_depth == 40 and pairer.counts.expired == 40
    assert pairer.waiting == (0, 1)
    for i in range(41, 100):  # ... or more than max_waiting wait at once
        pairer.add_depth(i * PERIOD, i)
        assert pairer.waiting[1] <= 50
    for i in range(100):  # the same for colour images of a dead depth topic
        pairer.add_color(i * PERIOD + 7 * 10**9, i)
        assert pairer.waiting[0] <= 50


def test_a_recording_played_again_starts_pairing_afresh():
    """Stamps that go back (a bag played in a loop) do not leave the newer images of the first pass waiting."""
    pairer = ImagePairer(SLOP, clock=Clock())
    first = _feed(pairer, [("c", 0), ("d", 0), ("c", PERIOD), ("d", PERIOD), ("c", 2 * PERIOD)])
    assert _stamps(first) == [(0, 0), (PERIOD, PERIOD)]
    again = _feed(pairer, [("d", 0), ("c", 0)])
    assert _stamps(again) == [(0, 0)]
    assert pairer.counts.unpaired_color == 1 and pairer.waiting == (0, 0)
