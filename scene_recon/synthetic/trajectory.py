"""Handheld-like camera trajectories that scan a room, plus an odometry-like pose-noise model.

A person scanning a room walks a loop through the free floor space holding the camera at chest /
eye height, looks at the furniture (not at blank walls), turns the head smoothly and keeps the
horizon roughly level. The generator reproduces that:

1. a free-space grid of the floor (room shrunk by a wall margin, furniture footprints inflated by an
   obstacle margin) with a clearance map;
2. waypoints on a ring around the room, snapped to free cells, connected by clearance-weighted
   shortest paths (scipy's Dijkstra on the grid graph) so the loop never crosses furniture;
3. a closed Catmull-Rom spline through equally spaced control points of that loop, walked at a
   smoothly varying speed, with a smooth height profile and a small hand wobble;
4. a gaze plan: fixate a point of interest (chosen for a comfortable distance, a small head turn
   and objects not looked at yet), then turn smoothly to the next one, the turn taking longer
   the bigger it is; yaw and pitch are rate-limited then smoothed, roll is a small smooth jitter
   around zero.

Everything is deterministic for a seed. `add_pose_noise` turns the true poses into "estimated"
poses (drift + jitter) for testing robustness to imperfect localisation; the generator itself
always returns the true poses.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import trimesh
from scipy import ndimage, sparse
from scipy.sparse import csgraph
from scipy.spatial.transform import Rotation

from scene_recon.synthetic.geometry import EPS, camera_rotation


@dataclass(frozen=True)
class RoomBounds:
    """Axis-aligned room: floor rectangle at z = 0, walls up to `height`."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float
    height: float = 2.6

    def __post_init__(self) -> None:
        if not (self.x_max > self.x_min and self.y_max > self.y_min and self.height > 0):
            raise ValueError(f"degenerate room bounds {self}")

    @property
    def center(self) -> np.ndarray:
        return np.array([(self.x_min + self.x_max) / 2, (self.y_min + self.y_max) / 2])

    @property
    def half_extents(self) -> np.ndarray:
        return np.array([(self.x_max - self.x_min) / 2, (self.y_max - self.y_min) / 2])

    def contains(self, xy: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """(N,) bool: points at least `margin` inside the floor rectangle."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return (
            (xy[:, 0] >= self.x_min + margin)
            & (xy[:, 0] <= self.x_max - margin)
            & (xy[:, 1] >= self.y_min + margin)
            & (xy[:, 1] <= self.y_max - margin)
        )


@dataclass(frozen=True)
class Footprint:
    """Oriented 2D box on the floor (furniture footprint) the camera must stay out of."""

    center: tuple[float, float]
    half_extents: tuple[float, float]
    yaw: float = 0.0

    @classmethod
    def from_bounds(cls, x_min: float, y_min: float, x_max: float, y_max: float) -> Footprint:
        return cls(((x_min + x_max) / 2, (y_min + y_max) / 2), ((x_max - x_min) / 2, (y_max - y_min) / 2))

    @classmethod
    def from_mesh(cls, mesh: trimesh.Trimesh) -> Footprint:
        """Axis-aligned x/y footprint of a mesh (conservative for rotated objects)."""
        (x0, y0, _), (x1, y1, _) = mesh.bounds
        return cls.from_bounds(float(x0), float(y0), float(x1), float(y1))

    def contains(self, xy: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """(N,) bool: points inside the box grown by `margin` (a rounded-corner-free box grow)."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2) - np.asarray(self.center, dtype=np.float64)
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        local = np.stack([c * xy[:, 0] + s * xy[:, 1], -s * xy[:, 0] + c * xy[:, 1]], axis=1)
        half = np.asarray(self.half_extents, dtype=np.float64) + margin
        return np.all(np.abs(local) <= half, axis=1)


@dataclass
class PoseNoiseConfig:
    """Odometry-like pose error: slow random-walk drift plus per-frame jitter.

    Drift is applied in the map frame about the first camera position (like accumulated SLAM
    error); roll/pitch drift is much smaller than yaw drift because gravity makes them observable.
    """

    drift_translation_m_per_sqrt_s: float = 0.005
    drift_yaw_deg_per_sqrt_s: float = 0.1
    drift_tilt_deg_per_sqrt_s: float = 0.01
    jitter_translation_m: float = 0.002
    jitter_rotation_deg: float = 0.1


@dataclass
class TrajectoryConfig:
    """Tunables of `generate_trajectory` (distances in metres, angles in degrees, times in s).

    Guarantee: camera positions keep at least the margins from walls and footprints, minus the
    hand wobble amplitude and about one grid cell (the free space is a grid).
    """

    #: Keep-out distance from the walls and from furniture footprints.
    wall_margin_m: float = 0.5
    obstacle_margin_m: float = 0.35
    #: Free-space grid resolution.
    grid_resolution_m: float = 0.05
    #: Waypoints on a ring around the room centre, with radial jitter. The ring's size (as a
    #: fraction of the free area's half extents) adapts to the recording: large enough that
    #: `laps` loops take the whole duration at `nominal_speed_mps`, within
    #: [min_loop_fraction, loop_fraction]. A short recording thus circles the middle of the room
    #: looking outwards (sees every wall) instead of walking a third of a big loop.
    num_waypoints: int = 8
    loop_fraction: float = 0.7
    min_loop_fraction: float = 0.2
    nominal_speed_mps: float = 0.35
    waypoint_jitter: float = 0.15
    #: Path cost = length * (1 + clearance_weight / (clearance + 0.1)): prefer open floor.
    clearance_weight: float = 0.5
    #: Spacing of the spline control points along the loop (smaller = follows the loop tighter).
    control_spacing_m: float = 0.6
    #: Walking speed; 0 = auto: walk `laps` loops in the trajectory duration, clipped to
    #: [min_speed_mps, max_speed_mps].
    speed_mps: float = 0.0
    laps: float = 1.0
    min_speed_mps: float = 0.1
    max_speed_mps: float = 0.5
    #: Relative smooth modulation of the speed (0..0.9) and its time scale.
    speed_variation: float = 0.3
    speed_interval_s: float = 2.0
    #: Camera height: nominal, smooth variation amplitude and hard limits.
    height_m: float = 1.45
    height_variation_m: float = 0.1
    height_interval_s: float = 3.0
    min_height_m: float = 1.2
    max_height_m: float = 1.7
    #: Hand wobble: smooth 3D position noise amplitude and time scale.
    wobble_m: float = 0.01
    wobble_interval_s: float = 0.5
    #: Look-at targets (tuned so 300 frames see ~90 % of a 20-object room: most objects are
    #: fixated briefly, as in a quick handheld scan): fixation time per target (+-25 %), minimum
    #: duration of the smooth turn to
    #: the next one (longer for big turns, see the rate limits), preferred horizontal distance,
    #: random offset, and the height looked at when no points of interest are given.
    target_dwell_s: float = 0.6
    target_transition_s: float = 0.4
    #: Score penalty per unit (1 - cos) of head turn to the next target (prefers nearby targets
    #: over ones behind the operator; 0 = any direction).
    turn_penalty: float = 0.0
    #: Score penalty per earlier look at the same point of interest (favours covering new objects).
    revisit_penalty: float = 1.5
    preferred_target_distance_m: float = 2.5
    min_target_distance_m: float = 0.6
    target_jitter_m: float = 0.15
    default_target_height_m: float = 0.7
    #: Pitch limits (negative = looking down) and angular-rate limits.
    min_pitch_deg: float = -50.0
    max_pitch_deg: float = 0.0
    max_yaw_rate_deg_s: float = 90.0
    max_pitch_rate_deg_s: float = 30.0
    #: Gaussian smoothing (std, seconds) of the view angles after rate limiting.
    angle_smoothing_s: float = 0.3
    #: Roll jitter amplitude (about the std) and time scale; hard-clipped at 3x amplitude.
    roll_jitter_deg: float = 1.0
    roll_interval_s: float = 1.5
    #: Settings for `add_pose_noise` (kept here so one YAML section describes the trajectory);
    #: `generate_trajectory` itself always returns the true poses.
    pose_noise: PoseNoiseConfig = field(default_factory=PoseNoiseConfig)


@dataclass
class CameraTrajectory:
    """True camera poses (F, 4, 4) camera-to-map optical frame, timestamps and look-at targets."""

    poses: np.ndarray
    timestamps_ns: np.ndarray
    targets: np.ndarray
    fps: float

    def __len__(self) -> int:
        return int(self.poses.shape[0])

    @property
    def positions(self) -> np.ndarray:
        return self.poses[:, :3, 3]


# ---------------------------------------------------------------------- spline / noise helpers
def catmull_rom(points: np.ndarray, s: np.ndarray, closed: bool = False) -> np.ndarray:
    """Uniform Catmull-Rom spline through `points` (K, D) evaluated at parameters `s` (knot units).

    Open curves clamp the end tangents by repeating the end points; closed curves wrap around
    (s in [0, K)). C1-continuous and passes through every point, so waypoints are visited exactly.
    """
    pts = np.asarray(points, dtype=np.float64)
    k = pts.shape[0]
    s = np.asarray(s, dtype=np.float64)
    if k == 1:
        return np.repeat(pts, s.size, axis=0).reshape(*s.shape, pts.shape[1])
    if closed:
        s = np.mod(s, k)
        i = np.floor(s).astype(np.int64)
        idx = np.stack([i - 1, i, i + 1, i + 2]) % k
    else:
        s = np.clip(s, 0.0, k - 1.0)
        i = np.minimum(np.floor(s).astype(np.int64), k - 2)
        idx = np.clip(np.stack([i - 1, i, i + 1, i + 2]), 0, k - 1)
    f = (s - i)[..., None]
    p0, p1, p2, p3 = pts[idx[0]], pts[idx[1]], pts[idx[2]], pts[idx[3]]
    f2, f3 = f * f, f * f * f
    return 0.5 * (
        2 * p1 + (-p0 + p2) * f + (2 * p0 - 5 * p1 + 4 * p2 - p3) * f2 + (-p0 + 3 * p1 - 3 * p2 + p3) * f3
    )


def smooth_noise(rng: np.random.Generator, times: np.ndarray, interval_s: float, dims: int = 1) -> np.ndarray:
    """(len(times), dims) smooth random signal, ~unit std, correlated over `interval_s` seconds."""
    times = np.asarray(times, dtype=np.float64)
    interval_s = max(float(interval_s), EPS)
    t0 = float(times.min()) if times.size else 0.0
    n_knots = int(np.ceil((float(times.max()) - t0) / interval_s)) + 4 if times.size else 4
    knots = rng.standard_normal((n_knots, dims))
    return catmull_rom(knots, (times - t0) / interval_s + 1.0)


def _rate_limit(values: np.ndarray, max_step: float) -> np.ndarray:
    """Clamp successive differences to +-max_step (a causal follower; loop over frames only)."""
    out = np.array(values, dtype=np.float64)
    for i in range(1, out.size):
        out[i] = out[i - 1] + np.clip(out[i] - out[i - 1], -max_step, max_step)
    return out


# ---------------------------------------------------------------------- free space / path
@dataclass
class _FreeSpace:
    origin: np.ndarray  # xy of cell (0, 0) centre
    res: float
    free: np.ndarray  # (ny, nx) bool
    clearance: np.ndarray  # (ny, nx) metres to the nearest blocked cell

    def cell_centers(self) -> np.ndarray:
        ny, nx = self.free.shape
        ys, xs = np.mgrid[0:ny, 0:nx]
        return np.stack([self.origin[0] + xs * self.res, self.origin[1] + ys * self.res], axis=-1)

    def lookup_free(self, xy: np.ndarray) -> np.ndarray:
        ny, nx = self.free.shape
        ij = np.round((np.asarray(xy).reshape(-1, 2) - self.origin) / self.res).astype(np.int64)
        inside = (ij[:, 0] >= 0) & (ij[:, 0] < nx) & (ij[:, 1] >= 0) & (ij[:, 1] < ny)
        out = np.zeros(len(ij), dtype=bool)
        out[inside] = self.free[ij[inside, 1], ij[inside, 0]]
        return out


def _free_space(
    room: RoomBounds, obstacles: Sequence[Footprint], wall_margin: float, obstacle_margin: float, res: float
) -> _FreeSpace:
    nx = max(int(np.floor((room.x_max - room.x_min) / res)), 1)
    ny = max(int(np.floor((room.y_max - room.y_min) / res)), 1)
    origin = np.array([room.x_min + 0.5 * (room.x_max - room.x_min - (nx - 1) * res),
                       room.y_min + 0.5 * (room.y_max - room.y_min - (ny - 1) * res)])
    space = _FreeSpace(origin, res, np.zeros((ny, nx), bool), np.zeros((ny, nx)))
    xy = space.cell_centers().reshape(-1, 2)
    free = room.contains(xy, wall_margin)
    for obstacle in obstacles:  # a handful of furniture boxes, each test vectorized over cells
        free &= ~obstacle.contains(xy, obstacle_margin)
    free = free.reshape(ny, nx)
    # Keep the largest connected free region: a loop cannot visit a disconnected pocket.
    labels, n = ndimage.label(free, structure=np.ones((3, 3)))
    if n > 1:
        sizes = ndimage.sum(free, labels, index=np.arange(1, n + 1))
        free = labels == (int(np.argmax(sizes)) + 1)
    space.free = free
    space.clearance = ndimage.distance_transform_edt(np.pad(free, 1)) [1:-1, 1:-1] * res
    return space


def _grid_graph(space: _FreeSpace, clearance_weight: float) -> sparse.csr_matrix:
    """8-connected graph over free cells, edge cost = length * clearance penalty."""
    ny, nx = space.free.shape
    ids = np.arange(ny * nx).reshape(ny, nx)
    penalty = 1.0 + clearance_weight / (space.clearance + 0.1)
    rows, cols, costs = [], [], []
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        y0, y1 = max(0, -dy), ny - max(0, dy)
        x0, x1 = max(0, -dx), nx - max(0, dx)
        a = (slice(y0, y1), slice(x0, x1))
        b = (slice(y0 + dy, y1 + dy), slice(x0 + dx, x1 + dx))
        ok = space.free[a] & space.free[b]
        length = space.res * np.hypot(dy, dx)
        cost = length * 0.5 * (penalty[a] + penalty[b])
        rows.append(ids[a][ok])
        cols.append(ids[b][ok])
        costs.append(cost[ok])
    r, c, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(costs)
    return sparse.csr_matrix((np.concatenate([w, w]), (np.concatenate([r, c]), np.concatenate([c, r]))),
                             shape=(ny * nx, ny * nx))


def _waypoints(
    space: _FreeSpace, room: RoomBounds, config: TrajectoryConfig, fraction: float, rng: np.random.Generator
) -> np.ndarray:
    """Flat cell ids of waypoints on a jittered ring around the room, snapped to free cells."""
    centers = space.cell_centers().reshape(-1, 2)
    free_ids = np.flatnonzero(space.free.reshape(-1))
    free_xy = centers[free_ids]
    free_clear = space.clearance.reshape(-1)[free_ids]
    k = max(int(config.num_waypoints), 3)
    start = rng.uniform(0, 2 * np.pi)
    direction = 1.0 if rng.uniform() < 0.5 else -1.0
    angles = start + direction * (2 * np.pi * np.arange(k) / k + rng.uniform(-0.3, 0.3, k) * np.pi / k)
    half = np.maximum(room.half_extents - config.wall_margin_m, space.res)
    radius = fraction * (1.0 + config.waypoint_jitter * rng.uniform(-1, 1, k))
    target = room.center + (radius[:, None] * half) * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    dist = np.linalg.norm(free_xy[None, :, :] - target[:, None, :], axis=2)
    score = dist - 0.5 * np.minimum(free_clear, config.obstacle_margin_m)[None, :]
    chosen = free_ids[np.argmin(score, axis=1)]
    # Drop consecutive duplicates (tiny free space can snap several targets to one cell).
    keep = np.concatenate([[True], chosen[1:] != chosen[:-1]])
    return chosen[keep]


def _loop_polyline(space: _FreeSpace, waypoint_ids: np.ndarray, clearance_weight: float) -> np.ndarray:
    """Closed polyline (M, 2) through the waypoints along shortest free-space paths."""
    graph = _grid_graph(space, clearance_weight)
    unique_ids, inverse = np.unique(waypoint_ids, return_inverse=True)
    _, pred = csgraph.dijkstra(graph, directed=False, indices=unique_ids, return_predecessors=True)
    centers = space.cell_centers().reshape(-1, 2)
    cells: list[int] = []
    k = len(waypoint_ids)
    for j in range(k):  # loop over waypoints; each path is walked along its predecessor chain
        src_row, dst = inverse[j], int(waypoint_ids[(j + 1) % k])
        chain = [dst]
        while chain[-1] != int(waypoint_ids[j]):
            prev = int(pred[src_row, chain[-1]])
            if prev < 0:
                raise ValueError("free space is disconnected between waypoints (no path found)")
            chain.append(prev)
        cells.extend(reversed(chain[1:]))  # from the waypoint (inclusive) up to the next (exclusive)
    if not cells:
        cells = [int(waypoint_ids[0])]
    return centers[np.asarray(cells)]


def _resample_closed(polyline: np.ndarray, spacing: float) -> np.ndarray:
    """Equally spaced points (by arc length) along a closed polyline."""
    closed = np.vstack([polyline, polyline[:1]])
    seg = np.linalg.norm(np.diff(closed, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    length = cum[-1]
    if length < EPS:
        return polyline[:1]
    n = max(int(np.round(length / spacing)), 4)
    s = np.linspace(0.0, length, n, endpoint=False)
    return np.stack([np.interp(s, cum, closed[:, 0]), np.interp(s, cum, closed[:, 1])], axis=1)


def _smooth_loop(space: _FreeSpace, polyline: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Dense samples (N, 2) of a closed spline through the loop and their arc lengths (N+1,).

    Tries the configured control spacing first and tightens it until the spline stays in free
    space (a spline may cut corners the grid path goes around). In cramped rooms (U-turns in
    one-cell corridors) even the tightest spline can overshoot; then the offending samples are
    snapped to their nearest free cell, a kink of at most a few grid cells.
    """
    for spacing_try in (spacing, spacing / 2, spacing / 4, 2 * space.res):
        controls = _resample_closed(polyline, max(spacing_try, space.res))
        k = len(controls)
        dense = catmull_rom(controls, np.linspace(0.0, k, 24 * k, endpoint=False), closed=True)
        inside = space.lookup_free(dense)
        if np.all(inside):
            break
    else:
        dense = _snap_to_free(space, dense, ~inside)
    closed = np.vstack([dense, dense[:1]])
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    return closed, cum


def _snap_to_free(space: _FreeSpace, xy: np.ndarray, bad: np.ndarray) -> np.ndarray:
    """Move the `bad` points to the centre of the nearest free cell (vectorized)."""
    ny, nx = space.free.shape
    _, (iy, ix) = ndimage.distance_transform_edt(~space.free, return_indices=True)
    ij = np.round((xy[bad] - space.origin) / space.res).astype(np.int64)
    cx, cy = np.clip(ij[:, 0], 0, nx - 1), np.clip(ij[:, 1], 0, ny - 1)
    out = xy.copy()
    out[bad] = space.origin + space.res * np.stack([ix[cy, cx], iy[cy, cx]], axis=1)
    return out


# ---------------------------------------------------------------------- look-at targets
@dataclass
class _GazeState:
    """Bookkeeping of the target choice: how often each point was looked at, and the last one."""

    looks: np.ndarray
    last: int = -1


def _choose_target(
    now_xy: np.ndarray,
    later_xy: np.ndarray,
    pois: np.ndarray,
    previous: np.ndarray | None,
    state: _GazeState,
    room: RoomBounds,
    config: TrajectoryConfig,
    rng: np.random.Generator,
) -> np.ndarray:
    """The next look-at point (3,), scored over all points of interest at once."""
    if pois.size == 0:
        # Nothing to look at in particular: look across the room, towards points around its centre.
        ang = rng.uniform(0, 2 * np.pi)
        xy = room.center + 0.3 * room.half_extents * np.array([np.cos(ang), np.sin(ang)])
        return np.array([xy[0], xy[1], config.default_target_height_m])
    delta = pois[:, :2] - now_xy
    dist = np.linalg.norm(delta, axis=1)
    # The target should stay comfortable until the gaze moves on: judge the distance at the end
    # of the dwell too (walking right past an object whips the head around).
    dist_end = np.linalg.norm(pois[:, :2] - later_xy, axis=1)
    pref = config.preferred_target_distance_m
    score = 0.5 * (np.abs(dist - pref) + np.abs(dist_end - pref))
    score = score + np.where(np.minimum(dist, dist_end) < config.min_target_distance_m, 10.0, 0.0)
    # Variety: the last target is nearly excluded, earlier ones are penalized per look, so a
    # short recording still sweeps over many objects.
    score = score + config.revisit_penalty * state.looks + np.where(np.arange(len(pois)) == state.last, 2.0, 0.0)
    if previous is not None:  # prefer small head turns from where the camera looks now
        prev_dir = previous[:2] - now_xy
        prev_dir = prev_dir / max(float(np.linalg.norm(prev_dir)), EPS)
        cosang = (delta @ prev_dir) / np.maximum(dist, EPS)
        score = score + config.turn_penalty * (1.0 - cosang)
    score = score + rng.uniform(0.0, 0.6, len(pois))
    best = int(np.argmin(score))
    state.looks[best] += 1.0
    state.last = best
    return pois[best] + rng.uniform(-1, 1, 3) * config.target_jitter_m


def _view_angles(positions: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Yaw and pitch (radians) of the directions from positions to targets (both (N, 3))."""
    view = targets - positions
    horiz = np.linalg.norm(view[:, :2], axis=1)
    yaw = np.arctan2(view[:, 1], view[:, 0])
    pitch = np.arctan2(view[:, 2], np.maximum(horiz, 0.25))  # steep views close by are clipped later
    return yaw, pitch


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2 * np.pi) - np.pi


def _plan_gaze(
    times: np.ndarray,
    positions: np.ndarray,
    pois: np.ndarray,
    room: RoomBounds,
    config: TrajectoryConfig,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Raw (yaw, pitch) per frame and the gaze target points: fixate, then turn to the next target.

    Each target is held for about `target_dwell_s`; the turn to the next one takes
    `target_transition_s` or longer for big turns (so the smootherstep's peak rate stays within the
    rate limits), and blends the *view angles* towards both targets as seen from the current
    position, so the turn is a clean head rotation rather than a sweep across the room.
    """
    duration = float(times[-1])

    def pos_at(t: float) -> np.ndarray:
        return np.array([np.interp(t, times, positions[:, i]) for i in range(3)])

    dwell = max(config.target_dwell_s, EPS)
    state = _GazeState(looks=np.zeros(len(pois)))
    starts, hold_ends, targets = [], [], []
    t = 0.0
    target = _choose_target(pos_at(0.0)[:2], pos_at(dwell)[:2], pois, None, state, room, config, rng)
    while True:  # one iteration per fixation (a few per 10 s)
        hold_end = t + dwell * float(rng.uniform(0.75, 1.25))
        starts.append(t)
        hold_ends.append(hold_end)
        targets.append(target)
        if hold_end >= duration:
            break
        here = pos_at(hold_end)
        nxt = _choose_target(here[:2], pos_at(hold_end + dwell)[:2], pois, target, state, room, config, rng)
        (ya, yb), (pa, pb) = _view_angles(np.stack([here, here]), np.stack([target, nxt]))
        turn = max(
            config.target_transition_s,
            1.875 * abs(float(_wrap(yb - ya))) / np.radians(max(config.max_yaw_rate_deg_s, EPS)),
            1.875 * abs(float(pb - pa)) / np.radians(max(config.max_pitch_rate_deg_s, EPS)),
        )  # 1.875 = peak / mean rate of smootherstep
        t = hold_end + turn
        target = nxt
    starts_a, hold_a, targets_a = np.array(starts), np.array(hold_ends), np.array(targets)
    k = np.searchsorted(starts_a, times, side="right") - 1
    k_next = np.minimum(k + 1, len(starts_a) - 1)
    span = np.where(k_next > k, starts_a[k_next] - hold_a[k], 1.0)
    f = np.where(k_next > k, np.clip((times - hold_a[k]) / np.maximum(span, EPS), 0.0, 1.0), 0.0)
    w = f * f * f * (f * (6 * f - 15) + 10)  # smootherstep: zero rate and acceleration at both ends
    yaw_a, pitch_a = _view_angles(positions, targets_a[k])
    yaw_b, pitch_b = _view_angles(positions, targets_a[k_next])
    # Unwrap the fixation headings first so that blends never take the long way round.
    yaw_a = np.unwrap(yaw_a)
    yaw = yaw_a + w * _wrap(yaw_b - yaw_a)
    pitch = pitch_a + w * (pitch_b - pitch_a)
    gaze_points = (1 - w)[:, None] * targets_a[k] + w[:, None] * targets_a[k_next]
    return np.unwrap(yaw), pitch, gaze_points


# ---------------------------------------------------------------------- main entry
def generate_trajectory(
    room: RoomBounds,
    points_of_interest: np.ndarray | Sequence[Sequence[float]] | None,
    obstacles: Sequence[Footprint],
    num_frames: int,
    fps: float = 30.0,
    seed: int = 0,
    config: TrajectoryConfig | None = None,
) -> CameraTrajectory:
    """A smooth handheld scanning trajectory of `num_frames` poses at `fps` (deterministic per seed).

    points_of_interest: (N, 3) map-frame points the operator looks at (object centres); may be
    empty. obstacles: floor footprints the camera must stay out of (with `obstacle_margin_m`).
    In a room too cramped for the margins they are relaxed to 70 %, then 50 %, before giving up
    with a ValueError.
    """
    cfg = config or TrajectoryConfig()
    if num_frames < 1:
        raise ValueError("num_frames must be >= 1")
    if not fps > 0:
        raise ValueError("fps must be > 0")
    rng = np.random.default_rng(seed)
    pois = np.asarray(points_of_interest if points_of_interest is not None else [], dtype=np.float64)
    pois = pois.reshape(-1, 3)

    # Free space; relax margins in cramped rooms rather than failing outright.
    for relax in (1.0, 0.7, 0.5):
        space = _free_space(room, obstacles, cfg.wall_margin_m * relax, cfg.obstacle_margin_m * relax,
                            cfg.grid_resolution_m)
        if np.count_nonzero(space.free) >= 9:
            break
    else:
        raise ValueError(f"no free floor space for the camera in {room} with the given obstacles")

    times = np.arange(num_frames, dtype=np.float64) / fps
    duration = max(float(times[-1]), 1.0 / fps)
    half = np.maximum(room.half_extents - cfg.wall_margin_m, cfg.grid_resolution_m)
    # Ramanujan's ellipse perimeter for the ring at fraction 1.
    h = ((half[0] - half[1]) / (half[0] + half[1])) ** 2
    perimeter = np.pi * (half[0] + half[1]) * (1 + 3 * h / (10 + np.sqrt(4 - 3 * h)))
    wanted = cfg.nominal_speed_mps * duration / max(cfg.laps, EPS)
    fraction = float(np.clip(wanted / perimeter, cfg.min_loop_fraction, max(cfg.loop_fraction, cfg.min_loop_fraction)))

    waypoint_ids = _waypoints(space, room, cfg, fraction, rng)
    polyline = _loop_polyline(space, waypoint_ids, cfg.clearance_weight)
    loop, cum = _smooth_loop(space, polyline, cfg.control_spacing_m)
    length = float(cum[-1])
    if cfg.speed_mps > 0:
        speed = cfg.speed_mps
    else:
        speed = float(np.clip(cfg.laps * length / duration, cfg.min_speed_mps, cfg.max_speed_mps))
    variation = np.clip(cfg.speed_variation, 0.0, 0.9)
    rate = speed * (1.0 + variation * np.tanh(smooth_noise(rng, times, cfg.speed_interval_s)[:, 0]))
    arc = rng.uniform(0.0, length) + np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) / fps)])
    arc = np.mod(arc, length) if length > EPS else np.zeros_like(arc)
    xy = np.stack([np.interp(arc, cum, loop[:, 0]), np.interp(arc, cum, loop[:, 1])], axis=1)

    z = cfg.height_m + cfg.height_variation_m * np.tanh(smooth_noise(rng, times, cfg.height_interval_s)[:, 0])
    positions = np.column_stack([xy, np.clip(z, cfg.min_height_m, cfg.max_height_m)])
    wobble = cfg.wobble_m * np.tanh(smooth_noise(rng, times, cfg.wobble_interval_s, 3))
    positions = positions + wobble
    positions[:, 2] = np.clip(positions[:, 2], cfg.min_height_m, cfg.max_height_m)

    # Gaze: fixate points of interest in turn; then follow with bounded angular rate and smooth.
    yaw_raw, pitch_raw, targets = _plan_gaze(times, positions, pois, room, cfg, rng)
    pitch_raw = np.clip(pitch_raw, np.radians(cfg.min_pitch_deg), np.radians(cfg.max_pitch_deg))
    sigma = cfg.angle_smoothing_s * fps
    yaw = _rate_limit(yaw_raw, np.radians(cfg.max_yaw_rate_deg_s) / fps)
    pitch = _rate_limit(pitch_raw, np.radians(cfg.max_pitch_rate_deg_s) / fps)
    if sigma > 0 and num_frames > 1:
        yaw = ndimage.gaussian_filter1d(yaw, sigma, mode="nearest")
        pitch = ndimage.gaussian_filter1d(pitch, sigma, mode="nearest")
    roll_amp = np.radians(cfg.roll_jitter_deg)
    roll = np.clip(roll_amp * smooth_noise(rng, times, cfg.roll_interval_s)[:, 0], -3 * roll_amp, 3 * roll_amp)

    poses = np.tile(np.eye(4), (num_frames, 1, 1))
    poses[:, :3, :3] = camera_rotation(yaw, pitch, roll)
    poses[:, :3, 3] = positions
    timestamps = np.round(times * 1e9).astype(np.int64)
    return CameraTrajectory(poses=poses, timestamps_ns=timestamps, targets=targets, fps=float(fps))


def add_pose_noise(
    poses: np.ndarray, config: PoseNoiseConfig, rng: np.random.Generator, fps: float = 30.0
) -> np.ndarray:
    """Noisy copies (F, 4, 4) of true poses: map-frame random-walk drift, then camera-frame jitter."""
    poses = np.asarray(poses, dtype=np.float64)
    f = poses.shape[0]
    if f == 0:
        return poses.copy()
    sqrt_dt = np.sqrt(1.0 / fps)

    def walk(sigma: float, dims: int) -> np.ndarray:
        steps = rng.standard_normal((f, dims)) * sigma * sqrt_dt
        steps[0] = 0.0
        return np.cumsum(steps, axis=0)

    t_drift = walk(config.drift_translation_m_per_sqrt_s, 3)
    tilt = walk(np.radians(config.drift_tilt_deg_per_sqrt_s), 2)
    yaw = walk(np.radians(config.drift_yaw_deg_per_sqrt_s), 1)
    r_drift = Rotation.from_rotvec(np.column_stack([tilt, yaw])).as_matrix()
    pivot = poses[0, :3, 3]
    noisy = poses.copy()
    noisy[:, :3, :3] = r_drift @ poses[:, :3, :3]
    noisy[:, :3, 3] = np.einsum("fij,fj->fi", r_drift, poses[:, :3, 3] - pivot) + pivot + t_drift

    jitter = np.tile(np.eye(4), (f, 1, 1))
    jitter[:, :3, :3] = Rotation.from_rotvec(
        rng.standard_normal((f, 3)) * np.radians(config.jitter_rotation_deg)
    ).as_matrix()
    jitter[:, :3, 3] = rng.standard_normal((f, 3)) * config.jitter_translation_m
    return noisy @ jitter
