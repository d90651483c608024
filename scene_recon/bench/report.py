"""The benchmark report: results.json, plots (matplotlib), report.md and report.html in one folder."""

from __future__ import annotations

import html
import json
import time
from pathlib import Path
from typing import Any

from scene_recon.bench.pipeline import accuracy_score, pareto_front

#: Columns of the end-to-end tables: (header, row -> text).
_COLUMNS: list[tuple[str, Any]] = [
    ("run", lambda r: r["label"]),
    ("scene", lambda r: r.get("scene", "")),
    ("total s", lambda r: f"{r['times_s']['total']:.1f}"),
    ("total CPU s", lambda r: f"{r['cpu_s']['total']:.1f}" if "cpu_s" in r else "-"),
    ("map s", lambda r: f"{r['times_s']['map']:.1f}"),
    ("graph s", lambda r: f"{r['times_s']['graph']:.2f}"),
    ("replace s", lambda r: f"{r['times_s']['replace']:.1f}"),
    ("PQ", lambda r: f"{r['pq']:.1f}"),
    ("box mAP", lambda r: f"{100 * r['box_mAP']:.0f}"),
    ("GED %", lambda r: f"{100 * r['ged_ratio']:.1f}"),
    ("pose success %", lambda r: "-" if r.get("pose_success") is None else f"{100 * r['pose_success']:.0f}"),
    ("AE med mm", lambda r: "-" if r.get("ae_median_m") is None else f"{1000 * r['ae_median_m']:.1f}"),
    ("still %", lambda r: "-" if r.get("stillness") is None else f"{100 * r['stillness']:.0f}"),
    ("score", lambda r: f"{accuracy_score(r):.3f}"),
    ("CAD re-matched, unchanged scene", lambda r: str(r.get("unchanged_rematched", "-"))),
    ("shared", lambda r: r.get("shared") or "-"),
]


def _table_md(rows: list[dict[str, Any]]) -> str:
    head = "| " + " | ".join(h for h, _ in _COLUMNS) + " |"
    sep = "|" + "|".join("---" for _ in _COLUMNS) + "|"
    return "\n".join([head, sep, *("| " + " | ".join(f(r) for _, f in _COLUMNS) + " |" for r in rows)])


def _table_html(rows: list[dict[str, Any]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h, _ in _COLUMNS)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(f(r))}</td>" for _, f in _COLUMNS) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def plot_pareto(rows: list[dict[str, Any]], path: Path, title: str, time_key: str = "total",
                cpu: bool = False) -> Path | None:
    """Accuracy score against (wall or CPU) time, the Pareto front drawn; None when matplotlib is missing."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    times = "cpu_s" if cpu else "times_s"
    front = set(pareto_front(rows, time_key, cpu=cpu))
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for r in rows:
        t, a = r[times][time_key], accuracy_score(r)
        ax.scatter(t, a, s=60 if r["label"] in front else 30,
                   marker="o" if r.get("method", "ours") == "ours" and r.get("mode", "full") == "full" else "s",
                   color="tab:red" if r["label"] in front else "tab:blue")
        ax.annotate(r["label"], (t, a), textcoords="offset points", xytext=(4, 4), fontsize=7)
    pts = sorted((r[times][time_key], accuracy_score(r)) for r in rows if r["label"] in front)
    if len(pts) > 1:
        ax.plot(*zip(*pts, strict=True), color="tab:red", lw=1, alpha=0.6, label="Pareto front")
        ax.legend(fontsize=8)
    ax.set_xlabel(f"{time_key} {'CPU' if cpu else 'wall'} time (s)")
    ax.set_ylabel("accuracy score (mean of PQ, box mAP, 1-GED, pose success)")
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_series(series: dict[str, tuple[list[float], list[float]]], path: Path, title: str, xlabel: str,
                ylabel: str) -> Path | None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    fig, ax = plt.subplots(figsize=(7, 4))
    for name, (x, y) in series.items():
        ax.plot(x, y, marker="." if len(x) < 100 else None, lw=1, label=name)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    if len(series) > 1:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_report(out: Path, suite: str, results: dict[str, Any]) -> dict[str, Path]:
    """results.json, report.md and report.html (+ the plots already in `results["plots"]`)."""
    out.mkdir(parents=True, exist_ok=True)
    results = {"suite": suite, "written": time.strftime("%Y-%m-%dT%H:%M:%S"), **results}
    (out / "results.json").write_text(json.dumps(results, indent=1, default=str), encoding="utf-8")
    cpu = results.get("suite_cpu_s")
    load = (f" (load average before {results['load_avg_before']}, at the end "
            f"{results.get('machine', {}).get('load_avg')})" if results.get("load_avg_before") else "")
    md: list[str] = [f"# scene_recon benchmark: suite `{suite}`", "",
                     f"Written {results['written']} on {results.get('machine', {})}; wall time of the suite "
                     f"{results.get('suite_wall_s', 0):.0f} s"
                     + (f", CPU time {cpu:.0f} s (this process and its children)" if cpu is not None else "")
                     + f"{load}. Times are wall seconds on this machine unless marked CPU (ratios "
                     "are against runs of the same suite invocation); accuracy against the generated ground truth. "
                     "A row marked shared reused the map (and graph) of an earlier run with the same settings and "
                     "carries that run's stage times.", ""]
    body_html: list[str] = [f"<h1>scene_recon benchmark: suite <code>{html.escape(suite)}</code></h1>",
                            f"<p>{html.escape(md[2])}</p>"]
    costs = results.get("section_costs") or []
    if costs:
        md += ["| section(s) | wall s | CPU s |", "|---|---|---|"]
        md += [f"| {c['title']}{' (+' + str(c['sections'] - 1) + ' more)' if c.get('sections', 1) > 1 else ''} | "
               f"{c['wall']:.0f} | {c['cpu']:.0f} |" for c in costs]
        md.append("")
    for section in results.get("sections", []):
        md += [f"## {section['title']}", "", section.get("text", ""), ""]
        body_html += [f"<h2>{html.escape(section['title'])}</h2>", f"<p>{html.escape(section.get('text', ''))}</p>"]
        if section.get("rows"):
            md += [_table_md(section["rows"]), ""]
            body_html.append(_table_html(section["rows"]))
        for line in section.get("lines", []):
            md.append(f"- {line}")
            body_html.append(f"<p>{html.escape(line)}</p>")
        if section.get("lines"):
            md.append("")
        for plot in section.get("plots", []):
            name = Path(plot).name
            md += [f"![{name}]({name})", ""]
            body_html.append(f'<p><img src="{html.escape(name)}" alt="{html.escape(name)}"></p>')
    (out / "report.md").write_text("\n".join(md) + "\n", encoding="utf-8")
    style = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto}table{border-collapse:collapse;"
             "font-size:13px}td,th{border:1px solid #bbb;padding:3px 6px;text-align:right}"
             "td:first-child,th:first-child{text-align:left}img{max-width:100%}")
    (out / "report.html").write_text(
        f"<!doctype html><html><head><meta charset='utf-8'><title>scene_recon benchmark {html.escape(suite)}"
        f"</title><style>{style}</style></head><body>{''.join(body_html)}</body></html>\n", encoding="utf-8")
    return {"json": out / "results.json", "markdown": out / "report.md", "html": out / "report.html"}
