"""The 7-Scenes kitchen with a stock YOLOX-Nano: get the inputs, run the pipeline, measure the replaced scene.

Nothing of the data or the weights is in this repository (docs/REAL_DATA.md says where they come from
and under which terms). Three steps, each usable on its own:

``fetch``   extract the frames and the model from git snapshots of their public repositories (any git
            directory of ``andyzeng/tsdf-fusion-python`` and ``Bigisland1729/object-detection-models``,
            e.g. a clone): ``DEST/tsdf-fusion-python/data/`` and ``DEST/models/yolox_nano.onnx``.
``run``     ``scene-recon run DATA --out OUT --model MODEL --stride N`` (map, graph, replace).
``measure`` ground-truth-free figures of one or more replaced scene folders (``scene-recon replace``
            output): per object what stands for it (CAD model, or observed mesh and why), the paper's AE
            (observed -> CAD RMS, Sec. 4.3) and the two-sided AE of each CAD-replaced object, their
            median and maximum, substitutions across classes, and the stillness of the movable objects
            in PyBullet and MuJoCo over 2 s (``scene_recon.evaluation.physics``), and the support patches
            the graph derived from observed, undetected surfaces (``scene_graph/surfaces.py``).

    PY=.venv/bin/python; R=/work/realdata
    $PY tools/real_data/real_kitchen.py fetch --tsdf-git GIT_DIR --models-git GIT_DIR --dest $R
    $PY tools/real_data/real_kitchen.py run --data $R/tsdf-fusion-python/data --model $R/models/yolox_nano.onnx \\
        --out $R/out/run_s5 --stride 5
    $PY tools/real_data/real_kitchen.py measure $R/out/run_s5/scene [--json FILE] \\
        [--picture docs/img/real_kitchen_scene.png]

Scene folders of older code without fit figures in replacement.json are measured from the AE of the
chosen candidate (two-sided only).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))


def fetch(tsdf_git: Path, models_git: Path, dest: Path) -> None:
    """Extract ``data/`` and ``yolox_nano.onnx`` from the two git directories (bare or not) into ``dest``."""
    frames = dest / "tsdf-fusion-python"
    frames.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(["git", f"--git-dir={tsdf_git}", "archive", "HEAD", "data"], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(frames)], input=archive, check=True)
    models = dest / "models"
    models.mkdir(parents=True, exist_ok=True)
    blob = subprocess.run(["git", f"--git-dir={models_git}", "show", "HEAD:yolox_nano.onnx"], check=True,
                          capture_output=True).stdout
    (models / "yolox_nano.onnx").write_bytes(blob)
    print(f"frames: {frames / 'data'} ({len(list((frames / 'data').glob('*.depth.png')))} depth images); "
          f"model: {models / 'yolox_nano.onnx'} ({len(blob)} bytes)")


def run(data: Path, model: Path, out: Path, stride: int) -> int:
    cmd = [sys.executable, "-m", "scene_recon.cli", "run", str(data), "--out", str(out), "--model", str(model),
           "--stride", str(stride)]
    print("$", " ".join(cmd), flush=True)
    return subprocess.call(cmd, cwd=ROOT)


def _chosen_fit(rec: dict[str, Any]) -> dict[str, Any]:
    """The fit figures of the exported model of one record (new records carry them, older ones only the
    chosen candidate's two-sided AE)."""
    fit = dict(rec.get("fit") or {})
    if not fit:
        cand = next((c for c in rec.get("candidates", []) if c.get("cad_id") == rec.get("cad_id")), None)
        if cand is not None:
            fit = {"ae": cand.get("alignment_error"), "ae_points": cand.get("ae_points")}
    return fit


def measure(folder: Path, physics: bool = True) -> dict[str, Any]:
    """Ground-truth-free figures of one replaced scene folder."""
    rep = json.loads((folder / "replacement.json").read_text())
    scene = {o["name"]: o for o in rep["scene"]["objects"]}
    rows = []
    for rec in rep["objects_detail"]:
        if rec["kind"] == "layout":
            continue
        obj = scene.get(rec["name"], {})
        fit = _chosen_fit(rec)
        rows.append({"name": rec["name"], "class": rec["class_name"], "kind": rec["kind"],
                     "cad_id": obj.get("cad_id", rec.get("cad_id", "")), "class_exported": obj.get("class_name"),
                     "movable": obj.get("movable"), "ae_points": fit.get("ae_points"), "ae": fit.get("ae"),
                     "ae_limit": fit.get("ae_limit"), "view_coverage": fit.get("view_coverage"),
                     "reason": rec.get("reason") or (rec.get("message") if rec["kind"] != "cad" else ""),
                     "substituted_from": rec.get("substituted_from") or (
                         rec["class_name"] if obj.get("class_name") not in (None, rec["class_name"]) else "")})
    cad = [r for r in rows if r["kind"] == "cad"]
    ae = [r["ae_points"] if r["ae_points"] is not None else r["ae"] for r in cad]
    ae = [float(v) for v in ae if v is not None]
    two = [float(r["ae"]) for r in cad if r["ae"] is not None]
    out: dict[str, Any] = {
        "folder": str(folder), "objects": len(rows), "cad": len(cad),
        "observed_mesh": sum(1 for r in rows if r["kind"] == "observed_mesh"),
        "fallbacks": [{"name": r["name"], "reason": r["reason"]} for r in rows if r["kind"] == "observed_mesh"],
        "substitutions": [f"{r['name']}: {r['substituted_from']} -> {r['class_exported']}" for r in rows
                          if r["substituted_from"]],
        "ae_median_m": float(np.median(ae)) if ae else None, "ae_max_m": max(ae) if ae else None,
        "ae_over_5cm": sum(1 for v in ae if v > 0.05),
        "ae_two_sided_median_m": float(np.median(two)) if two else None,
        "ae_two_sided_max_m": max(two) if two else None,
        "max_penetration_after_m": rep.get("physical_check", {}).get("max_penetration_after_m"),
        "surface_patches": surface_patches(folder),
        "per_object": rows,
    }
    if physics:
        from scene_recon.evaluation.physics import check_mujoco, check_pybullet

        out["physics"] = {"pybullet": check_pybullet(folder).to_dict(), "mujoco": check_mujoco(folder).to_dict()}
    return out


def surface_patches(folder: Path) -> dict[str, dict[str, Any]]:
    """The support patches the contact graph derived from observed, undetected surfaces
    (``scene_graph/surfaces.py``): carried object name -> patch node name, surface height, evidence areas."""
    path = folder / "contact_graph.json"
    if not path.is_file():
        return {}
    graph = json.loads(path.read_text())
    names = {int(n["id"]): n.get("name", str(n["id"])) for n in graph.get("nodes", [])}
    out = {}
    for child, p in (graph.get("stats", {}).get("surface_patches") or {}).items():
        out[names.get(int(child), child)] = {"patch": names.get(int(p["id"]), str(p["id"])), "height_m": p["height"],
                                             "area_unlabelled_m2": p["area_unlabelled_m2"],
                                             "area_own_m2": p["area_own_m2"]}
    return out


def picture(scene_folder: Path, dest: Path, max_bytes: int = 500_000) -> None:
    """A scene folder's before_after.png (map entities | replaced scene), shrunk until under ``max_bytes``."""
    from PIL import Image

    img = Image.open(scene_folder / "before_after.png").convert("RGB")
    dest.parent.mkdir(parents=True, exist_ok=True)
    width = img.width
    while True:
        im = img if width == img.width else img.resize((width, round(img.height * width / img.width)), Image.LANCZOS)
        im.quantize(colors=128, method=Image.Quantize.MEDIANCUT).save(dest, optimize=True)
        if dest.stat().st_size <= max_bytes or width < 400:
            break
        width = int(width * 0.8)
    print(f"{dest}: {im.width}x{im.height}, {dest.stat().st_size} bytes")


def _print(m: dict[str, Any]) -> None:
    mm = lambda v: "-" if v is None else f"{1000 * v:.1f}"  # noqa: E731
    print(f"== {m['folder']}: {m['objects']} objects, {m['cad']} CAD, {m['observed_mesh']} observed meshes")
    for r in m["per_object"]:
        what = r["cad_id"] if r["kind"] == "cad" else f"observed mesh: {r['reason']}"
        print(f"  {r['name']:14s} {r['class']:10s} AE {mm(r['ae_points']):>6s} mm (two-sided {mm(r['ae']):>6s}) "
              f"{'movable' if r['movable'] else '       '} {what}")
    print(f"  CAD-replaced AE: median {mm(m['ae_median_m'])} mm, max {mm(m['ae_max_m'])} mm, "
          f"{m['ae_over_5cm']} over 5 cm (two-sided: median {mm(m['ae_two_sided_median_m'])}, max "
          f"{mm(m['ae_two_sided_max_m'])} mm); substitutions: {m['substitutions'] or 'none'}")
    for child, p in (m.get("surface_patches") or {}).items():
        print(f"  {child} stands on {p['patch']} (observed surface at z = {p['height_m']} m; upward faces "
              f"{1e4 * p['area_unlabelled_m2']:.0f} cm^2 unlabelled, {1e4 * p['area_own_m2']:.0f} cm^2 its own)")
    for engine, p in m.get("physics", {}).items():
        n = len(p["displacement"])
        still = n - len(p["moved"])
        print(f"  {engine}: loaded {p['loaded']}, {still}/{n} movable objects still (moved: {p['moved']})")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    f = sub.add_parser("fetch")
    f.add_argument("--tsdf-git", type=Path, required=True)
    f.add_argument("--models-git", type=Path, required=True)
    f.add_argument("--dest", type=Path, required=True)
    r = sub.add_parser("run")
    r.add_argument("--data", type=Path, required=True)
    r.add_argument("--model", type=Path, required=True)
    r.add_argument("--out", type=Path, required=True)
    r.add_argument("--stride", type=int, default=5)
    m = sub.add_parser("measure")
    m.add_argument("folders", type=Path, nargs="+")
    m.add_argument("--no-physics", action="store_true")
    m.add_argument("--json", type=Path, help="write the figures here")
    m.add_argument("--picture", type=Path, help="copy the first folder's before_after.png here (< 500 KB)")
    args = p.parse_args(argv)
    if args.cmd == "fetch":
        fetch(args.tsdf_git, args.models_git, args.dest)
        return 0
    if args.cmd == "run":
        return run(args.data, args.model, args.out, args.stride)
    results = [measure(folder, physics=not args.no_physics) for folder in args.folders]
    for res in results:
        _print(res)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1, allow_nan=False))
    if args.picture:
        picture(args.folders[0], args.picture)
    return 0


if __name__ == "__main__":
    sys.exit(main())
