"""Room layout generation: which CAD models stand where, on what, and in which joint state.

Rules, in order (each placement is checked against everything placed before, in 2D footprints
built from the *posed* meshes, so an ajar door also claims its space):
1. the room: floor, four walls, optional ceiling (boxes around an axis-aligned interior);
2. furniture with a back (fridge, cabinet, shelf, sofa, ...) against a wall, front to the room;
3. tables in the free interior, chairs around them facing the table;
4. small objects (cup, bottle, book, monitor, microwave, box, bag) on the support surfaces of
   furniture (table tops, shelf levels, cabinet tops and insides, desks), stacked books/boxes,
   or on the floor (bags, boxes).
Every placed object records its support parent, so the ground-truth contact graph follows.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely
import trimesh
from shapely.geometry import Polygon
from shapely.geometry import box as shapely_box
from shapely.prepared import prep

from cad_replacement.cad.model import CadModel
from cad_replacement.cad.procedural import build_model


@dataclass
class LayoutConfig:
    """Tunables of the layout rules (defaults give varied, furnished rooms)."""

    room_size_min: tuple[float, float] = (4.0, 3.5)
    room_size_max: tuple[float, float] = (7.0, 6.0)
    wall_height: tuple[float, float] = (2.5, 3.0)
    wall_thickness: float = 0.1
    floor_thickness: float = 0.05
    ceiling: bool = False
    #: Share of the requested objects that are furniture (the rest are small objects on them).
    furniture_share: float = 0.4
    #: Probability that an articulated object is left ajar, and the opened share of its range.
    ajar_probability: float = 0.35
    ajar_range: tuple[float, float] = (0.25, 0.8)
    #: Gap kept between footprints and to walls (m): no interpenetration, contact-like spacing.
    gap: float = 0.01
    #: Clear space kept in front of furniture with doors (m), so doors can open.
    front_clearance: float = 0.05
    #: Probability that a book or box gets another one stacked on top.
    stack_probability: float = 0.3
    placement_attempts: int = 40
    wall_classes: tuple[str, ...] = (
        "fridge", "cabinet", "wardrobe", "shelf", "sofa", "bed", "desk", "oven", "dishwasher",
    )
    wall_class_weights: tuple[float, ...] = (1.0, 1.5, 0.7, 1.5, 0.8, 0.5, 1.2, 0.6, 0.5)
    small_classes: tuple[str, ...] = ("cup", "bottle", "book", "monitor", "microwave", "box", "bag")
    small_class_weights: tuple[float, ...] = (1.5, 1.2, 1.5, 0.5, 0.5, 0.7, 0.5)
    #: Which parents a small class may stand on ("floor" allowed for bags and boxes).
    small_parents: dict[str, list[str]] = field(default_factory=lambda: {
        "cup": ["table", "desk", "cabinet", "shelf", "dishwasher"],
        "bottle": ["table", "desk", "cabinet", "shelf", "fridge"],
        "book": ["shelf", "desk", "table", "cabinet", "book"],
        "monitor": ["desk", "table"],
        "microwave": ["cabinet", "table", "desk", "dishwasher"],
        "box": ["shelf", "table", "floor", "cabinet", "wardrobe", "box"],
        "bag": ["floor", "bed", "sofa"],
    })


@dataclass
class PlacedObject:
    """One object of the generated room (layout elements have no CAD model)."""

    name: str
    class_name: str
    pose: np.ndarray  # model frame -> map (yaw + translation)
    model: CadModel | None = None
    joint_values: dict[str, float] = field(default_factory=dict)
    parent: str = ""
    #: Link of the parent that carries this object (a drawer, a shelf body); "" for the root link.
    parent_link: str = ""
    layout_mesh: trimesh.Trimesh | None = None  # floor / wall / ceiling geometry in the map frame
    seed: int = 0

    def mesh(self) -> trimesh.Trimesh:
        """The object's mesh in the map frame at its joint values."""
        if self.layout_mesh is not None:
            return self.layout_mesh
        mesh = self.model.mesh(self.joint_values).copy()
        mesh.apply_transform(self.pose)
        return mesh


@dataclass
class _Surface:
    owner: str
    owner_class: str
    height: float
    polygon: Polygon
    clearance: float | None
    link: str = ""
    occupied: list[Polygon] = field(default_factory=list)


def yaw_pose(x: float, y: float, z: float, yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    pose = np.eye(4)
    pose[:2, :2] = [[c, -s], [s, c]]
    pose[:3, 3] = [x, y, z]
    return pose


def footprint(mesh: trimesh.Trimesh) -> Polygon:
    """Convex hull of the mesh's vertices projected on the floor plane."""
    return shapely.convex_hull(shapely.MultiPoint(np.asarray(mesh.vertices)[:, :2]))


class RoomLayout:
    """Generates one furnished room; deterministic for a seed."""

    def __init__(self, config: LayoutConfig | None = None):
        self.config = config or LayoutConfig()

    # ------------------------------------------------------------------ room
    def _room(self, rng: np.random.Generator) -> tuple[list[PlacedObject], tuple[float, float, float]]:
        c = self.config
        width = float(rng.uniform(c.room_size_min[0], c.room_size_max[0]))
        depth = float(rng.uniform(c.room_size_min[1], c.room_size_max[1]))
        height = float(rng.uniform(*c.wall_height))
        t, ft = c.wall_thickness, c.floor_thickness
        hx, hy = width / 2, depth / 2

        def slab(lo, hi):
            lo, hi = np.asarray(lo, float), np.asarray(hi, float)
            m = trimesh.creation.box(extents=hi - lo)
            m.apply_translation((lo + hi) / 2)
            return m

        floor = slab([-hx - t, -hy - t, -ft], [hx + t, hy + t, 0])
        items = [PlacedObject("floor", "floor", np.eye(4), layout_mesh=floor, parent="scene")]
        walls = [
            ("wall_west", [-hx - t, -hy - t, 0], [-hx, hy + t, height]),
            ("wall_east", [hx, -hy - t, 0], [hx + t, hy + t, height]),
            ("wall_south", [-hx, -hy - t, 0], [hx, -hy, height]),
            ("wall_north", [-hx, hy, 0], [hx, hy + t, height]),
        ]
        for name, lo, hi in walls:
            items.append(PlacedObject(name, "wall", np.eye(4), layout_mesh=slab(lo, hi), parent="floor"))
        if c.ceiling:
            items.append(PlacedObject("ceiling", "ceiling", np.eye(4),
                                      layout_mesh=slab([-hx - t, -hy - t, height], [hx + t, hy + t, height + ft]),
                                      parent="wall_west"))
        return items, (width, depth, height)

    # ------------------------------------------------------------------ helpers
    def _joint_values(self, model: CadModel, rng: np.random.Generator) -> dict[str, float]:
        values = model.zero_configuration()
        if model.is_articulated and rng.uniform() < self.config.ajar_probability:
            lo, hi = self.config.ajar_range
            for j in model.movable_joints:
                if rng.uniform() < 0.7:
                    frac = rng.uniform(lo, hi)
                    values[j.name] = float(j.lower + frac * (j.upper - j.lower)) if j.lower >= 0 or j.upper <= 0 \
                        else float(frac * (j.upper if abs(j.upper) >= abs(j.lower) else j.lower))
        return values

    def _posed(self, model: CadModel, pose: np.ndarray, values: dict[str, float]) -> trimesh.Trimesh:
        mesh = model.mesh(values).copy()
        mesh.apply_transform(pose)
        return mesh

    # ------------------------------------------------------------------ generate
    def generate(self, num_objects: int, seed: int) -> tuple[list[PlacedObject], tuple[float, float, float]]:
        """Place about `num_objects` objects (furniture + small ones) in a new room."""
        c = self.config
        rng = np.random.default_rng(seed)
        items, (width, depth, height) = self._room(rng)
        hx, hy = width / 2, depth / 2
        interior = shapely_box(-hx + c.gap, -hy + c.gap, hx - c.gap, hy - c.gap)
        taken: list[Polygon] = []
        surfaces: list[_Surface] = []
        counts: dict[str, int] = {}

        def new_name(cls: str) -> str:
            counts[cls] = counts.get(cls, 0) + 1
            return f"{cls}_{counts[cls]}"

        def fits(poly: Polygon) -> bool:
            if not interior.contains(poly):
                return False
            grown = poly.buffer(c.gap / 2)
            return not any(grown.intersects(p) for p in taken)

        def add_surfaces(obj: PlacedObject) -> None:
            for s in obj.model.features.support_surfaces:
                motion = obj.model.surface_motion(s.link, obj.joint_values)
                t = obj.pose @ motion
                pts = np.c_[s.polygon, np.full(len(s.polygon), s.height), np.ones(len(s.polygon))] @ t.T
                poly = Polygon(pts[:, :2]).buffer(0)
                if poly.area > 0.005:
                    surfaces.append(_Surface(obj.name, obj.class_name, float(pts[0, 2]), poly, s.clearance,
                                             link=s.link))

        n_furniture = max(1, round(num_objects * c.furniture_share)) if num_objects > 0 else 0
        n_small = max(num_objects - n_furniture, 0)
        placed_furniture = 0

        # tables first (they carry most small objects), at least one when small objects are asked for
        n_tables = 1 if n_furniture >= 2 or n_small else 0
        n_tables += int(n_furniture >= 6 and rng.uniform() < 0.5)
        wall_p = np.asarray(c.wall_class_weights, float)
        wall_p /= wall_p.sum()
        plan = ["table"] * n_tables
        while len(plan) < n_furniture:
            plan.append(str(rng.choice(c.wall_classes, p=wall_p)))
        for cls in plan:
            if placed_furniture >= n_furniture:
                break
            model_seed = int(rng.integers(2**31))
            model = build_model(cls, model_seed)
            values = self._joint_values(model, rng)
            sx, sy, _ = model.size
            for _attempt in range(c.placement_attempts):
                if cls == "table":
                    yaw = float(rng.choice([0.0, np.pi / 2]) + rng.normal(0, 0.05))
                    x = rng.uniform(-hx + 0.8, hx - 0.8) if hx > 0.8 else 0.0
                    y = rng.uniform(-hy + 0.8, hy - 0.8) if hy > 0.8 else 0.0
                else:
                    wall = int(rng.integers(4))
                    along = (hy if wall < 2 else hx) - sy / 2 - c.gap
                    if along <= 0:
                        continue
                    u = rng.uniform(-along, along)
                    off = sx / 2 + c.gap * 1.5
                    x, y, yaw = [(-hx + off, u, 0.0), (hx - off, u, np.pi), (u, -hy + off, np.pi / 2),
                                 (u, hy - off, -np.pi / 2)][wall]
                pose = yaw_pose(x, y, 0.0, yaw)
                fp = footprint(self._posed(model, pose, values))
                check = fp
                if model.is_articulated and cls != "table":  # keep room in front so doors can open
                    check = fp.union(footprint(self._posed(model, pose @ yaw_pose(c.front_clearance, 0, 0, 0),
                                                           values)))
                if fits(check):
                    obj = PlacedObject(new_name(cls), cls, pose, model, values, parent="floor", seed=model_seed)
                    items.append(obj)
                    taken.append(fp)
                    add_surfaces(obj)
                    placed_furniture += 1
                    if cls == "table":
                        budget = n_furniture - placed_furniture - (len(plan) - plan.index(cls) - 1 > 0)
                        placed_furniture += self._chairs(obj, rng, items, taken, fits, new_name, add_surfaces,
                                                         max(budget, 0))
                    break

        # small objects on surfaces (or the floor)
        small_p = np.asarray(c.small_class_weights, float)
        small_p /= small_p.sum()
        floor_surface = _Surface("floor", "floor", 0.0, interior, None)
        placed_small = 0
        tries = 0
        while placed_small < n_small and tries < n_small * 6:
            tries += 1
            cls = str(rng.choice(c.small_classes, p=small_p))
            allowed = c.small_parents.get(cls, [])
            cands = [s for s in surfaces if s.owner_class in allowed]
            if "floor" in allowed:
                cands.append(floor_surface)
            if not cands:
                continue
            surf = cands[int(rng.integers(len(cands)))]
            model_seed = int(rng.integers(2**31))
            model = build_model(cls, model_seed)
            obj = self._place_on(surf, cls, model, model_seed, rng, taken, fits, new_name)
            if obj is None:
                continue
            items.append(obj)
            placed_small += 1
            if cls in ("book", "box") and rng.uniform() < c.stack_probability:
                add_surfaces(obj)  # something may be stacked on it later
        return items, (width, depth, height)

    def _chairs(self, table: PlacedObject, rng, items, taken, fits, new_name, add_surfaces, budget: int) -> int:
        """Place up to min(4, budget) chairs around `table`, each facing it; returns how many were placed."""
        n = min(int(rng.integers(0, 5)), budget)
        placed = 0
        tx, ty = table.pose[:2, 3]
        tyaw = np.arctan2(table.pose[1, 0], table.pose[0, 0])
        sx, sy, _ = table.model.size
        sides = rng.permutation(4)[:n]
        for side in sides:
            model_seed = int(rng.integers(2**31))
            model = build_model("chair", model_seed)
            cx = model.size[0]
            dist = (sx if side < 2 else sy) / 2 + cx / 2 + 0.05
            ang = tyaw + side * np.pi / 2
            x, y = tx + dist * np.cos(ang), ty + dist * np.sin(ang)
            pose = yaw_pose(x, y, 0.0, ang + np.pi)  # chair front (+x) faces the table
            fp = footprint(self._posed(model, pose, {}))
            if fits(fp):
                obj = PlacedObject(new_name("chair"), "chair", pose, model, model.zero_configuration(), "floor",
                                   seed=model_seed)
                items.append(obj)
                taken.append(fp)
                add_surfaces(obj)
                placed += 1
        return placed

    def _place_on(self, surf: _Surface, cls: str, model: CadModel, model_seed: int, rng, taken, fits,
                  new_name) -> PlacedObject | None:
        c = self.config
        size = model.size
        if surf.clearance is not None and size[2] + c.gap > surf.clearance:
            return None
        values = model.zero_configuration()
        minx, miny, maxx, maxy = surf.polygon.bounds
        inner = surf.polygon.buffer(-0.01)
        if inner.is_empty:
            return None
        prepared = prep(inner)
        for _attempt in range(c.placement_attempts):
            x, y = rng.uniform(minx, maxx), rng.uniform(miny, maxy)
            yaw = float(rng.uniform(-np.pi, np.pi))
            pose = yaw_pose(x, y, surf.height, yaw)
            fp = footprint(self._posed(model, pose, values))
            if not prepared.contains(fp):
                continue
            grown = fp.buffer(c.gap / 2)
            if any(grown.intersects(o) for o in surf.occupied):
                continue
            if surf.owner == "floor" and not fits(fp):
                continue
            surf.occupied.append(fp)
            if surf.owner == "floor":
                taken.append(fp)
            return PlacedObject(new_name(cls), cls, pose, model, values, parent=surf.owner, parent_link=surf.link,
                                seed=model_seed)
        return None
