"""Overview picture of a synthetic scene and the camera path, to show users what was generated.

A virtual camera looks down at the room from high up at an oblique angle. To see *into* the room,
the ray caster peels away what would hide it: back faces (the inside of the near walls and of the
ceiling), anything outside the room box (outer wall faces, the top of the ceiling) and optionally
hidden labels; peeled rays are re-cast from just behind the skipped surface (a few layers, all
vectorized). Surfaces are coloured by label (or by their rendered appearance) with simple shading,
then the camera path is drawn with OpenCV: bright where visible, dim where occluded, with small view
frustums, a start dot, an end square and a thin grey footprint of the path on the floor.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import trimesh

from recon_core.entity import Entity
from recon_core.frame import CameraIntrinsics
from scene_recon.synthetic.geometry import look_at_pose, normalize, pixel_rays, project
from scene_recon.synthetic.items import RenderItem, label_colors
from scene_recon.synthetic.renderer import RaycastRenderer, RayHits, RenderConfig, _rowdot
from scene_recon.synthetic.trajectory import RoomBounds


@dataclass
class OverviewConfig:
    """How the overview picture is framed and drawn."""

    width: int = 960
    height: int = 720
    #: Horizontal field of view of the virtual camera.
    fov_deg: float = 50.0
    #: Viewing direction: elevation above the horizon (90 = straight down) and azimuth of the
    #: camera position around the scene centre (degrees from +x, counter-clockwise).
    elevation_deg: float = 60.0
    azimuth_deg: float = -70.0
    #: Extra distance factor (>1 leaves more border around the scene).
    distance_factor: float = 1.05
    #: "labels": flat label colours (what the segmentation ground truth is); "appearance": the
    #: simulator's textured colours.
    mode: Literal["labels", "appearance"] = "labels"
    #: Skip hits above this height (None: the room height when a room is given, else no cut).
    cut_height_m: float | None = None
    #: Labels not drawn (peeled away like the ceiling).
    hide_labels: tuple[int, ...] = ()
    cull_backfaces: bool = True
    #: Maximum surfaces peeled per ray.
    max_layers: int = 6
    #: Draw a frustum every N frames (0 = none) and its size in metres.
    frustum_every: int = 30
    frustum_size_m: float = 0.3
    #: Also draw the path's footprint on the floor (thin grey line).
    draw_floor_shadow: bool = True
    #: Write label ids at the centre of each visible object smaller than `max_text_area` (fraction
    #: of the image; keeps the floor/walls unlabelled).
    draw_label_ids: bool = True
    max_text_area: float = 0.1


def _overview_camera(
    items: Sequence[RenderItem], room: RoomBounds | None, cfg: OverviewConfig
) -> tuple[np.ndarray, CameraIntrinsics]:
    """Pose and intrinsics that frame the whole scene from the configured direction."""
    lo = np.min([it.mesh.bounds[0] for it in items], axis=0)
    hi = np.max([it.mesh.bounds[1] for it in items], axis=0)
    if room is not None:
        lo = np.array([room.x_min, room.y_min, 0.0])
        hi = np.array([room.x_max, room.y_max, room.height])
    center = 0.5 * (lo + hi)
    center[2] = lo[2] + 0.3 * (hi[2] - lo[2])
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    f = 0.5 * cfg.width / np.tan(np.radians(cfg.fov_deg) / 2)
    vfov = 2 * np.arctan(0.5 * cfg.height / f)
    half = min(np.radians(cfg.fov_deg), vfov) / 2
    dist = cfg.distance_factor * radius / max(np.sin(half), 1e-3)
    el, az = np.radians(cfg.elevation_deg), np.radians(cfg.azimuth_deg)
    eye = center + dist * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    if cfg.elevation_deg >= 89.9:  # straight down: heading undefined, nudge it
        eye[:2] += 1e-3 * np.array([np.cos(az), np.sin(az)])
    intr = CameraIntrinsics(f, f, (cfg.width - 1) / 2, (cfg.height - 1) / 2, cfg.width, cfg.height)
    return look_at_pose(eye, center), intr


def _peel_cast(
    renderer: RaycastRenderer,
    pose: np.ndarray,
    intr: CameraIntrinsics,
    room: RoomBounds | None,
    cfg: OverviewConfig,
) -> RayHits:
    """Cast the overview rays, re-casting rays whose first hit must be peeled away.

    float32 throughout, row dot products written out, and the first layer (every ray) cast without
    gathering: a 960x720 image had cost 0.5 CPU s here, most of it in numpy, not in the casting."""
    rot = pose[:3, :3]
    dirs = (pixel_rays(intr).reshape(-1, 3) @ rot.T).astype(np.float32)
    n = dirs.shape[0]
    eye = pose[:3, 3].astype(np.float32)
    origin = np.broadcast_to(eye, (n, 3)).copy()
    t_total = np.zeros(n, np.float32)
    item_index = np.full(n, -1, np.int32)
    normals = np.zeros((n, 3), np.float32)
    labels_of = np.array([it.label for it in renderer.items], dtype=np.int32)
    hidden = np.isin(labels_of, np.asarray(cfg.hide_labels, dtype=np.int64))
    any_hidden = bool(hidden.any())
    cut = cfg.cut_height_m if cfg.cut_height_m is not None else (room.height - 0.02 if room else np.inf)
    cut32 = np.float32(cut)
    pending: np.ndarray | None = None  # None: every ray (no gather)
    for _ in range(max(cfg.max_layers, 1)):  # a few layers, each vectorized over all rays
        o = origin if pending is None else origin[pending]
        d = dirs if pending is None else dirs[pending]
        raw = renderer.cast_rays(o, d)
        hit = np.isfinite(raw.t) & (raw.item_index >= 0)
        t = np.where(hit, raw.t, np.float32(0.0))
        point = o + t[:, None] * d
        skip = point[:, 2] > cut32
        if any_hidden:
            skip |= hidden[np.maximum(raw.item_index, 0)]
        if cfg.cull_backfaces:
            skip |= _rowdot(raw.face_normals, d) > 0
        if room is not None:
            eps = 0.01
            px, py = point[:, 0], point[:, 1]
            skip |= ~((px > room.x_min - eps) & (px < room.x_max + eps) & (py > room.y_min - eps)
                      & (py < room.y_max + eps))
        skip &= hit
        done = hit & ~skip
        sel = np.flatnonzero(done) if pending is None else pending[done]
        t_total[sel] += t[done]
        item_index[sel] = raw.item_index[done]
        normals[sel] = raw.face_normals[done]
        # Peeled rays continue from just behind the skipped surface.
        again = np.flatnonzero(skip) if pending is None else pending[skip]
        step = t[skip] + np.float32(1e-3)
        origin[again] += step[:, None] * dirs[again]
        t_total[again] += step
        pending = again
        if pending.size == 0:
            break
    valid = item_index >= 0
    flip = np.where(_rowdot(normals, dirs) > 0, np.float32(-1.0), np.float32(1.0))
    normals *= (flip / np.maximum(np.sqrt(_rowdot(normals, normals)), np.float32(1e-12)))[:, None]
    inv_len = np.float32(1.0) / np.sqrt(_rowdot(dirs, dirs))
    view_cos = np.clip(-_rowdot(normals, dirs) * inv_len, 0, 1) * valid
    depth = t_total * valid
    points = eye + depth[:, None] * dirs
    h, w = intr.height, intr.width
    labels = np.where(valid, labels_of[np.maximum(item_index, 0)], 0).astype(np.int32)
    return RayHits(
        depth=depth.reshape(h, w),
        labels=labels.reshape(h, w),
        item_index=item_index.reshape(h, w),
        normals=(normals @ rot.astype(np.float32)).reshape(h, w, 3),
        normals_world=normals.reshape(h, w, 3),
        points=points.reshape(h, w, 3),
        view_cos=view_cos.astype(np.float32).reshape(h, w),
        pose=pose,
    )


def _draw_path(image: np.ndarray, hits: RayHits, poses: np.ndarray, intr: CameraIntrinsics, pose: np.ndarray,
               cfg: OverviewConfig) -> None:
    """Draw the camera path (visible: bright, occluded: dim), frustums and start/end markers."""
    if len(poses) == 0:
        return
    h, w = hits.depth.shape
    positions = poses[:, :3, 3]
    uv, z = project(positions, intr, pose)
    px = np.round(uv).astype(np.int64)
    inside = (z > 0) & (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
    surface = np.full(len(z), np.inf)
    # Distance along the overview ray to the camera position vs. to the visible surface there.
    ray_len = np.linalg.norm(positions - pose[:3, 3], axis=1)
    scale = np.linalg.norm(pixel_rays(intr)[np.clip(px[:, 1], 0, h - 1), np.clip(px[:, 0], 0, w - 1)], axis=1)
    d = hits.depth[np.clip(px[:, 1], 0, h - 1), np.clip(px[:, 0], 0, w - 1)]
    surface[inside] = np.where(d[inside] > 0, d[inside] * scale[inside], np.inf)
    visible = inside & (ray_len <= surface + 0.05)
    n = len(positions)
    shift = 4  # sub-pixel precision for smooth anti-aliased lines
    if cfg.draw_floor_shadow:
        # The path's footprint on the floor: disambiguates where the (elevated) camera really was.
        floor = positions * np.array([1.0, 1.0, 0.0])
        fuv, fz = project(floor, intr, pose)
        ok = fz > 0
        if ok.sum() > 1:
            pts_floor = np.round(fuv[ok] * (1 << shift)).astype(np.int32).reshape(-1, 1, 2)
            cv2.polylines(image, [pts_floor], False, (60, 60, 60), 1, cv2.LINE_AA, shift)
    frac = np.arange(n) / max(n - 1, 1)
    # Colour ramp from cyan (start) to magenta (end) so the walking direction is readable.
    colors = np.stack([255 * frac, 255 * (1 - frac), np.full(n, 255.0)], axis=1)
    pts = np.round(uv * (1 << shift)).astype(np.int64)
    for i in range(n - 1):  # path segments (frames), not pixels
        if z[i] <= 0 or z[i + 1] <= 0:
            continue
        both = visible[i] and visible[i + 1]
        color = tuple(float(c) for c in (colors[i] if both else 0.45 * colors[i]))
        cv2.line(image, tuple(int(v) for v in pts[i]), tuple(int(v) for v in pts[i + 1]), color,
                 3 if both else 1, cv2.LINE_AA, shift)
    if cfg.frustum_every > 0:
        s = cfg.frustum_size_m
        corners_cam = np.array([[-0.6, -0.45, 1.0], [0.6, -0.45, 1.0], [0.6, 0.45, 1.0], [-0.6, 0.45, 1.0]]) * s
        for i in range(0, n, cfg.frustum_every):
            world = corners_cam @ poses[i, :3, :3].T + poses[i, :3, 3]
            cuv, cz = project(np.vstack([positions[i], world]), intr, pose)
            if np.any(cz <= 0):
                continue
            c = np.round(cuv * (1 << shift)).astype(np.int64)
            color = tuple(float(v) for v in colors[i])
            for a, b in ((0, 1), (0, 2), (0, 3), (0, 4), (1, 2), (2, 3), (3, 4), (4, 1)):
                cv2.line(image, tuple(int(v) for v in c[a]), tuple(int(v) for v in c[b]), color, 1, cv2.LINE_AA, shift)
    if z[0] > 0:
        cv2.circle(image, tuple(int(v) for v in np.round(uv[0])), 7, (40, 220, 40), -1, cv2.LINE_AA)
    if z[-1] > 0:
        e = np.round(uv[-1]).astype(int)
        cv2.rectangle(image, (int(e[0]) - 6, int(e[1]) - 6), (int(e[0]) + 6, int(e[1]) + 6), (230, 40, 40), -1)


def _draw_label_ids(image: np.ndarray, labels: np.ndarray, max_area: float) -> None:
    """Write each visible label's id at the centroid of its pixels (vectorized via bincount)."""
    h, w = labels.shape
    flat = labels.reshape(-1).astype(np.int64)
    counts = np.bincount(flat)
    vs, us = np.divmod(np.arange(flat.size), w)
    su = np.bincount(flat, weights=us, minlength=counts.size)
    sv = np.bincount(flat, weights=vs, minlength=counts.size)
    for label in np.flatnonzero(counts):  # one text per object
        if label == 0 or counts[label] < 30 or counts[label] > max_area * h * w:
            continue
        org = (int(su[label] / counts[label]) - 8, int(sv[label] / counts[label]) + 5)
        cv2.putText(image, str(label), org, cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(image, str(label), org, cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)


def render_overview(
    items: Sequence[RenderItem],
    poses: np.ndarray | None = None,
    path: str | Path | None = None,
    room: RoomBounds | None = None,
    config: OverviewConfig | None = None,
    renderer: RaycastRenderer | None = None,
) -> np.ndarray:
    """(H, W, 3) uint8 RGB overview image; also written as PNG to `path` when given.

    poses: (F, 4, 4) camera-to-map poses of the trajectory to draw (None: scene only).
    renderer: reuse an existing renderer of the same items (saves rebuilding the scene).
    """
    cfg = config or OverviewConfig()
    renderer = renderer or RaycastRenderer(items, RenderConfig(max_depth_m=1e4))
    pose, intr = _overview_camera(renderer.items, room, cfg)
    hits = _peel_cast(renderer, pose, intr, room, cfg)
    valid = hits.valid
    if cfg.mode == "appearance":
        image = renderer.shade(hits, intr, rng=None)
    else:
        light = normalize(np.array([0.3, -0.4, 1.0]))
        shade = 0.55 + 0.3 * np.clip(hits.normals_world @ light, 0, 1) + 0.15 * hits.view_cos
        # one colour per label, looked up per pixel (label_colors over every pixel cost 0.4 s a 960x720 image)
        base = label_colors(np.arange(int(hits.labels.max(initial=0)) + 1))[hits.labels].astype(np.float32)
        image = np.clip(base * shade[..., None], 0, 255).astype(np.uint8)
    image[~valid] = (250, 250, 250)
    # Outline label boundaries so adjacent same-coloured surfaces stay distinguishable.
    lab = hits.labels
    edge = np.zeros(lab.shape, bool)
    edge[:, 1:] |= lab[:, 1:] != lab[:, :-1]
    edge[1:, :] |= lab[1:, :] != lab[:-1, :]
    image[edge] = (image[edge] * 0.35).astype(np.uint8)
    image = np.ascontiguousarray(image)
    if poses is not None:
        _draw_path(image, hits, np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4), intr, pose, cfg)
    if cfg.draw_label_ids:
        _draw_label_ids(image, hits.labels, cfg.max_text_area)
    if path is not None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR)):
            raise OSError(f"could not write overview image {path}")
    return image


def render_map_picture(ents: list[Entity], poses: list[np.ndarray], path: Path) -> bool:
    """Bird's-eye picture of the panoptic map: each entity in its own colour, camera path drawn."""
    # the unclaimed surface (entity 0, "unknown") gets a label of its own: labels must be > 0
    spare = max((int(e.id) for e in ents), default=0) + 1
    items = [RenderItem(mesh=e.mesh(), label=int(e.id) if e.id > 0 else spare, name=f"{e.class_name}")
             for e in ents if len(e.faces)]
    if not items:
        return False
    render_overview(items, np.array(poses) if poses else None, path)
    return True


#: Size of each panel of ``render_scene_picture`` (the observation | the replaced scene). A command-line
#: ``replace`` waits for it: at 960x720 the two panels took 1.4-2.3 CPU s (the label colours of every
#: pixel alone 0.4 s a panel), about half of a warm run; at 640x480 with the colours looked up per label
#: and the panels drawn on two threads (numpy and Open3D's ray casting release the interpreter lock)
#: 0.3-0.4 CPU s.
SCENE_PICTURE_PANEL = (640, 480)


def render_scene_picture(scene_dir: str | Path, path: str | Path,
                         before: Mapping[str, trimesh.Trimesh] | None = None,
                         config: OverviewConfig | None = None) -> Path:
    """Bird's-eye picture of a replaced scene (``scene.glb`` of ``scene-recon replace``, walls left out).

    With ``before`` (object name -> its observed mesh in the map frame: what stage 4 was given) the
    observation and the interactive scene are drawn side by side from the same camera, each object
    in the same colour on both sides, so a reader sees at once which object became which model.
    ``config``: each panel's framing (default: ``OverviewConfig`` at ``SCENE_PICTURE_PANEL``).
    """
    from concurrent.futures import ThreadPoolExecutor

    cfg = config or OverviewConfig(width=SCENE_PICTURE_PANEL[0], height=SCENE_PICTURE_PANEL[1])
    scene = trimesh.load(Path(scene_dir) / "scene.glb", force="scene")
    labels: dict[str, int] = {}
    after: list[RenderItem] = []
    for node in scene.graph.nodes_geometry:
        transform, geom = scene.graph[node]
        mesh = scene.geometry.get(geom)
        if not isinstance(mesh, trimesh.Trimesh) or not len(mesh.faces):
            continue
        posed = mesh.copy()
        posed.apply_transform(transform)
        owner = str(node).split("__")[0]
        if owner.startswith("wall"):  # walls would hide the room from the bird's-eye camera
            continue
        after.append(RenderItem(mesh=posed, label=labels.setdefault(owner, len(labels) + 1), name=owner))
    if not after:
        raise ValueError(f"{scene_dir}/scene.glb holds no geometry")
    observed = [RenderItem(mesh=m, label=labels.setdefault(n, len(labels) + 1), name=n)
                for n, m in (before or {}).items() if len(m.faces) and not n.startswith("wall")]
    lo = np.min([it.mesh.bounds[0] for it in [*after, *observed]], axis=0)
    hi = np.max([it.mesh.bounds[1] for it in [*after, *observed]], axis=0)
    room = RoomBounds(float(lo[0]), float(hi[0]) + 1e-6, float(lo[1]), float(hi[1]) + 1e-6,
                      max(float(hi[2]), 1e-3))
    if observed:  # both panels at once: most of their time is spent outside the interpreter lock
        with ThreadPoolExecutor(1, thread_name_prefix="picture-panel") as pool:
            left_job = pool.submit(render_overview, observed, room=room, config=cfg)
            image = render_overview(after, room=room, config=cfg)
            left = left_job.result()
        image = np.concatenate([left, np.full((left.shape[0], 8, 3), 255, np.uint8), image], axis=1)
    else:
        image = render_overview(after, room=room, config=cfg)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), cv2.cvtColor(image, cv2.COLOR_RGB2BGR)):
        raise OSError(f"could not write {out}")
    return out
