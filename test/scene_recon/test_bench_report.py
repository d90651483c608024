"""The benchmark report: the Pareto front, the accuracy score and the files of `write_report`."""

from __future__ import annotations

import json

import pytest

from scene_recon.bench.pipeline import accuracy_score, pareto_front
from scene_recon.bench.report import write_report


def _row(label: str, total: float, pq: float, box: float = 0.5, ged: float = 0.1, pose: float | None = 0.5) -> dict:
    return {"label": label, "scene": "s", "times_s": {"total": total, "map": total / 2, "graph": 0.1,
                                                     "replace": total / 3},
            "pq": pq, "box_mAP": box, "ged_ratio": ged, "pose_success": pose, "ae_median_m": 0.01,
            "stillness": 1.0, "unchanged_rematched": 0}


def test_accuracy_score_is_the_mean_of_the_stage_figures():
    assert accuracy_score(_row("a", 1, 80.0, 0.6, 0.2, 0.4)) == pytest.approx((0.8 + 0.6 + 0.8 + 0.4) / 4, abs=1e-4)
    assert accuracy_score(_row("a", 1, 80.0, 0.6, 0.2, None)) == pytest.approx((0.8 + 0.6 + 0.8) / 3, abs=1e-4)
    assert accuracy_score(_row("a", 1, 80.0, 0.6, 1.5, 0.4)) == pytest.approx((0.8 + 0.6 + 0.0 + 0.4) / 4, abs=1e-4)


def test_pareto_front_keeps_only_undominated_runs():
    rows = [_row("fast", 5, 70), _row("mid", 10, 80), _row("slow-worse", 20, 75), _row("slow-best", 30, 90),
            _row("tie-slower", 11, 80)]
    assert pareto_front(rows) == ["fast", "mid", "slow-best"]
    assert pareto_front([_row("a", 1, 50), _row("b", 1, 50)]) == ["a", "b"]  # equal points dominate neither


def test_report_files(tmp_path):
    rows = [_row("fast", 5, 70), _row("accurate", 30, 90)]
    files = write_report(tmp_path, "quick", {"machine": {"cpus": 2}, "suite_wall_s": 12.0, "sections": [
        {"title": "Presets", "text": "t", "rows": rows, "lines": ["fast is 6x faster"], "plots": []}]})
    md = files["markdown"].read_text()
    assert "| fast | s | 5.0 |" in md and "fast is 6x faster" in md and "## Presets" in md
    html = files["html"].read_text()
    assert html.count("<tr>") == 3 and "<td>accurate</td>" in html
    data = json.loads(files["json"].read_text())
    assert data["suite"] == "quick" and data["sections"][0]["rows"][1]["pq"] == 90
