"""Turn a part list (axis-aligned boxes/cylinders per link) into a ``CadModel``.

Procedural builders describe every part directly in *model* coordinates at the closed
configuration (which is what a designer thinks in: "the door covers the front"); joints are given
by an anchor point and an axis. ``Assembly.build`` then

1. recentres everything so the bounding box's bottom centre is the origin,
2. gives each non-root link a frame at its joint anchor (identity rotation at the closed pose),
3. unions each link's parts exactly with manifold3d (watertight, correct volume), subtracting the
   ``cut`` parts (cup cavities),
4. records each link's collision shapes from its parts (``part_collisions``: the boxes decomposed
   exactly by box CSG, cylinders kept as cylinders, a coaxial cylinder cut as a ring of convex
   prisms), so a hollow carcass never collides as its convex hull, and
5. derives the matching features analytically from the parts (see ``_analytic_planes``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import manifold3d as m3
import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from cad_replacement.cad.feature_types import ModelFeatures, Plane, SupportSurface, merge_planes
from cad_replacement.cad.model import CadModel, Joint, Link, ParamValue
from cad_replacement.collision import box_csg, box_shape, cylinder_shape, mesh_collisions, ring_pieces
from recon_core.geometry.transforms import translation
from recon_core.kinematic_tree import CollisionShape, JointType

#: Segments of every procedural cylinder; a multiple of 4 puts vertices on the +-x/+-y extremes,
#: so mesh bounding boxes equal the analytic ones.
CYLINDER_SEGMENTS = 32
#: A bounding-box side becomes a feature plane when parts cover at least this fraction of it.
MIN_FACE_COVERAGE = 0.3
#: Geometric tolerance (m) for "part face lies on the bounding-box face".
FACE_TOL = 1e-6

_AXES = {"x": 0, "y": 1, "z": 2}


@dataclass(frozen=True)
class Box:
    """Axis-aligned box ``lo..hi`` (model coordinates while building)."""

    lo: NDArray[np.float64]
    hi: NDArray[np.float64]
    cut: bool = False

    def bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return self.lo, self.hi

    def shifted(self, offset: NDArray[np.float64]) -> Box:
        return Box(self.lo + offset, self.hi + offset, self.cut)

    def manifold(self) -> m3.Manifold:
        return m3.Manifold.cube((self.hi - self.lo).tolist(), center=False).translate(self.lo.tolist())


@dataclass(frozen=True)
class Cylinder:
    """Cylinder of ``radius`` and ``length`` centred at ``center`` along coordinate axis ``axis``."""

    center: NDArray[np.float64]
    radius: float
    length: float
    axis: int = 2
    cut: bool = False

    def bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        half = np.full(3, self.radius)
        half[self.axis] = 0.5 * self.length
        return self.center - half, self.center + half

    def shifted(self, offset: NDArray[np.float64]) -> Cylinder:
        return Cylinder(self.center + offset, self.radius, self.length, self.axis, self.cut)

    def manifold(self) -> m3.Manifold:
        c = m3.Manifold.cylinder(self.length, self.radius, -1.0, CYLINDER_SEGMENTS, True)
        if self.axis == 0:
            c = c.rotate([0.0, 90.0, 0.0])
        elif self.axis == 1:
            c = c.rotate([-90.0, 0.0, 0.0])
        return c.translate(self.center.tolist())


Primitive = Box | Cylinder


def _check_dims(lo: NDArray[np.float64], hi: NDArray[np.float64], what: str) -> None:
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi - lo > 1e-6)):
        raise ValueError(f"{what}: degenerate part lo={lo.tolist()} hi={hi.tolist()}")


@dataclass
class LinkBuilder:
    """Collects the parts of one link (model coordinates, closed configuration)."""

    name: str
    color: tuple[float, float, float, float] | None = None
    parts: list[Primitive] = field(default_factory=list)

    def box(self, lo: ArrayLike, hi: ArrayLike, *, cut: bool = False) -> LinkBuilder:
        lo_a = np.asarray(lo, dtype=np.float64).reshape(3)
        hi_a = np.asarray(hi, dtype=np.float64).reshape(3)
        lo_a, hi_a = np.minimum(lo_a, hi_a), np.maximum(lo_a, hi_a)
        _check_dims(lo_a, hi_a, f"link {self.name!r} box")
        self.parts.append(Box(lo_a, hi_a, cut))
        return self

    def cylinder(
        self, center: ArrayLike, radius: float, length: float, axis: str = "z", *, cut: bool = False
    ) -> LinkBuilder:
        c = np.asarray(center, dtype=np.float64).reshape(3)
        if not (radius > 1e-6 and length > 1e-6):
            raise ValueError(f"link {self.name!r}: degenerate cylinder r={radius} l={length}")
        self.parts.append(Cylinder(c, float(radius), float(length), _AXES[axis], cut))
        return self


@dataclass(frozen=True)
class JointSpec:
    name: str
    type: JointType
    parent: str
    child: str
    anchor: NDArray[np.float64]
    axis: NDArray[np.float64]
    lower: float
    upper: float


@dataclass(frozen=True)
class SupportSpec:
    height: float
    polygon: NDArray[np.float64]
    clearance: float | None
    link: str
    enclosed: bool


def rectangle(x0: float, x1: float, y0: float, y1: float) -> NDArray[np.float64]:
    """Counter-clockwise rectangle outline."""
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64)


def circle(cx: float, cy: float, radius: float, segments: int = CYLINDER_SEGMENTS) -> NDArray[np.float64]:
    """Counter-clockwise polygon matching the procedural cylinder tessellation."""
    t = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    return np.stack([cx + radius * np.cos(t), cy + radius * np.sin(t)], axis=1)


class Assembly:
    """Builder-side description of one model; the first link added is the root."""

    def __init__(self, class_name: str) -> None:
        self.class_name = class_name
        self._links: dict[str, LinkBuilder] = {}
        self._joints: list[JointSpec] = []
        self._supports: list[SupportSpec] = []

    @property
    def root(self) -> str:
        return next(iter(self._links))

    @property
    def joints(self) -> tuple[JointSpec, ...]:
        """The joints declared so far (no geometry is built to know them)."""
        return tuple(self._joints)

    def link(self, name: str, color: tuple[float, float, float, float] | None = None) -> LinkBuilder:
        if name in self._links:
            raise ValueError(f"duplicate link {name!r}")
        lb = LinkBuilder(name, color)
        self._links[name] = lb
        return lb

    def joint(
        self,
        name: str,
        type: JointType,
        parent: str,
        child: str,
        anchor: ArrayLike,
        axis: ArrayLike = (0.0, 0.0, 1.0),
        lower: float = 0.0,
        upper: float = 0.0,
    ) -> None:
        """Connect ``child`` to ``parent``; ``anchor`` (model coords) becomes the child frame origin."""
        self._joints.append(
            JointSpec(
                name,
                type,
                parent,
                child,
                np.asarray(anchor, dtype=np.float64).reshape(3),
                np.asarray(axis, dtype=np.float64).reshape(3),
                float(lower),
                float(upper),
            )
        )

    def support(
        self,
        height: float,
        polygon: ArrayLike,
        *,
        clearance: float | None = None,
        link: str | None = None,
        enclosed: bool = False,
    ) -> None:
        """Declare a horizontal support surface (model coords, closed configuration)."""
        self._supports.append(
            SupportSpec(
                float(height),
                np.asarray(polygon, dtype=np.float64).reshape(-1, 2),
                None if clearance is None else max(0.0, float(clearance)),
                link if link is not None else self.root,
                enclosed,
            )
        )

    # ------------------------------------------------------------------ build
    def _bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """The additive parts' bounding box (model coordinates) and the shift that recentres it."""
        adds = [p for lb in self._links.values() for p in lb.parts if not p.cut]
        if not adds:
            raise ValueError(f"{self.class_name}: assembly has no parts")
        lo = np.min([p.bounds()[0] for p in adds], axis=0)
        hi = np.max([p.bounds()[1] for p in adds], axis=0)
        shift = -np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), lo[2]])
        return lo, hi, shift

    def _features(self, lo: NDArray[np.float64], hi: NDArray[np.float64], shift: NDArray[np.float64]) -> ModelFeatures:
        """The matching features, from the parts alone (no mesh)."""
        parts = [p.shifted(shift) for lb in self._links.values() for p in lb.parts]
        supports = [
            SupportSurface(
                height=s.height + shift[2],
                polygon=s.polygon + shift[:2],
                clearance=s.clearance,
                link=s.link,
                enclosed=s.enclosed,
            )
            for s in self._supports
        ]
        box_lo, box_hi = lo + shift, hi + shift
        planes = _analytic_planes(parts, box_lo, box_hi) + [s.plane for s in supports if not s.enclosed]
        return ModelFeatures(
            box_center=0.5 * (box_lo + box_hi),
            box_size=box_hi - box_lo,
            planes=tuple(merge_planes(planes)),
            support_surfaces=tuple(supports),
        )

    def features(self) -> ModelFeatures:
        """``build(...).features`` without building a mesh: the features are analytic (the box, the
        covered box sides, the declared supports), the exact unions of the links' parts are what costs
        (12 ms a model; a library's features are needed for every model of a class, its meshes only for
        the few that matching shortlists)."""
        return self._features(*self._bounds())

    def build(self, model_id: str, params: Mapping[str, ParamValue], source: str) -> CadModel:
        lo, hi, shift = self._bounds()

        origins = {self.root: np.zeros(3)}
        for js in self._joints:
            origins[js.child] = js.anchor + shift
        missing = set(self._links) - set(origins)
        if missing:
            raise ValueError(f"{self.class_name}: links without a joint: {sorted(missing)}")

        links = []
        for lb in self._links.values():
            offset = shift - origins[lb.name]
            mesh = _link_mesh(lb, offset, self.class_name)
            links.append(Link(name=lb.name, mesh=mesh, color=lb.color,
                              collisions=_collision_builder([p.shifted(offset) for p in lb.parts], mesh)))
        joints = [
            Joint(
                name=js.name,
                type=js.type,
                parent=js.parent,
                child=js.child,
                origin=translation(origins[js.child] - origins[js.parent]),
                axis=js.axis,
                lower=js.lower,
                upper=js.upper,
            )
            for js in self._joints
        ]
        features = self._features(lo, hi, shift)
        return CadModel(
            class_name=self.class_name,
            model_id=model_id,
            links=tuple(links),
            joints=tuple(joints),
            features=features,
            params=params,
            source=source,
        )


def _collision_builder(parts: Sequence[Primitive], mesh: trimesh.Trimesh) -> Callable[[], tuple[CollisionShape, ...]]:
    """The link's collision shapes, computed on first use (exact primitives, else convex pieces)."""
    def build() -> tuple[CollisionShape, ...]:
        shapes = part_collisions(parts)
        return shapes if shapes is not None else mesh_collisions(mesh)
    return build


def _link_mesh(lb: LinkBuilder, offset: NDArray[np.float64], class_name: str) -> trimesh.Trimesh:
    """Exact union (minus cuts) of a link's parts, moved by ``offset`` into the link frame."""
    adds = [p.shifted(offset).manifold() for p in lb.parts if not p.cut]
    cuts = [p.shifted(offset).manifold() for p in lb.parts if p.cut]
    solid = m3.Manifold.batch_boolean(adds, m3.OpType.Add) if len(adds) > 1 else adds[0]
    if cuts:
        solid = solid - (m3.Manifold.batch_boolean(cuts, m3.OpType.Add) if len(cuts) > 1 else cuts[0])
    out = solid.to_mesh64()
    mesh = trimesh.Trimesh(
        vertices=np.asarray(out.vert_properties, dtype=np.float64)[:, :3],
        faces=np.asarray(out.tri_verts, dtype=np.int64),
        process=False,  # manifold's output is already indexed and 2-manifold; merging could break it
    )
    if not (mesh.is_watertight and mesh.volume > 0.0):
        raise RuntimeError(f"{class_name}: link {lb.name!r} mesh is not a closed positive-volume solid")
    return mesh


def _overlap(a: Primitive, b: Primitive) -> bool:
    """Whether the parts' bounding boxes share interior (touching faces do not count)."""
    alo, ahi = a.bounds()
    blo, bhi = b.bounds()
    return bool(np.all(np.minimum(ahi, bhi) - np.maximum(alo, blo) > FACE_TOL))


def _coaxial(a: Cylinder, b: Cylinder) -> bool:
    off = np.delete(a.center - b.center, a.axis)
    return a.axis == b.axis and bool(np.all(np.abs(off) <= FACE_TOL))


def part_collisions(parts: Sequence[Primitive]) -> tuple[CollisionShape, ...] | None:
    """Exact collision shapes of one link's parts (link frame), or ``None`` when not expressible.

    Boxes (additive minus cut) go through the exact box CSG; an additive cylinder untouched by
    cuts stays a cylinder; one with a single coaxial, narrower cylinder cut (a cup) becomes the
    solid segments outside the cut plus a ring of convex prisms where the cut runs. Cut cylinders
    through boxes, or cut boxes through cylinders, have no exact primitive form: ``None`` (the
    caller then decomposes the mesh into convex pieces).
    """
    box_adds = [p for p in parts if isinstance(p, Box) and not p.cut]
    box_cuts = [p for p in parts if isinstance(p, Box) and p.cut]
    cyl_adds = [p for p in parts if isinstance(p, Cylinder) and not p.cut]
    cyl_cuts = [p for p in parts if isinstance(p, Cylinder) and p.cut]
    if any(_overlap(k, b) for k in cyl_cuts for b in box_adds):
        return None
    shapes: list[CollisionShape] = []
    if box_adds:
        boxes = box_csg([[p.lo, p.hi] for p in box_adds], [[p.lo, p.hi] for p in box_cuts] or None)
        shapes.extend(box_shape(lo, hi) for lo, hi in boxes)
    for cyl in cyl_adds:
        if any(_overlap(cyl, k) for k in box_cuts):
            return None
        cuts = [k for k in cyl_cuts if _overlap(cyl, k)]
        if not cuts:
            shapes.append(cylinder_shape(cyl.center, cyl.radius, cyl.length, cyl.axis))
            continue
        cut = cuts[0]
        if len(cuts) > 1 or not _coaxial(cyl, cut) or cut.radius >= cyl.radius:
            return None
        ax = cyl.axis
        c0, c1 = cyl.center[ax] - 0.5 * cyl.length, cyl.center[ax] + 0.5 * cyl.length
        k0, k1 = max(c0, cut.center[ax] - 0.5 * cut.length), min(c1, cut.center[ax] + 0.5 * cut.length)
        for lo, hi in ((c0, k0), (k1, c1)):
            if hi - lo > FACE_TOL:  # solid end segment (a cup's bottom)
                centre = cyl.center.copy()
                centre[ax] = 0.5 * (lo + hi)
                shapes.append(cylinder_shape(centre, cyl.radius, hi - lo, ax))
        centre = cyl.center.copy()
        centre[ax] = 0.5 * (k0 + k1)
        shapes.extend(ring_pieces(centre, cut.radius, cyl.radius, k1 - k0, ax, CYLINDER_SEGMENTS))
    return tuple(shapes)


def _cross_section(p: Primitive, axis: int) -> float:
    """Area of the part's cross-section perpendicular to coordinate ``axis``."""
    if isinstance(p, Box):
        ext = p.hi - p.lo
        return float(np.prod(np.delete(ext, axis)))
    if p.axis == axis:
        return float(np.pi * p.radius**2)
    return 2.0 * p.radius * p.length


def _analytic_planes(parts: Sequence[Primitive], lo: NDArray[np.float64], hi: NDArray[np.float64]) -> list[Plane]:
    """Sides of the bounding box that the model's surface really covers.

    For each of the six box faces, sum the areas of part faces lying on it (box faces, cylinder
    caps), minus the cross-sections of cut parts crossing it, and keep the face when the covered
    fraction reaches ``MIN_FACE_COVERAGE``. A table's sides are mostly air and drop out; a cabinet
    keeps all six. The plane's ``area`` is the covered area.
    """
    planes = []
    size = hi - lo
    for axis in range(3):
        face_area = float(np.prod(np.delete(size, axis)))
        if face_area <= 0.0:
            continue
        for sign, coord in ((-1.0, lo[axis]), (1.0, hi[axis])):
            covered = 0.0
            for p in parts:
                plo, phi = p.bounds()
                if p.cut:
                    if plo[axis] < coord - FACE_TOL and phi[axis] > coord + FACE_TOL:
                        covered -= _cross_section(p, axis)
                    continue
                on_face = abs((phi[axis] if sign > 0 else plo[axis]) - coord) < FACE_TOL
                if on_face and (isinstance(p, Box) or p.axis == axis):
                    covered += _cross_section(p, axis)
            fraction = min(1.0, covered / face_area)
            if fraction >= MIN_FACE_COVERAGE:
                normal = np.zeros(3)
                normal[axis] = sign
                planes.append(Plane(normal=normal, d=-sign * coord, area=fraction * face_area))
    return planes
