"""Pose-success criteria per object and their per-class counts (scene_recon.evaluation.cad_metrics)."""

from __future__ import annotations

import math

import pytest

from scene_recon.evaluation.cad_metrics import (
    SIZE_TOL,
    TRANSLATION_TOL,
    YAW_TOL_DEG,
    ObjectEval,
    failed_criteria,
    failures_by_class,
)


def _eval(class_name: str, t: float, yaw: float, size: float, chosen: str = "procedural/x/x_s0000") -> ObjectEval:
    ok = t <= TRANSLATION_TOL and yaw <= YAW_TOL_DEG and size <= SIZE_TOL
    return ObjectEval("obj", class_name, chosen, class_name, 1, t, yaw, size, ok, None, 0.0, 0.0, 0.0,
                      True, 0, 0, 0, 0.1)


def test_each_threshold_is_named_at_its_limit_and_beyond():
    assert failed_criteria(_eval("cup", TRANSLATION_TOL, YAW_TOL_DEG, SIZE_TOL)) == []  # limits included
    assert failed_criteria(_eval("cup", 0.11, 3.0, 0.05)) == ["translation"]
    assert failed_criteria(_eval("cup", 0.01, 15.5, 0.05)) == ["yaw"]
    assert failed_criteria(_eval("cup", 0.01, 3.0, 0.16)) == ["size"]
    assert failed_criteria(_eval("table", 0.3, 63.0, 0.47)) == ["translation", "yaw", "size"]
    # no chosen model: infinite errors (and a NaN never passes a threshold)
    assert failed_criteria(_eval("book", math.inf, 180.0, math.inf, chosen="")) == ["translation", "yaw", "size"]
    assert failed_criteria(_eval("book", math.nan, 0.0, 0.0)) == ["translation"]


def test_counts_per_ground_truth_class_add_up():
    evals = [_eval("table", 0.02, 1.0, 0.05), _eval("table", 0.25, 89.0, 0.4), _eval("book", 0.01, 0.5, 0.3),
             _eval("book", 0.01, 0.5, 0.02)]
    counts = failures_by_class(evals)
    assert counts == {"book": {"objects": 2, "successes": 1, "translation": 0, "yaw": 0, "size": 1},
                      "table": {"objects": 2, "successes": 1, "translation": 1, "yaw": 1, "size": 1}}
    # the ground truth's class decides the row (a desk placed as a table counts as a desk)
    by_gt = failures_by_class(evals, ["desk", "table", "book", "book"])
    assert by_gt["desk"]["objects"] == 1 and by_gt["table"]["objects"] == 1
    with pytest.raises(ValueError, match="class names"):
        failures_by_class(evals, ["book"])
    assert failures_by_class([]) == {}
