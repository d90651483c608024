"""A tiny hand-made scene (box room + boxes/spheres/cylinders) for tests, benchmarks and demos.

Not the project's scene generator (that one decides realistic layouts); this only provides known
geometry so the sensor simulation can be checked and timed on its own.
Run `python -m scene_recon.synthetic.toy_scene [out_dir]` to time rendering at 640x480 and write an
example colour / depth / label image and an overview picture.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from scene_recon.synthetic.items import Appearance, RenderItem
from scene_recon.synthetic.trajectory import Footprint, RoomBounds

#: Labels 1..6 are the room shell (floor, ceiling, 4 walls); objects start here.
FIRST_OBJECT_LABEL = 10


@dataclass
class ToyScene:
    room: RoomBounds
    items: list[RenderItem]
    obstacles: list[Footprint]
    points_of_interest: np.ndarray  # (N, 3) object centres


def room_shell(room: RoomBounds, thickness: float = 0.05) -> list[RenderItem]:
    """Floor, ceiling and four walls as separate thin boxes whose inner faces bound the room."""
    cx, cy = room.center
    sx, sy = 2 * room.half_extents
    h, t = room.height, thickness
    wall_a = Appearance((0.8, 0.78, 0.7), "noise", scale_m=0.6)
    wall_b = Appearance((0.7, 0.75, 0.8), "stripes", scale_m=0.3, contrast=0.2)
    slab = (sx + 2 * t, sy + 2 * t, t)
    specs = [
        ("floor", slab, (cx, cy, -t / 2), Appearance((0.55, 0.42, 0.3), "grain", scale_m=0.5)),
        ("ceiling", slab, (cx, cy, h + t / 2), Appearance((0.85, 0.85, 0.82), "noise", detail=0.05)),
        ("wall_x_min", (t, sy, h), (room.x_min - t / 2, cy, h / 2), wall_a),
        ("wall_x_max", (t, sy, h), (room.x_max + t / 2, cy, h / 2), wall_a),
        ("wall_y_min", (sx, t, h), (cx, room.y_min - t / 2, h / 2), wall_b),
        ("wall_y_max", (sx, t, h), (cx, room.y_max + t / 2, h / 2), wall_b),
    ]
    items = []
    for label, (name, extents, center, app) in enumerate(specs, start=1):
        mesh = trimesh.creation.box(extents=extents)
        mesh.apply_translation(center)
        items.append(RenderItem(mesh, label, app, name))
    return items


def make_toy_scene(num_objects: int = 20, seed: int = 0, room: RoomBounds | None = None) -> ToyScene:
    """Room shell plus `num_objects` random boxes, spheres and cylinders resting on the floor.

    Objects are placed on a jittered grid so they do not intersect; about a third are small items
    (which do not block the camera), the rest are furniture-sized footprints given as obstacles.
    """
    rng = np.random.default_rng(seed)
    room = room or RoomBounds(-3.0, 3.0, -2.5, 2.5, 2.6)
    items = room_shell(room)
    obstacles: list[Footprint] = []
    centres = []
    cols = int(np.ceil(np.sqrt(num_objects * 1.3)))
    rows = int(np.ceil(num_objects / cols))
    gx = np.linspace(room.x_min + 0.6, room.x_max - 0.6, cols)
    gy = np.linspace(room.y_min + 0.6, room.y_max - 0.6, rows)
    cell = min((gx[1] - gx[0]) if cols > 1 else 1.0, (gy[1] - gy[0]) if rows > 1 else 1.0)
    slots = np.array([(x, y) for y in gy for x in gx])[:num_objects]
    for i, (x, y) in enumerate(slots):
        kind = i % 3
        size = rng.uniform(0.25, 0.55) * min(cell, 1.2) / 0.9
        xy = np.array([x, y]) + rng.uniform(-0.1, 0.1, 2) * cell
        if kind == 0:
            extents = np.array([size, size * rng.uniform(0.7, 1.3), rng.uniform(0.3, 1.1)])
            mesh = trimesh.creation.box(extents=extents)
            mesh.apply_transform(trimesh.transformations.rotation_matrix(rng.uniform(0, np.pi), [0, 0, 1]))
            mesh.apply_translation([xy[0], xy[1], extents[2] / 2])
            smooth = False
        elif kind == 1:
            radius = size / 2
            mesh = trimesh.creation.icosphere(subdivisions=3, radius=radius)
            mesh.apply_translation([xy[0], xy[1], radius])
            smooth = True
        else:
            height = rng.uniform(0.3, 1.0)
            mesh = trimesh.creation.cylinder(radius=size / 2, height=height, sections=32)
            mesh.apply_translation([xy[0], xy[1], height / 2])
            smooth = False  # cylinder caps share vertices with the sides: flat normals avoid smearing
        items.append(RenderItem(mesh, FIRST_OBJECT_LABEL + i, Appearance.random(rng, smooth), f"object_{i}"))
        centres.append(mesh.bounds.mean(axis=0))
        if mesh.extents[2] > 0.6:  # tall enough to be walked around rather than over
            obstacles.append(Footprint.from_mesh(mesh))
    return ToyScene(room, items, obstacles, np.asarray(centres).reshape(-1, 3))


def main(argv: list[str]) -> int:
    import cv2

    from scene_recon.synthetic.overview import render_overview
    from scene_recon.synthetic.sensor import RGBDSensorSimulator
    from scene_recon.synthetic.trajectory import generate_trajectory

    out = Path(argv[0]) if argv else Path("out/synthetic_demo")
    out.mkdir(parents=True, exist_ok=True)
    scene = make_toy_scene(20, seed=1)
    t0 = time.perf_counter()
    traj = generate_trajectory(scene.room, scene.points_of_interest, scene.obstacles, 300, 30.0, seed=1)
    t_traj = time.perf_counter() - t0
    t0 = time.perf_counter()
    sim = RGBDSensorSimulator(scene.items)
    t_build = time.perf_counter() - t0
    times = []
    frames = []
    for frame in sim.frames(traj.poses[:90], traj.timestamps_ns[:90], seed=0):
        times.append(time.perf_counter())
        frames.append(frame)
    per_frame = np.diff(times) * 1e3
    n_tri = sum(len(it.mesh.faces) for it in scene.items)
    print(f"trajectory 300 poses: {t_traj * 1e3:.0f} ms; scene build ({len(scene.items)} items, {n_tri} tris): "
          f"{t_build * 1e3:.0f} ms")
    print(f"render 640x480 (cast + colour + depth noise): median {np.median(per_frame):.1f} ms, "
          f"p90 {np.percentile(per_frame, 90):.1f} ms over {len(per_frame)} frames")
    f = frames[45]
    cv2.imwrite(str(out / "color.png"), cv2.cvtColor(f.color, cv2.COLOR_RGB2BGR))
    depth_vis = np.clip(f.depth / 6.0 * 255, 0, 255).astype(np.uint8)
    cv2.imwrite(str(out / "depth.png"), cv2.applyColorMap(depth_vis, cv2.COLORMAP_TURBO) * (f.depth > 0)[..., None])
    from scene_recon.synthetic.items import label_colors

    cv2.imwrite(str(out / "labels.png"), cv2.cvtColor(label_colors(f.extras["labels"]), cv2.COLOR_RGB2BGR))
    t0 = time.perf_counter()
    render_overview(scene.items, traj.poses, out / "overview.png", room=scene.room)
    print(f"overview: {(time.perf_counter() - t0) * 1e3:.0f} ms -> {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
