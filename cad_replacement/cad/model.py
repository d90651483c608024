"""The CAD model type shared by procedural, imported and exported models: links, joints, kinematics.

Canonical frame (every ``CadModel``): z up, front = +x (the side a user faces: doors open towards
+x, drawers slide along +x), +y = z cross x: the model's own left, i.e. the right-hand side of a
viewer standing in front of it.
The origin is the bottom centre of the model's axis-aligned bounding box in the closed
configuration (all joints at ``zero_configuration()``, which is 0 for procedural models).
The root link frame is the model frame; each other link has its own frame (its mesh is expressed
in it) and hangs off its parent through exactly one joint.

A joint's ``origin`` maps the joint frame into the parent link frame; the child link frame equals
the joint frame moved by the joint motion (rotation about / translation along ``axis``, both
given in the joint frame) -- the URDF convention, so export/import are one-to-one.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from cad_replacement.cad.feature_types import ModelFeatures
from cad_replacement.collision import transform_inertial, transform_shapes
from recon_core.geometry.transforms import as_mesh, invert_rigid, is_rigid
from recon_core.kinematic_tree import CollisionShape, Inertial, Joint

#: Joint types a CAD model may contain (a scene adds floating joints for movable objects).
CAD_JOINT_TYPES: tuple[str, ...] = ("revolute", "prismatic", "fixed")
ParamValue = float | int | str
RGBA = tuple[float, float, float, float]


#: Collision shapes of a link, or a zero-argument function that computes them on first use.
CollisionSource = tuple[CollisionShape, ...] | Callable[[], tuple[CollisionShape, ...] | None] | None


class Link:
    """A rigid part; ``mesh`` is expressed in the link frame (procedural links are watertight).

    ``collisions`` (primitives or convex pieces in the link frame) and ``inertial`` are optional:
    procedural builders know their primitives, imported assets may carry both; an exporter
    derives what is missing.

    Collisions may be given as a function: matching and alignment build and scale dozens of
    candidate models per object but only the chosen one is ever collided or exported, so the
    shapes (box CSG, cup rings, re-mapped convex pieces) are computed on first access and kept.
    """

    __slots__ = ("_collision_fn", "_collisions", "color", "inertial", "mesh", "name")

    def __init__(self, name: str, mesh: trimesh.Trimesh, color: RGBA | None = None,
                 collisions: CollisionSource = None, inertial: Inertial | None = None) -> None:
        if not name:
            raise ValueError("link name must be non-empty")
        if not isinstance(mesh, trimesh.Trimesh):
            raise TypeError(f"link {name!r}: mesh must be a trimesh.Trimesh")
        self.name = name
        self.mesh = mesh
        self.color = color
        self.inertial = inertial
        self._collision_fn = collisions if callable(collisions) else None
        self._collisions = None if callable(collisions) else collisions

    @property
    def collisions(self) -> tuple[CollisionShape, ...] | None:
        if self._collision_fn is not None:
            self._collisions = self._collision_fn()
            self._collision_fn = None
        return self._collisions

    @property
    def has_collisions(self) -> bool:
        """Whether collision shapes exist or will be computed (without computing them)."""
        return self._collision_fn is not None or self._collisions is not None

    def with_inertial(self, inertial: Inertial | None) -> Link:
        """The same link with another inertial (collisions still computed at most once, lazily)."""
        out = Link(self.name, self.mesh, self.color, None, inertial)
        out._collisions, out._collision_fn = self._collisions, self._collision_fn
        return out

    def __repr__(self) -> str:
        return f"Link(name={self.name!r}, faces={len(self.mesh.faces)})"


def join_link_meshes(posed: Mapping[str, trimesh.Trimesh]) -> trimesh.Trimesh:
    """Link meshes already in one frame (``CadModel.posed_link_meshes``) as one mesh, concatenated, not unioned."""
    meshes = [m for m in posed.values() if len(m.faces)]
    if not meshes:
        return trimesh.Trimesh()
    return as_mesh(trimesh.util.concatenate(meshes))


@dataclass(frozen=True, eq=False)
class CadModel:
    """A (possibly articulated) CAD model in its canonical frame with its matching features."""

    class_name: str
    model_id: str
    links: tuple[Link, ...]
    joints: tuple[Joint, ...]
    features: ModelFeatures
    params: Mapping[str, ParamValue] = field(default_factory=dict)
    source: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "links", tuple(self.links))
        object.__setattr__(self, "joints", tuple(self.joints))
        object.__setattr__(self, "params", dict(self.params))
        names = [lk.name for lk in self.links]
        if not names:
            raise ValueError(f"model {self.model_id!r} has no links")
        if len(set(names)) != len(names):
            raise ValueError(f"model {self.model_id!r}: duplicate link names {names}")
        joint_names = [j.name for j in self.joints]
        if len(set(joint_names)) != len(joint_names):
            raise ValueError(f"model {self.model_id!r}: duplicate joint names {joint_names}")
        known = set(names)
        children: dict[str, Joint] = {}
        for j in self.joints:
            if j.type not in CAD_JOINT_TYPES:
                raise ValueError(f"joint {j.name!r}: a CAD model's joints are {CAD_JOINT_TYPES}, got {j.type!r}")
            for end in (j.parent, j.child):
                if end not in known:
                    raise ValueError(f"joint {j.name!r} refers to unknown link {end!r}")
            if j.child in children:
                raise ValueError(f"link {j.child!r} has two parent joints")
            children[j.child] = j
        roots = [n for n in names if n not in children]
        if len(roots) != 1:
            raise ValueError(f"model {self.model_id!r} must have exactly one root link, got {roots}")
        # Breadth-first order from the root: also proves the joint graph is a connected tree.
        order: list[Joint] = []
        frontier = [roots[0]]
        by_parent: dict[str, list[Joint]] = {}
        for j in self.joints:
            by_parent.setdefault(j.parent, []).append(j)
        while frontier:
            nxt = []
            for parent in frontier:
                for j in by_parent.get(parent, []):
                    order.append(j)
                    nxt.append(j.child)
            frontier = nxt
        if len(order) != len(self.joints):
            raise ValueError(f"model {self.model_id!r}: joints form a cycle or are disconnected")
        object.__setattr__(self, "_root", roots[0])
        object.__setattr__(self, "_order", tuple(order))

    # ------------------------------------------------------------------ structure
    @property
    def root_link(self) -> str:
        return self._root  # type: ignore[attr-defined]

    @property
    def size(self) -> NDArray[np.float64]:
        """Overall extents (x, y, z) = (depth, width, height) in the closed configuration."""
        return self.features.box_size

    @property
    def movable_joints(self) -> tuple[Joint, ...]:
        return tuple(j for j in self.joints if j.movable)

    @property
    def is_articulated(self) -> bool:
        return bool(self.movable_joints)

    def link(self, name: str) -> Link:
        for lk in self.links:
            if lk.name == name:
                return lk
        raise KeyError(f"model {self.model_id!r} has no link {name!r}")

    def joint(self, name: str) -> Joint:
        for j in self.joints:
            if j.name == name:
                return j
        raise KeyError(f"model {self.model_id!r} has no joint {name!r}")

    def zero_configuration(self) -> dict[str, float]:
        """Joint values of the closed configuration (the one the canonical frame refers to)."""
        return {j.name: j.zero_value for j in self.movable_joints}

    # ------------------------------------------------------------------ kinematics
    def link_poses(self, joint_values: Mapping[str, float] | None = None) -> dict[str, NDArray[np.float64]]:
        """Pose of every link frame in the model frame.

        Joints missing from ``joint_values`` take their zero value; values are clipped to the
        limits (so optimisers may overshoot safely); unknown joint names raise ``KeyError``.
        """
        values = self.zero_configuration()
        for name, value in (joint_values or {}).items():
            if name not in values:
                movable = sorted(values)
                raise KeyError(f"model {self.model_id!r}: no movable joint {name!r} (has {movable})")
            values[name] = float(value)
        poses = {self.root_link: np.eye(4)}
        for j in self._order:  # type: ignore[attr-defined]
            poses[j.child] = poses[j.parent] @ j.transform(values.get(j.name, 0.0))
        return poses

    def posed_link_meshes(self, joint_values: Mapping[str, float] | None = None) -> dict[str, trimesh.Trimesh]:
        """Copies of the link meshes moved into the model frame at ``joint_values``."""
        poses = self.link_poses(joint_values)
        out = {}
        for lk in self.links:
            m = lk.mesh.copy()
            m.apply_transform(poses[lk.name])
            out[lk.name] = m
        return out

    def mesh(self, joint_values: Mapping[str, float] | None = None) -> trimesh.Trimesh:
        """Whole-object mesh (links concatenated, not unioned) in the model frame."""
        return join_link_meshes(self.posed_link_meshes(joint_values))

    def surface_motion(self, link: str, joint_values: Mapping[str, float] | None = None) -> NDArray[np.float64]:
        """Transform moving things attached to ``link`` from the closed to the given configuration.

        Support surfaces are stored at the closed configuration; a drawer's surface at joint values
        ``q`` is ``surface_motion(drawer, q) @ point``.
        """
        zero = self.link_poses()[link]
        return self.link_poses(joint_values)[link] @ invert_rigid(zero)

    # ------------------------------------------------------------------ variants
    def with_features(self, features: ModelFeatures) -> CadModel:
        return dataclasses.replace(self, features=features)

    def scaled(self, factors: ArrayLike | float) -> CadModel:
        """A copy scaled by ``diag(factors)`` about the model origin (bottom centre stays put).

        Uniform factors give the paper's scaled candidates; per-axis factors fit a target box.
        Link frames stay rigid: each link's geometry absorbs the affine map
        ``inv(P'_i) S P_i`` where ``P_i``/``P'_i`` are its closed-configuration poses before/after.
        """
        s = np.broadcast_to(np.asarray(factors, dtype=np.float64), (3,)).copy()
        if np.any(~np.isfinite(s)) or np.any(s <= 0.0):
            raise ValueError(f"scale factors must be positive and finite, got {s.tolist()}")
        scale = np.diag(np.append(s, 1.0))
        old = self.link_poses()
        new = {self.root_link: np.eye(4)}
        joints = []
        for j in self._order:  # type: ignore[attr-defined]
            frame = old[j.parent] @ j.origin  # joint frame in the model frame, closed config
            frame_new = frame.copy()
            frame_new[:3, 3] = s * frame[:3, 3]
            axis_world = s * (frame[:3, :3] @ j.axis)
            stretch = float(np.linalg.norm(axis_world))
            axis = frame[:3, :3].T @ (axis_world / stretch)
            lower, upper = (j.lower * stretch, j.upper * stretch) if j.type == "prismatic" else (j.lower, j.upper)
            nj = Joint(
                name=j.name,
                type=j.type,
                parent=j.parent,
                child=j.child,
                origin=invert_rigid(new[j.parent]) @ frame_new,
                axis=axis,
                lower=lower,
                upper=upper,
            )
            joints.append(nj)
            new[j.child] = new[j.parent] @ nj.transform(nj.zero_value)
        links = []
        for lk in self.links:
            affine = invert_rigid(new[lk.name]) @ scale @ old[lk.name]
            m = lk.mesh.copy()
            m.apply_transform(affine)
            links.append(_mapped_link(lk, m, affine))
        order_index = {j.name: i for i, j in enumerate(self.joints)}
        joints.sort(key=lambda jt: order_index[jt.name])
        return CadModel(
            class_name=self.class_name,
            model_id=self.model_id,
            links=tuple(links),
            joints=tuple(joints),
            features=self.features.scaled(s),
            params=self.params,
            source=self.source,
        )

    def reframed(self, transform: ArrayLike) -> CadModel:
        """The same object expressed in a new model frame: ``p_new = transform @ p_old`` (rigid).

        The root link's geometry and the origins of joints leaving the root absorb the transform;
        other links keep their local geometry. Planes and support surfaces are not carried over
        (only the bounding box is recomputed): recompute features afterwards.
        """
        g = np.asarray(transform, dtype=np.float64)
        if not is_rigid(g):
            raise ValueError("reframed() needs a rigid 4x4 transform")
        links = []
        for lk in self.links:
            if lk.name == self.root_link:
                m = lk.mesh.copy()
                m.apply_transform(g)
                links.append(_mapped_link(lk, m, g))
            else:
                links.append(lk)
        joints = [dataclasses.replace(j, origin=g @ j.origin) if j.parent == self.root_link else j for j in self.joints]
        draft = dataclasses.replace(self, links=tuple(links), joints=tuple(joints))
        return draft.with_features(bounding_box_features(draft.mesh()))


def _mapped_link(link: Link, mesh: trimesh.Trimesh, affine: NDArray[np.float64]) -> Link:
    """``link`` with its geometry mapped by ``affine``: the new mesh, collisions and inertial follow.

    Boxes scaled along their axes stay boxes, otherwise shapes become convex mesh pieces
    (``transform_shapes``); the inertial keeps its density (``transform_inertial``).
    """
    collisions: CollisionSource = None
    if link.has_collisions:
        def collisions() -> tuple[CollisionShape, ...] | None:  # lazily: see ``Link``
            shapes = link.collisions
            return None if shapes is None else transform_shapes(shapes, affine)
    inertial = None if link.inertial is None else transform_inertial(link.inertial, affine)
    return Link(name=link.name, mesh=mesh, color=link.color, collisions=collisions, inertial=inertial)


def bounding_box_features(mesh: trimesh.Trimesh) -> ModelFeatures:
    """Box-only features (no planes/surfaces) of a mesh; a zero box for an empty mesh."""
    if len(mesh.vertices) == 0:
        return ModelFeatures(box_center=np.zeros(3), box_size=np.zeros(3))
    lo, hi = mesh.bounds
    return ModelFeatures(box_center=0.5 * (lo + hi), box_size=hi - lo)
