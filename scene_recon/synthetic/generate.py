"""`scene-recon generate`: a synthetic scene recorded as a real ROS 2 bag, ground truth beside it.

Output layout for `--out out/kitchen` (a `.mcap`/`.db3` suffix on PATH picks the storage and is
stripped from the folder name):

    out/kitchen/                    rosbag2 folder: metadata.yaml + kitchen.mcap (lz4 chunks, see bag_writer)
        /camera/color/image_raw          rgb8
        /camera/depth/image_rect_raw     16UC1 (mm), noisy like a structured-light sensor
        /camera/color/camera_info
        /tf (map -> camera_link), /tf_static (camera_link -> camera_color_optical_frame)
        /ground_truth/panoptic_labels    32SC1: entity id per pixel (0 = nothing)
    out/kitchen_groundtruth/
        scene.json      entities (id, class, pose, joints, box, parent), support and proximal edges
        meshes/*.ply    every entity's mesh in the map frame
        urdf/scene.urdf ground-truth kinematic tree through the stage-4 exporter (+ urdf/meshes/,
                        scene.xml MJCF, scene.glb, static.urdf, objects/*.urdf, joint_states.json)
        overview.png    bird's-eye picture with the camera path
        generation.json the settings and timings of the run
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from panoptic_mapping.dataio.bag_writer import RGBDBagWriter
from scene_recon.synthetic.layout import LayoutConfig
from scene_recon.synthetic.scene import GroundTruthScene, build_scene
from scene_recon.synthetic.sensor import RGBDSensorSimulator, SensorConfig
from scene_recon.synthetic.trajectory import Footprint, RoomBounds, TrajectoryConfig, generate_trajectory


@dataclass
class GenerateConfig:
    objects: int = 20
    frames: int = 300
    fps: float = 30.0
    seed: int = 0
    storage: str = "mcap"
    #: MCAP chunk compression ("lz4", "zstd", "none"; None: the writer's default, lz4 for mcap, none for db3)
    bag_compression: str | None = None
    layout: LayoutConfig = field(default_factory=LayoutConfig)
    sensor: SensorConfig = field(default_factory=SensorConfig)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)


def split_output_path(path: str | Path, storage: str | None = None) -> tuple[Path, str]:
    """(bag folder, storage) from PATH: a .mcap/.db3 suffix selects the storage and is dropped."""
    path = Path(path)
    if path.suffix in (".mcap", ".db3"):
        return path.with_suffix(""), path.suffix[1:]
    return path, storage or "mcap"


def ground_truth_path(bag: str | Path) -> Path:
    """The ground-truth folder beside a generated bag."""
    bag = Path(bag)
    if bag.is_file():  # the bare .mcap/.db3 inside the bag folder
        bag = bag.parent
    return bag.with_name(bag.name + "_groundtruth")


def room_bounds(scene: GroundTruthScene) -> RoomBounds:
    w, d, h = scene.room_size
    return RoomBounds(-w / 2, w / 2, -d / 2, d / 2, h)


def generate_recording(out: str | Path, config: GenerateConfig, progress: bool = True) -> dict:
    """Generate scene + trajectory, render every frame into a bag; returns a summary dict."""
    from tqdm import tqdm

    bag_path, storage = split_output_path(out, config.storage)
    gt_path = ground_truth_path(bag_path)
    if bag_path.exists():
        raise FileExistsError(f"{bag_path} exists; remove it or choose another --out")
    timings = {}
    t0 = time.perf_counter()
    scene = build_scene(config.objects, config.seed, name=bag_path.name, layout=config.layout)
    timings["scene_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    objects = [e for e in scene.entities if e.category != "layout"]
    poi = np.array([e.box.center for e in objects]) if objects else None
    obstacles = [Footprint((float(e.box.center[0]), float(e.box.center[1])),
                           (float(e.box.size[0] / 2), float(e.box.size[1] / 2)), float(e.box.yaw))
                 for e in objects if e.parent == "floor"]
    traj = generate_trajectory(room_bounds(scene), poi, obstacles, config.frames, config.fps, config.seed,
                               config.trajectory)
    timings["trajectory_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    sim = RGBDSensorSimulator(scene.render_items(config.seed), config=config.sensor)
    visible = np.zeros(max(e.id for e in scene.entities) + 1, np.int64)
    bag_path.parent.mkdir(parents=True, exist_ok=True)
    with RGBDBagWriter(bag_path, storage=storage, compression=config.bag_compression) as writer:
        compression = writer.compression
        frames = sim.frames(traj.poses, traj.timestamps_ns, seed=config.seed, fps=config.fps)
        for frame in tqdm(frames, total=len(traj), desc="rendering", unit="frame", disable=not progress):
            labels = frame.extras["labels"]
            visible += np.bincount(labels.ravel(), minlength=visible.size)[: visible.size]
            writer.write_frame(frame.timestamp_ns, frame.color, frame.depth, frame.intrinsics, frame.pose, labels)
    timings["render_and_write_s"] = time.perf_counter() - t0
    for e in scene.entities:
        e.visible_pixels = int(visible[e.id])

    t0 = time.perf_counter()
    scene.save(gt_path)
    from scene_recon.synthetic.overview import render_overview

    render_overview(sim.items, traj.poses, gt_path / "overview.png", room=room_bounds(scene),
                    renderer=sim.renderer)
    timings["ground_truth_s"] = time.perf_counter() - t0
    summary = {
        "bag": str(bag_path), "storage": storage, "compression": compression, "ground_truth": str(gt_path),
        "frames": len(traj), "resolution": [config.sensor.camera.width, config.sensor.camera.height],
        "room_size_m": [round(v, 3) for v in scene.room_size],
        "entities": len(scene.entities),
        "objects": len(objects),
        "classes": _class_counts(scene),
        "never_seen": [e.name for e in scene.entities if e.visible_pixels == 0],
        "support_edges": len(scene.support_edges), "proximal_edges": len(scene.proximal),
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
        "total_s": round(sum(timings.values()), 3),
    }
    (gt_path / "generation.json").write_text(
        json.dumps({"config": asdict(config), "summary": summary}, indent=1, default=str), encoding="utf-8")
    return summary


def _class_counts(scene: GroundTruthScene) -> dict[str, int]:
    counts: dict[str, int] = {}
    for e in scene.entities:
        counts[e.class_name] = counts.get(e.class_name, 0) + 1
    return dict(sorted(counts.items()))
