"""The orientation the front cue names always gets a short fit (issue 22: monitors turned 180 degrees).

Box starts centre a model in the observed box whichever way it faces; when the observation reaches
beyond the object's front, the right orientation starts furthest from its surface and, ranked on start
scores alone, every short-fit slot can go to back-to-front starts of other models."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from cad_replacement.replace_object import _front_cue_fitted


def _starts(fronts: list[float]) -> list:
    """Starts sorted by score, the i-th with front cost ``fronts[i]``."""
    return [(0.01 * (i + 1), SimpleNamespace(d_front=f, name=f"s{i}"), None, np.zeros(6)) for i, f in enumerate(fronts)]


def _names(starts: list) -> list[str]:
    return [s[1].name for s in starts]


def test_the_cue_orientation_takes_the_last_slot_when_no_start_of_it_holds_one():
    starts = _starts([1.0, 1.0, 1.0, 1.0, 0.0, 0.0])
    out = _front_cue_fitted(starts, slots=3)
    assert _names(out)[:3] == ["s0", "s1", "s4"]  # the best start the cue names, in the last slot
    assert sorted(_names(out)) == sorted(_names(starts))  # nothing lost, nothing added


def test_nothing_moves_when_a_cue_start_already_holds_a_slot():
    starts = _starts([1.0, 0.0, 1.0, 1.0, 0.0])
    assert _names(_front_cue_fitted(starts, slots=3)) == _names(starts)


def test_nothing_moves_without_a_cue():
    starts = _starts([0.0] * 6)  # no front hint: every front cost is 0
    assert _names(_front_cue_fitted(starts, slots=2)) == _names(starts)
    assert _names(_front_cue_fitted(_starts([1.0, 0.0]), slots=4)) == ["s0", "s1"]  # every start is fitted anyway
