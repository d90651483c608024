"""`scene-recon map`: build the volumetric panoptic map of a recording."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from pathlib import Path

from scene_recon.commands.common import (
    add_data_options,
    add_preset_option,
    data_config_from_args,
    json_text,
    preset_from_args,
    print_json,
)
from scene_recon.commands.scene_identity import recording_identity


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "map",
        help="build the panoptic map of a recording (stage 2)",
        description="Segment keyframes with a 2D panoptic backend, fuse them with depth segments, integrate a "
        "labelled TSDF and extract panoptic entities (paper Sec. 3). Writes entities.json + meshes/, a resumable "
        "map (map.npz/map.json), summary.json and, when the map has surface, panoptic_map.png into --out. "
        "Exit status: 0 done; 2 error (nothing written; e.g. no frame with a pose: the message says why); "
        "3 written but empty (no entity).",
    )
    p.add_argument("source", help="bag or frame folder")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--segmenter", choices=["auto", "oracle", "onnx", "none"], default="auto",
                   help="2D panoptic backend; auto (default): onnx when --model/--model-config is given, else the "
                   "oracle when the recording has ground truth (a generated scene), else none (geometry only)")
    p.add_argument("--noise", default="default", help="oracle noise level: clean | default | hard")
    p.add_argument("--ground-truth", help="ground-truth folder for the oracle (default: beside the bag)")
    p.add_argument("--model", metavar="ONNX",
                   help="exported detector/segmenter (YOLOX, YOLOv5, YOLOv8/11, YOLOv8-seg, torchvision Mask/Faster "
                   "R-CNN, semantic logits); its output convention is read off the graph")
    p.add_argument("--model-config", help="ONNX model config YAML pinning what detection gets wrong "
                   "(config/segmentation/*.yaml)")
    p.add_argument("--classes", metavar="YAML", help="class table (default config/classes.yaml)")
    p.add_argument("--device", choices=["auto", "cpu", "cuda"], default="auto",
                   help="onnxruntime device (auto: CUDA when available, else CPU)")
    p.add_argument("--mode", choices=["full", "baseline"], default="full",
                   help="full = the paper's method; baseline = Voxblox++-style fusion")
    p.add_argument("--config", help="mapper config YAML (default config/mapper.yaml)")
    p.add_argument("--voxel-size", type=float, help="TSDF voxel size in metres")
    p.add_argument("--max-depth", type=float, metavar="M",
                   help="ignore depth readings beyond M metres (default tsdf.max_depth_m of config/mapper.yaml: 4.0)")
    p.add_argument("--min-depth", type=float, metavar="M",
                   help="ignore depth readings nearer than M metres (default tsdf.min_depth_m: 0.1)")
    p.add_argument("--gravity", metavar="auto|z|FILE",
                   help="up of the input's world frame (default gravity.mode of config/data.yaml: auto): auto "
                   "estimates it from the depth of the first frames (floor, walls) and rotates the poses into a "
                   "z-up map frame (left as is when within 1 deg of +z); z trusts the input; FILE: a 4x4 transform "
                   "(text) from the input's world frame to a z-up frame. The rotation is written to map.json "
                   "(gravity_alignment)")
    p.add_argument("--no-keyframes", action="store_true", help="segment every frame")
    p.add_argument("--resume", nargs="?", const="", metavar="DIR",
                   help="continue from the newest good checkpoint in DIR/checkpoints (default DIR: --out); of the "
                   "same recording: from the first frame it had not read; of another one, or a folder holding only "
                   "a saved map (map.npz/map.json): the map continues with every frame of SOURCE. A damaged newest "
                   "checkpoint is reported and the older one used")
    p.add_argument("--checkpoint-every", type=int, metavar="FRAMES",
                   help="checkpoint after this many frames (default checkpoint.every_n_frames of the mapper config: "
                   "100; 0: never by count)")
    p.add_argument("--checkpoint-every-s", type=float, metavar="S",
                   help="checkpoint after this many seconds (default checkpoint.every_s: 60; 0: never by time)")
    p.add_argument("--no-checkpoints", action="store_true",
                   help="write no periodic checkpoints (a kill -9 then loses the run); SIGINT/SIGTERM still write "
                   "one, which --resume continues")
    p.add_argument("--seed", type=int, default=0, help="oracle noise seed")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_preset_option(p)
    add_data_options(p)
    p.set_defaults(func=run)


def choose_segmenter(args: argparse.Namespace) -> tuple[str, str]:
    """The backend `--segmenter` names, `auto` resolved; and why (for the log)."""
    from scene_recon.synthetic.generate import ground_truth_path

    if args.segmenter != "auto":
        return args.segmenter, "--segmenter"
    if getattr(args, "model", None) or getattr(args, "model_config", None):
        return "onnx", "a model was given"
    if getattr(args, "ground_truth", None):
        return "oracle", "--ground-truth was given"
    if (ground_truth_path(Path(args.source)) / "scene.json").is_file():
        return "oracle", "the recording has ground truth beside it"
    return "none", "no model and no ground truth: geometry only"


def build_segmenter(args: argparse.Namespace, segmenter: str | None = None, class_table=None):
    from panoptic_mapping.segmentation.config import SegmentationConfig
    from panoptic_mapping.segmentation.factory import make_segmenter
    from scene_recon.synthetic.generate import ground_truth_path

    name = segmenter or choose_segmenter(args)[0]
    if name == "none":
        return None
    cfg = SegmentationConfig(backend=name)
    if name == "oracle":
        gt = args.ground_truth or str(ground_truth_path(Path(args.source)))
        cfg.oracle.ground_truth = gt
        cfg.oracle.level = args.noise
        cfg.oracle.seed = args.seed
    elif name == "onnx":
        model, model_config = getattr(args, "model", None), getattr(args, "model_config", None)
        if not model and not model_config:
            raise FileNotFoundError("--segmenter onnx needs --model (an exported .onnx file) or --model-config")
        cfg.onnx.model = model or ""
        cfg.onnx.model_config = model_config or ""
        cfg.onnx.device = getattr(args, "device", "auto")
    return make_segmenter(cfg, class_table=class_table)


def mapper_config_from_args(args: argparse.Namespace):
    from panoptic_mapping.config import MapperConfig
    from recon_core.config import CONFIG_DIR, load_config, preset_overrides

    overrides = preset_overrides(preset_from_args(args), "mapper", {"mode": args.mode})
    if args.voxel_size:
        overrides["tsdf.voxel_size_m"] = args.voxel_size
    if getattr(args, "max_depth", None) is not None:
        overrides["tsdf.max_depth_m"] = args.max_depth
    if getattr(args, "min_depth", None) is not None:
        overrides["tsdf.min_depth_m"] = args.min_depth
    if args.no_keyframes:
        overrides["keyframes.enabled"] = False
    if getattr(args, "checkpoint_every", None) is not None:
        overrides["checkpoint.every_n_frames"] = args.checkpoint_every
    if getattr(args, "checkpoint_every_s", None) is not None:
        overrides["checkpoint.every_s"] = args.checkpoint_every_s
    if getattr(args, "no_checkpoints", False):
        overrides["checkpoint.enabled"] = False
    path = args.config or (CONFIG_DIR / "mapper.yaml" if (CONFIG_DIR / "mapper.yaml").is_file() else None)
    return load_config(MapperConfig, path, overrides)


#: Exit status of a run that wrote its outputs but found nothing in them.
EXIT_EMPTY = 3


def resume_state(args: argparse.Namespace):
    """(checkpoint to continue, or None; map to continue with all frames, or None) of `--resume`."""
    from panoptic_mapping.checkpoint import CHECKPOINT_DIR, CheckpointStore
    from panoptic_mapping.mapper import PanopticMapper

    if args.resume is None:
        return None, None
    folder = Path(args.resume or args.out)
    store = CheckpointStore(folder / CHECKPOINT_DIR)
    if store.generations():
        ckpt = store.load_latest()  # a damaged generation is logged (warning) and skipped; none usable: error
        source = ckpt.progress.get("source")
        if source and source != str(Path(args.source).resolve()):
            print(f"checkpoint {ckpt.path} is of {source}: its map continues with every frame of {args.source}",
                  file=sys.stderr)
            return None, ckpt.mapper
        if not args.json:
            print(f"resuming from checkpoint {ckpt.path}: {ckpt.progress.get('frames_read', 0)} frames already read")
        return ckpt, None
    if (folder / "map.json").is_file() or (folder / "map.npz").is_file():
        return None, PanopticMapper.load(folder)
    raise FileNotFoundError(f"--resume: {folder} holds no checkpoint ({CHECKPOINT_DIR}/gen-*) and no saved map "
                            "(map.npz + map.json)")


class _StopOnSignal:
    """SIGINT/SIGTERM ask the command to stop after the current frame (it then checkpoints).

    Installed for the whole command, so a signal while the segmenter loads or while the finished map is
    written is honoured too (no KeyboardInterrupt half-way through writing). A second SIGINT stops at
    once (KeyboardInterrupt: exit 130; the checkpoints written so far stay)."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self._old: dict[int, object] = {}

    def __call__(self) -> bool:
        return self.signum is not None

    @property
    def name(self) -> str:
        return signal.Signals(self.signum or signal.SIGINT).name

    @property
    def exit_code(self) -> int:
        return 128 + int(self.signum or signal.SIGINT)

    def _handle(self, signum: int, _frame: object) -> None:
        if self.signum is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt  # asked twice: stop now
        if self.signum is None:
            print(f"\n{signal.Signals(signum).name}: stopping after this frame (checkpoint first; SIGINT again to "
                  "stop at once)", file=sys.stderr)
        self.signum = signum

    def __enter__(self) -> _StopOnSignal:
        if threading.current_thread() is threading.main_thread():
            self._old = {s: signal.signal(s, self._handle) for s in (signal.SIGINT, signal.SIGTERM)}
        return self

    def __exit__(self, *_exc: object) -> None:
        for s, old in self._old.items():
            signal.signal(s, old)  # type: ignore[arg-type]


def make_checkpointer(config, out: str | Path):
    """The run's Checkpointer: periodic as configured; with checkpoints disabled, one that writes only
    the checkpoint of a stop (SIGINT/SIGTERM), so an interrupted run never loses its frames."""
    from dataclasses import replace

    from panoptic_mapping.checkpoint import CHECKPOINT_DIR, Checkpointer, CheckpointStore

    store = CheckpointStore(Path(out) / CHECKPOINT_DIR, keep=config.checkpoint.keep)
    if config.checkpoint.enabled:
        return Checkpointer(store, config.checkpoint)
    return Checkpointer(store, replace(config.checkpoint, enabled=True, every_n_frames=0, every_s=0.0))


def run(args: argparse.Namespace) -> int:
    with _StopOnSignal() as stop:
        return _run(args, stop)


def _run(args: argparse.Namespace, stop: _StopOnSignal) -> int:
    from panoptic_mapping.checkpoint import CHECKPOINT_DIR
    from panoptic_mapping.pipeline import map_recording, write_map_outputs
    from recon_core.classes import load_class_table
    from scene_recon.synthetic.overview import render_map_picture

    data_cfg = data_config_from_args(args)
    if getattr(args, "gravity", None):
        data_cfg.gravity.mode = args.gravity
    name, why = choose_segmenter(args)
    if not args.json:
        print(f"segmenter: {name} ({why})")
    if name == "oracle":
        data_cfg.topics.labels = data_cfg.topics.labels or "/ground_truth/panoptic_labels"
    table = load_class_table(args.classes) if args.classes else None
    segmenter = build_segmenter(args, name, table)
    if segmenter is not None and hasattr(segmenter, "description") and not args.json:
        print(f"model: {segmenter.description} (onnxruntime on {segmenter.provider})")
    ckpt, mapper = resume_state(args)
    config = mapper_config_from_args(args)
    if stop():
        print(f"scene-recon map: interrupted by {stop.name} before mapping began: nothing to save",
              file=sys.stderr)
        return stop.exit_code
    checkpointer = make_checkpointer(config, args.out)
    mapper, run_stats = map_recording(args.source, segmenter, config, data_cfg, progress=not args.json,
                                      mapper=mapper, class_table=table, checkpointer=checkpointer,
                                      resume=ckpt, stop=stop)
    if run_stats.interrupted:
        where = (f"checkpoint {checkpointer.last_path} written ({run_stats.frames_read} frames read, "
                 f"{run_stats.frames} mapped)" if checkpointer.last_path is not None else "no checkpoint written")
        print(f"scene-recon map: interrupted by {stop.name} after {run_stats.frames_read} frames; {where}; "
              f"continue with --resume {args.out}", file=sys.stderr)
        return stop.exit_code
    run_info = {"segmenter": name, "source": str(args.source)}
    scene_id = recording_identity(args.source, args.ground_truth if name == "oracle" else None)
    if scene_id:  # the generated scene this map shows: eval-map refuses another scene's ground truth
        run_info["scene"] = scene_id
    if name == "oracle":
        run_info["noise"] = args.noise
    if name == "onnx":
        run_info["model"] = str(args.model or args.model_config)
    if args.classes:
        run_info["classes"] = str(args.classes)
    ents, summary = write_map_outputs(args.out, mapper, run_stats, extra=run_info)
    out = Path(args.out)
    written = ["entities.json", "meshes/", "map.npz", "map.json", "summary.json"]
    if mapper.gravity.get("refined", {}).get("suggest_file"):
        written.append("gravity_refined.txt")
    if checkpointer.saved:
        written.append(f"{CHECKPOINT_DIR}/")
    if stop():  # the map is complete and written; the picture is a convenience
        print(f"scene-recon map: {stop.name} while writing the outputs: the map was finished and written "
              "first; panoptic_map.png skipped", file=sys.stderr)
    else:
        try:
            if render_map_picture(ents, run_stats.poses, out / "panoptic_map.png"):
                written.append("panoptic_map.png")
        except OSError as exc:
            logging.getLogger(__name__).warning("no map picture: %s", exc)
    summary["files"] = written
    (out / "summary.json").write_text(json_text(summary, indent=1), encoding="utf-8")
    problem = empty_result(summary, name)
    if args.json:
        print_json(summary)
    else:
        print_report(summary, ents, args.out, written)
    if problem:
        print(f"scene-recon map: {problem}", file=sys.stderr)
        return EXIT_EMPTY
    return 0


def empty_result(summary: dict, segmenter: str) -> str:
    """Why a written map is empty, and what to do ("" when it is not)."""
    r = summary["run"]
    if summary["entities"] == 0:
        lo, hi = summary.get("depth_range_m", ["?", "?"])
        return (f"the map of {r['frames']} frames has no surface: check the depth range ({lo}-{hi} m, "
                "--min-depth/--max-depth), the depth scale and the camera poses")
    if segmenter != "none" and summary.get("panoptic_entities", 0) == 0:
        return (f"{r['frames']} frames mapped ({r['segmentation_calls']} segmented) but the segmenter "
                f"'{segmenter}' found no object: the map holds unlabelled surface only (entity 'unknown'). "
                "Check the segmenter (--segmenter, --model, --model-config) on these images")
    return ""


def print_report(summary: dict, ents: list, out: str, written: list[str]) -> None:
    r = summary["run"]
    print(f"mapped {r['frames']} frames ({r['keyframes']} keyframes, {r['segmentation_calls']} segmentation calls) "
          f"in {r['wall_s']:.1f} s; mapper alone {r['mapper_fps']:.1f} frames/s")
    if r.get("stage_ms"):
        print("per frame: " + ", ".join(f"{k} {v:.1f} ms" for k, v in r["stage_ms"].items()))
    skipped = r.get("skipped", {})
    if skipped:
        print("skipped: " + ", ".join(f"{k}={v}" for k, v in skipped.items()))
    if r.get("failed_frames"):
        worst = max(r["failures"].items(), key=lambda kv: kv[1])[0]
        print(f"warning: {r['failed_frames']} frames failed in the mapper and were skipped (most often: {worst})")
    if r.get("truncated"):
        print("warning: the recording is truncated; the frames before the cut were mapped")
    if any(summary.get("origin_offset_m", [0, 0, 0])):
        off = summary["origin_offset_m"]
        print(f"map recentred: its origin is at ({off[0]:.0f}, {off[1]:.0f}, {off[2]:.0f}) m of the input map frame "
              "(origin_offset_m in map.json / summary.json; add it to map back)")
    gravity = summary.get("gravity") or {}
    if gravity.get("note"):
        print(gravity["note"])
    print(f"map: {summary['map_blocks']} voxel blocks, {summary['map_memory_mb']} MB, "
          f"{summary['global_segments']} global segments")
    print(f"{'id':>5s} {'class':12s} {'instance':>8s} {'conf':>5s} {'vertices':>8s}")
    for e in sorted(ents, key=lambda e: (e.class_name, e.id)):
        print(f"{e.id:5d} {e.class_name:12s} {e.instance_id:8d} {e.confidence:5.2f} {len(e.vertices):8d}")
    print(f"wrote {out}/: " + ", ".join(written))
