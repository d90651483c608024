"""Scene actions (``ApplySceneAction``): set a joint, move an object, put it on another support.

One module holds the semantics the ROS service, the CLI and planners share. Every action is
validated and applied to a copy of the scene: on success the copy (with ``revision`` + 1) replaces
the scene, on failure an ``ActionError`` says why and the scene is unchanged. Placements are
physical: a moved or re-parented object ends resting on a support surface of its (new) parent
(a table top, a shelf level, a drawer bottom: ``CadModel.features.support_surfaces`` moved by the
parent's pose and joint values), never floating and never more than ``MAX_PENETRATION_M`` inside
another object; the objects standing on it move with it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import trimesh
from numpy.typing import NDArray

from cad_replacement.cad.feature_types import SupportSurface
from cad_replacement.scene_model import MAP_ROOT, PlacedObject, ReplacedScene
from cad_replacement.solids import ObjectSolids, penetration_between
from recon_core.errors import InputError
from recon_core.geometry.polygon import points_in_polygon

#: Largest accepted depth (m) of a placed object inside another one (the issue's 1 cm).
MAX_PENETRATION_M = 0.01
#: Joint values may exceed their limits by this much (rounding of a planner's request).
LIMIT_TOLERANCE = 1e-6
#: A moved object may be dropped onto a support at most this far below where it was asked to be (m).
MAX_DROP_M = 0.25
#: Grid resolution (per axis) of the search for a free spot on a support surface.
SPOT_GRID = 9
#: An object must stay upright: its z axis within this angle of the map's (deg).
UPRIGHT_TOL_DEG = 1.0

ACTIONS = ("set_joint", "move", "reparent")


class ActionError(InputError):
    """An action cannot be applied (unknown object or joint, limit, impossible placement)."""


@dataclass(frozen=True)
class SceneAction:
    """What to do. ``joint`` is the model's joint name (with ``object_name``) or ``<object>__<joint>``."""

    kind: str
    object_name: str = ""
    joint: str = ""
    value: float = 0.0
    pose: NDArray[np.float64] | None = None
    new_parent: str = ""


@dataclass
class SupportSpot:
    """A support surface of an object in the map frame: height, outline (N, 2), free height, link."""

    owner: str
    link: str
    height: float
    polygon: NDArray[np.float64]
    clearance: float | None
    enclosed: bool = False


# ---------------------------------------------------------------------------------------------- queries
def descendants(scene: ReplacedScene, name: str) -> list[PlacedObject]:
    """Objects resting (directly or not) on ``name``."""
    out: list[PlacedObject] = []
    frontier = [name]
    while frontier:
        kids = [o for o in scene.objects if o.parent in frontier]
        out.extend(kids)
        frontier = [o.name for o in kids]
    return out


def support_spots(obj: PlacedObject) -> list[SupportSpot]:
    """The object's support surfaces in the map frame at its joint values (plus its top if it has none)."""
    surfaces: Iterable[SupportSurface] = obj.model.features.support_surfaces
    spots: list[SupportSpot] = []
    for s in surfaces:
        motion = obj.model.surface_motion(s.link, obj.joint_values) if s.link in {lk.name for lk in obj.model.links} \
            else np.eye(4)
        t = obj.pose @ motion
        pts = np.c_[s.polygon, np.full(len(s.polygon), s.height), np.ones(len(s.polygon))] @ t.T
        spots.append(SupportSpot(obj.name, s.link, float(pts[:, 2].mean()), pts[:, :2], s.clearance, s.enclosed))
    if not spots:  # a layout slab or a model without analytic surfaces: its top face
        lo, hi = posed_bounds(obj)
        poly = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
        spots.append(SupportSpot(obj.name, obj.model.root_link, float(hi[2]), poly, None))
    return spots


def _posed_meshes(obj: PlacedObject) -> list[trimesh.Trimesh]:
    out = []
    for m in obj.model.posed_link_meshes(obj.joint_values).values():
        if len(m.faces):
            posed = m.copy()
            posed.apply_transform(obj.pose)
            out.append(posed)
    return out


def posed_bounds(obj: PlacedObject) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    meshes = _posed_meshes(obj)
    if not meshes:
        return obj.pose[:3, 3].copy(), obj.pose[:3, 3].copy()
    v = np.concatenate([m.vertices for m in meshes])
    return v.min(axis=0), v.max(axis=0)


def penetration(obj: PlacedObject, others: Iterable[PlacedObject]) -> tuple[float, str]:
    """Deepest point of ``obj`` inside another object's solids (or of another inside it), and who."""
    mine = ObjectSolids(obj, hulls=False)
    worst, who = 0.0, ""
    for other in others:
        depth = penetration_between(mine, ObjectSolids(other, hulls=False))
        if depth > worst:
            worst, who = depth, other.name
    return worst, who


# ---------------------------------------------------------------------------------------------- helpers
def copy_scene(scene: ReplacedScene) -> ReplacedScene:
    """A copy whose poses, joint values and support relations can change; models are shared (immutable)."""
    objects = [dataclasses.replace(o, pose=o.pose.copy(), joint_values=dict(o.joint_values)) for o in scene.objects]
    return ReplacedScene(scene.name, objects, scene.frame_id, scene.revision)


def _shift(scene: ReplacedScene, obj: PlacedObject, transform: NDArray[np.float64]) -> None:
    """Apply ``transform`` (map frame) to ``obj`` and everything resting on it."""
    for o in [obj, *descendants(scene, obj.name)]:
        o.pose = transform @ o.pose


def _check_upright(pose: NDArray[np.float64]) -> None:
    z = pose[:3, 2]
    if float(z[2]) < np.cos(np.radians(UPRIGHT_TOL_DEG)):
        raise ActionError("objects stay upright: the requested orientation tilts the object; give a rotation "
                          "about the vertical axis only")


def _resolve_joint(scene: ReplacedScene, action: SceneAction) -> tuple[PlacedObject, str]:
    if action.object_name:
        obj = _find(scene, action.object_name)
        return obj, action.joint
    for o in scene.objects:
        prefix = f"{o.name}__"
        if action.joint.startswith(prefix) and action.joint[len(prefix):] in {j.name for j in o.model.joints}:
            return o, action.joint[len(prefix):]
    raise ActionError(f"no joint {action.joint!r} in scene {scene.name!r}; joints are named <object>__<joint>: "
                      f"{sorted(f'{o.name}__{j.name}' for o in scene.objects for j in o.model.movable_joints)}")


def _find(scene: ReplacedScene, name: str) -> PlacedObject:
    try:
        return scene.object(name)
    except InputError as exc:
        raise ActionError(str(exc)) from exc


def _rest_on_spot(scene: ReplacedScene, obj: PlacedObject, spot: SupportSpot) -> None:
    """Drop/lift ``obj`` (with what rests on it) so its bottom touches the spot's height."""
    delta = np.eye(4)
    delta[2, 3] = spot.height - obj.resting_height()
    _shift(scene, obj, delta)
    obj.parent, obj.parent_link = spot.owner, spot.link
    if spot.owner == MAP_ROOT:
        obj.parent_link = ""


def _others(scene: ReplacedScene, obj: PlacedObject) -> list[PlacedObject]:
    carried = {o.name for o in descendants(scene, obj.name)} | {obj.name}
    return [o for o in scene.objects if o.name not in carried]


def _check_free(scene: ReplacedScene, obj: PlacedObject, support_owner: str) -> None:
    others = [o for o in _others(scene, obj)]
    depth, who = penetration(obj, others)
    if depth > MAX_PENETRATION_M:
        where = f" (resting on {support_owner})" if support_owner else ""
        raise ActionError(f"{obj.name} would be {100 * depth:.1f} cm inside {who}{where}; choose another place")


def _reorder(scene: ReplacedScene) -> None:
    """Parents before children again after a re-parenting."""
    order: list[PlacedObject] = []
    placed: set[str] = {MAP_ROOT}
    pending = list(scene.objects)
    while pending:
        ready = [o for o in pending if o.parent in placed]
        if not ready:
            raise ActionError("the support relations would form a cycle")
        for o in ready:
            order.append(o)
            placed.add(o.name)
        pending = [o for o in pending if o.name not in placed]
    scene.objects = order


# ---------------------------------------------------------------------------------------------- actions
def _set_joint(scene: ReplacedScene, action: SceneAction) -> None:
    obj, joint_name = _resolve_joint(scene, action)
    movable = {j.name: j for j in obj.model.movable_joints}
    if joint_name not in movable:
        raise ActionError(f"{obj.name} has no movable joint {joint_name!r} (has {sorted(movable)})")
    joint = movable[joint_name]
    value = float(action.value)
    if not np.isfinite(value):
        raise ActionError(f"joint value must be finite, got {value}")
    if joint.type != "continuous" and not (joint.lower - LIMIT_TOLERANCE <= value <= joint.upper + LIMIT_TOLERANCE):
        raise ActionError(f"{obj.name}__{joint_name}: {value:.4g} is outside its limits "
                          f"[{joint.lower:.4g}, {joint.upper:.4g}]")
    before = obj.link_poses()
    obj.joint_values[joint_name] = joint.clip(value)
    after = obj.link_poses()
    # objects resting in a drawer or on a door shelf move with their link
    for child in descendants(scene, obj.name):
        if child.parent == obj.name and child.parent_link and child.parent_link != obj.model.root_link:
            motion = after[child.parent_link] @ np.linalg.inv(before[child.parent_link])
            _shift(scene, child, motion)


def _move(scene: ReplacedScene, action: SceneAction) -> None:
    obj = _find(scene, action.object_name)
    if action.pose is None:
        raise ActionError("move needs a pose")
    pose = np.asarray(action.pose, dtype=np.float64).reshape(4, 4)
    if not np.all(np.isfinite(pose)):
        raise ActionError("move: the pose must be finite")
    _check_upright(pose)
    _shift(scene, obj, pose @ np.linalg.inv(obj.pose))
    bottom = obj.resting_height()
    centre = obj.pose[:2, 3]
    carried = {o.name for o in descendants(scene, obj.name)} | {obj.name}
    spots = [s for o in scene.objects if o.name not in carried for s in support_spots(o)
             if s.height <= bottom + MAX_PENETRATION_M and s.height >= bottom - MAX_DROP_M
             and points_in_polygon(centre[None], s.polygon)[0]]
    if not spots:
        raise ActionError(f"nothing below {obj.name} at ({centre[0]:.2f}, {centre[1]:.2f}) within "
                          f"{100 * MAX_DROP_M:.0f} cm to rest on; place it over a table, shelf or the floor")
    spot = max(spots, key=lambda s: s.height)
    _rest_on_spot(scene, obj, spot)
    _check_free(scene, obj, spot.owner)


def _free_spot(scene: ReplacedScene, obj: PlacedObject, spot: SupportSpot) -> NDArray[np.float64] | None:
    """An xy position on ``spot`` where ``obj``'s footprint fits and clears what already stands there."""
    lo, hi = posed_bounds(obj)
    half = 0.5 * (hi[:2] - lo[:2])
    height = hi[2] - lo[2]
    if spot.clearance is not None and spot.clearance < height:
        return None
    poly = spot.polygon
    plo, phi = poly.min(axis=0) + half, poly.max(axis=0) - half
    if np.any(plo > phi):
        return None
    gx, gy = np.meshgrid(np.linspace(plo[0], phi[0], SPOT_GRID), np.linspace(plo[1], phi[1], SPOT_GRID))
    cand = np.c_[gx.ravel(), gy.ravel()]
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half
    inside = np.all([points_in_polygon(cand + c, poly) for c in corners], axis=0)
    cand = cand[inside]
    occupants = [o for o in scene.objects if o.parent == spot.owner and o.name != obj.name]
    if len(cand) and occupants:
        boxes = np.array([np.r_[posed_bounds(o)[0][:2], posed_bounds(o)[1][:2]] for o in occupants])
        clear = np.ones(len(cand), bool)
        for b in boxes:
            clear &= ~((cand[:, 0] + half[0] > b[0]) & (cand[:, 0] - half[0] < b[2])
                       & (cand[:, 1] + half[1] > b[1]) & (cand[:, 1] - half[1] < b[3]))
        cand = cand[clear]
    if not len(cand):
        return None
    centre = poly.mean(axis=0)
    return cand[int(np.argmin(np.linalg.norm(cand - centre, axis=1)))]


def _reparent(scene: ReplacedScene, action: SceneAction) -> None:
    obj = _find(scene, action.object_name)
    if action.new_parent == obj.name or action.new_parent in {o.name for o in descendants(scene, obj.name)}:
        raise ActionError(f"{obj.name} cannot rest on itself or on something that rests on it")
    parent = _find(scene, action.new_parent)
    # inside a container first (a fridge shelf, a cabinet level), then the highest open surface
    spots = sorted(support_spots(parent), key=lambda s: (not s.enclosed, -s.height))
    for spot in spots:
        xy = _free_spot(scene, obj, spot)
        if xy is None:
            continue
        lo, hi = posed_bounds(obj)
        delta = np.eye(4)
        delta[:2, 3] = xy - 0.5 * (lo[:2] + hi[:2])
        trial = copy_scene(scene)
        moved = trial.object(obj.name)
        _shift(trial, moved, delta)
        _rest_on_spot(trial, moved, spot)
        try:
            _check_free(trial, moved, spot.owner)
        except ActionError:
            continue
        scene.objects = trial.objects
        return
    raise ActionError(f"no free support surface on {parent.name} holds {obj.name} (checked {len(spots)} "
                      "surfaces: too small, too low or occupied)")


def apply_action(scene: ReplacedScene, action: SceneAction) -> ReplacedScene:
    """A new scene with ``action`` applied and ``revision`` + 1; ``scene`` itself is never modified."""
    if action.kind not in ACTIONS:
        raise ActionError(f"unknown action {action.kind!r}; valid: {ACTIONS}")
    result = copy_scene(scene)
    if action.kind == "set_joint":
        _set_joint(result, action)
    elif action.kind == "move":
        _move(result, action)
    else:
        _reparent(result, action)
    _reorder(result)
    result.validate()
    result.revision = scene.revision + 1
    return result


__all__ = ["ACTIONS", "ActionError", "SceneAction", "SupportSpot", "apply_action", "copy_scene", "descendants",
           "penetration", "support_spots"]
