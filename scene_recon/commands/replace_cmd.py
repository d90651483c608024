"""`scene-recon replace GRAPH_DIR`: CAD replacement (stage 4) -> an interactive scene folder."""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import logging
import math
import os
import threading
import time
from pathlib import Path
from typing import Any

from scene_recon.commands.common import add_preset_option, preset_from_args, print_json

log = logging.getLogger(__name__)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "replace",
        help="replace the objects of a contact graph by CAD models: URDF scene for planners and simulators",
        description="Read GRAPH_DIR (written by `scene-recon graph`: contact_graph.json + nodes/), match and align "
        "a CAD model to every object (paper Sec. 4.2-4.3: matching Eqs. 7-10, alignment Eqs. 11-14, articulation "
        "state), check the scene physically (Sec. 4.4) and write an interactive scene folder: scene.urdf (root "
        "`map`, fixed/floating/revolute/prismatic joints), scene.xml (MuJoCo), scene.glb, joint_states.json, "
        "meshes/ and replacement.json "
        "(per object: candidates with matching and alignment errors, the choice, pose, scale, joint values, "
        "timings).",
    )
    p.add_argument("graph", help="folder written by `scene-recon graph` (contact_graph.json + nodes/)")
    p.add_argument("--out", required=True, help="output scene folder")
    p.add_argument("--method", choices=("ours", "paper"), default="ours",
                   help="ours (gravity-restricted, coarse-to-fine) or the paper's method (all 24 orientations, "
                   "dense LM) for comparison (default: ours)")
    p.add_argument("--seeds-per-class", type=int, default=10, metavar="N",
                   help="procedural CAD models per class (articulated classes and shelves: 2x; default: 10)")
    p.add_argument("--cad-dir", metavar="DIR",
                   help="folder of imported CAD assets (<class>/<model>/ with a URDF) added to the library")
    p.add_argument("--no-picture", action="store_true",
                   help="do not draw before_after.png (the observed node meshes beside the replaced scene; it is "
                   "drawn while the export writes, but adds 1-2 s)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_preset_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # What a user waits for, in order: the fork server starts first (it imports the CAD code, 1.5-2 s,
    # while this process imports its own and reads the graph), unless a previous run of this very input
    # left every result in the store (then no worker is needed: the fits are read back).
    from cad_replacement.replace_config import CadReplacementConfig
    from cad_replacement.result_store import default_store_dir
    from cad_replacement.workers import prestart_fork_server, resolve_workers, skip_scipy_docstring_notes
    from recon_core.config import build_config, preset_overrides
    from recon_core.errors import InputError

    graph_dir = Path(args.graph)
    graph_file = graph_dir / "contact_graph.json" if graph_dir.is_dir() else graph_dir
    if not graph_file.is_file():
        raise InputError(f"{graph_file} not found: run `scene-recon graph SOURCE --out {graph_dir}` first")
    nodes_dir = graph_file.parent / "nodes"
    if not (nodes_dir / "entities.json").is_file():
        raise InputError(f"{nodes_dir}/entities.json not found: re-run `scene-recon graph` (it writes the node "
                         "geometry CAD replacement aligns to)")
    cad_cfg = build_config(CadReplacementConfig, {},
                           preset_overrides(preset_from_args(args), "cad", {"method": args.method}))
    n_workers = resolve_workers(cad_cfg.workers)
    marker = default_store_dir() / "inputs" / _input_fingerprint(graph_file, nodes_dir, cad_cfg, args)
    if n_workers > 1 and not marker.is_file():
        prestart_fork_server()
    skip_scipy_docstring_notes()  # SciPy's import-time docstring rewriting (0.1-0.3 s): help text only
    from recon_core.lazy_import import import_geometry_libraries

    import_geometry_libraries()  # Open3D without Dash and Plotly (0.4 s), trimesh without networkx (0.15 s)
    from cad_replacement.cad.library import CadLibrary
    from cad_replacement.physical_check import PhysicalCheck
    from cad_replacement.replacer import CadReplacer
    from cad_replacement.workers import ReplaceWorkers
    from recon_core.contact_graph import ContactGraph
    from recon_core.entity import load_entities

    phases = {"imports": _since_start()}
    graph = ContactGraph.load(graph_file)
    entities = {e.id: e for e in load_entities(nodes_dir)}
    library = CadLibrary(root=args.cad_dir, seeds_per_class=args.seeds_per_class)
    phases["input"] = _since_start()
    check = PhysicalCheck(method=args.method)
    # results stored by earlier runs (same observation, settings, library and code) are read back
    workers = ReplaceWorkers(library, n_workers, store="library") if n_workers > 1 else None
    t0 = time.perf_counter()
    try:
        with CadReplacer(library, cad_cfg, physical_check=check, workers=workers) as replacer:
            result = replacer.replace(graph, entities)
    finally:
        if workers is not None:
            workers.close()
    if workers is not None and workers.store is not None and not workers.failed:
        _write_marker(marker)
    phases["replaced"] = _since_start()
    from cad_replacement.export import export_scene
    from cad_replacement.scene_model import scene_record
    from recon_core.io import write_text_atomic

    out = Path(args.out)
    # the picture is drawn (numpy and Open3D ray casting, mostly outside the interpreter lock) while the
    # URDF, MJCF and meshes are written: it needs scene.glb only, which the export writes first
    picture_job = _PictureJob(graph, entities, out)
    # the replacer's class table (the same default file): loading its YAML again cost 0.1-0.3 s
    exported = export_scene(result.scene, out, class_table=replacer.class_table,
                            on_glb=None if args.no_picture else picture_job.start)
    urdf = exported.urdf
    phases["exported"] = _since_start()
    physics = check.last_report
    summary = {"scene": result.scene.name, "method": args.method, "objects": len(result.scene),
               "rematched": result.rematched, "timings": result.timings,
               "physical_check": {"pairs_tested": physics.pairs_tested, "pairs_total": physics.pairs_total,
                                  "conflicts_before": len(physics.conflicts_before),
                                  "conflicts_after": len(physics.conflicts_after), "switches": physics.switches,
                                  "max_penetration_after_m": physics.max_penetration_after},
               "wall_s": time.perf_counter() - t0, "urdf": str(urdf)}
    if graph.stats.get("scene"):  # the generated scene behind the graph (eval-scene checks its ground truth)
        summary["scene_identity"] = graph.stats["scene"]
    cad = [r for r in result.records if r.kind == "cad"]
    if not cad and not any(r.kind == "observed_mesh" for r in result.records):
        raise InputError(f"no object of {graph_file} could be replaced: the graph has no object nodes with "
                         "geometry (check `scene-recon graph` output and its nodes/ folder)")
    graph.save(out / "contact_graph.json")  # the input, so the folder can be scored on its own
    picture = picture_job.result()
    phases["picture"] = _since_start()
    # when each phase ended, seconds since the process started (None where that is unknown)
    summary["phases_s"] = phases
    write_text_atomic(out / "replacement.json", json.dumps(
        {**summary, "objects_detail": [r.to_dict() for r in result.records],
         "scene": scene_record(result.scene)}, indent=1))
    if args.json:
        print_json(summary)
        return 0
    print(f"{'object':20s} {'class':10s} {'kind':14s} {'CAD model':34s} {'AE mm':>6s}  why")
    for r in result.records:
        ae = next((c["alignment_error"] for c in r.candidates if c["cad_id"] == r.cad_id), None)
        ae_txt = f"{1000 * ae:6.1f}" if ae is not None and math.isfinite(ae) else "     -"
        # the stage-4 gate's word: why an object stays its observed mesh, or which class it replaced
        why = r.reason or ""
        if r.substituted_from:
            why = f"replaces detected class {r.substituted_from} (clearly better fit) {why}".strip()
        print(f"{r.name[:20]:20s} {r.class_name[:10]:10s} {r.kind:14s} {r.cad_id[:34]:34s} {ae_txt}  {why}")
    fallbacks = [r for r in result.records if r.kind == "observed_mesh" and r.candidates]
    swapped = [r for r in result.records if r.substituted_from]
    if fallbacks or swapped:
        print(f"{len(fallbacks)} object(s) kept as their observed mesh (no model explains them), "
              f"{len(swapped)} replaced by another class")
    print(f"{len(result.scene)} objects in {summary['wall_s']:.2f} s ({result.rematched} matched); wrote {urdf}, "
          f"{exported.mjcf.name}, {exported.joint_states.name}, replacement.json"
          + (f", {exported.glb.name}" if exported.glb else "") + (f", {picture.name}" if picture else ""))
    return 0


def _since_start() -> float | None:
    """Seconds since this process started (Linux: its start time in /proc), or ``None``."""
    try:
        start_ticks = int(Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()[19])
        return time.clock_gettime(time.CLOCK_BOOTTIME) - start_ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError, AttributeError):
        return None


def _input_fingerprint(graph_file: Path, nodes_dir: Path, config: Any, args: argparse.Namespace) -> str:
    """Names this input (graph and node files, settings, library options, code): a run that finds its marker
    expects the result store to answer and starts no fork server up front (a guess, never a result)."""
    from cad_replacement.result_store import code_digest

    h = hashlib.sha256(repr((code_digest(), config, args.method, args.seeds_per_class, args.cad_dir)).encode())
    for path in (graph_file, nodes_dir / "entities.json"):
        h.update(path.read_bytes())
    for path in sorted(nodes_dir.rglob("*")):
        if path.is_file():
            st = path.stat()
            h.update(f"{path.relative_to(nodes_dir)}\0{st.st_size}\0{st.st_mtime_ns}\0".encode())
    return h.hexdigest()


def _write_marker(marker: Path) -> None:
    with contextlib.suppress(OSError):  # a hint for the next run only
        marker.parent.mkdir(parents=True, exist_ok=True)
        marker.touch()


class _PictureJob:
    """``_before_after`` in a thread, started when scene.glb is written; ``result`` waits for it."""

    def __init__(self, graph: Any, entities: dict[int, Any], out: Path) -> None:
        self._args = (graph, entities, out)
        self._thread: threading.Thread | None = None
        self._path: Path | None = None
        self._error: BaseException | None = None

    def _run(self) -> None:
        try:
            self._path = _before_after(*self._args)
        except BaseException as exc:  # handed to the caller by ``result``
            self._error = exc

    def start(self, _glb: Path | None = None) -> None:
        self._thread = threading.Thread(target=self._run, name="before-after-picture", daemon=True)
        self._thread.start()

    def result(self) -> Path | None:
        if self._thread is None:  # no scene.glb was written: nothing to draw
            return None
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self._path


def _before_after(graph: Any, entities: dict[int, Any], out: Path) -> Path | None:
    """``before_after.png``: the observed node meshes beside the replaced scene (same camera)."""
    from scene_recon.synthetic.overview import render_scene_picture

    if not (out / "scene.glb").is_file():
        return None
    before = {graph.nodes[i].name: e.mesh() for i, e in entities.items() if i in graph.nodes and len(e.faces)}
    try:
        return render_scene_picture(out, out / "before_after.png", before)
    except (ValueError, OSError) as exc:  # a picture is a convenience: never fail the scene for it
        log.warning("no before/after picture: %s", exc)
        return None
