"""A generated scene with exact ground truth: entities, contact graph, URDF, render items.

The ground truth is what every later stage is measured against:
* per entity: label id (the value in the label images), class, category, pose, joint values,
  gravity-aligned oriented box, mesh, support parent (and the parent's link);
* the ground-truth contact graph: support parent of every node, proximal pairs (boxes overlap);
* the ground-truth scene as stage 4's ``ReplacedScene`` (``ground_truth_scene``), exported by the
  same exporter as a reconstruction (``cad_replacement.export``): ``urdf/scene.urdf`` (support
  edges as fixed/floating joints, CAD joints kept), ``urdf/scene.xml`` (MJCF), per-object URDFs.
Saved as a folder (`scene.json` + PLY meshes + `urdf/`), never pickled.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from cad_replacement.cad.model import CadModel, Link, bounding_box_features
from cad_replacement.cad.procedural import build_model
from cad_replacement.collision import box_shape
from cad_replacement.export import ExportResult, export_scene
from cad_replacement.scene_model import MAP_ROOT, PlacedObject, ReplacedScene
from recon_core.classes import load_class_table
from recon_core.entity import Entity
from recon_core.geometry.box import GravityBox
from scene_recon.synthetic.items import Appearance, RenderItem
from scene_recon.synthetic.layout import LayoutConfig, RoomLayout

SCENE_FORMAT_VERSION = 1
ROOT = "scene"


@dataclass
class SceneEntity:
    id: int  # value in the ground-truth label images
    name: str
    class_name: str
    class_id: int
    category: str  # layout / rigid / articulated
    is_thing: bool
    movable: bool
    pose: np.ndarray
    parent: str
    parent_link: str = ""
    joint_values: dict[str, float] = field(default_factory=dict)
    model_seed: int | None = None
    box: GravityBox | None = None
    mesh: trimesh.Trimesh | None = None
    visible_pixels: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id, "name": self.name, "class_name": self.class_name, "class_id": self.class_id,
            "category": self.category, "is_thing": self.is_thing, "movable": self.movable,
            "pose": self.pose.tolist(), "parent": self.parent, "parent_link": self.parent_link,
            "joint_values": self.joint_values, "model_seed": self.model_seed,
            "box": self.box.to_dict() if self.box else None, "mesh_file": f"meshes/{self.name}.ply",
            "visible_pixels": int(self.visible_pixels),
        }


@dataclass
class GroundTruthScene:
    name: str
    seed: int
    room_size: tuple[float, float, float]
    entities: list[SceneEntity]
    proximal: list[tuple[str, str]] = field(default_factory=list)

    # ------------------------------------------------------------------ queries
    def entity(self, name: str) -> SceneEntity:
        for e in self.entities:
            if e.name == name:
                return e
        raise KeyError(f"no entity named {name!r}")

    @property
    def support_edges(self) -> list[tuple[str, str]]:
        """(parent, child) for every entity; the root is "scene"."""
        return [(e.parent, e.name) for e in self.entities]

    def model_of(self, e: SceneEntity):
        return None if e.model_seed is None else build_model(e.class_name, e.model_seed)

    def render_items(self, seed: int = 0) -> list[RenderItem]:
        rng = np.random.default_rng(seed)
        items = []
        for e in self.entities:
            smooth = e.class_name in ("cup", "bottle", "bag")
            items.append(RenderItem(mesh=e.mesh, label=e.id, appearance=Appearance.random(rng, smooth_shading=smooth),
                                    name=e.name))
        return items

    # ------------------------------------------------------------------ replaced scene
    def replaced_scene(self) -> ReplacedScene:
        """The ground truth as stage 4's result (see ``ground_truth_scene``)."""
        return ground_truth_scene(self)

    def export(self, folder: str | Path, *, glb: bool = True) -> ExportResult:
        """Write the ground truth's URDF/MJCF/GLB folder through the stage-4 exporter."""
        return export_scene(self.replaced_scene(), folder, glb=glb)

    # ------------------------------------------------------------------ persistence
    def save(self, folder: str | Path) -> Path:
        folder = Path(folder)
        (folder / "meshes").mkdir(parents=True, exist_ok=True)
        for e in self.entities:
            e.mesh.export(folder / "meshes" / f"{e.name}.ply")
        data = {
            "format_version": SCENE_FORMAT_VERSION, "name": self.name, "seed": self.seed,
            "room_size": list(self.room_size), "map_frame": "map",
            "entities": [e.to_dict() for e in self.entities],
            "support_edges": [{"parent": p, "child": c} for p, c in self.support_edges],
            "proximal_edges": [list(p) for p in self.proximal],
        }
        (folder / "scene.json").write_text(json.dumps(data, indent=1), encoding="utf-8")
        self.export(folder / "urdf")
        return folder / "scene.json"

    @classmethod
    def load(cls, folder: str | Path) -> GroundTruthScene:
        folder = Path(folder)
        f = folder / "scene.json" if folder.is_dir() else folder
        data = json.loads(f.read_text(encoding="utf-8"))
        if data.get("format_version") != SCENE_FORMAT_VERSION:
            raise ValueError(f"{f}: unsupported ground-truth format {data.get('format_version')}")
        entities = []
        for d in data["entities"]:
            mesh = trimesh.load(f.parent / d["mesh_file"], force="mesh", process=False)
            entities.append(SceneEntity(
                d["id"], d["name"], d["class_name"], d["class_id"], d["category"], d["is_thing"], d["movable"],
                np.asarray(d["pose"], float), d["parent"], d.get("parent_link", ""), d.get("joint_values", {}),
                d.get("model_seed"), GravityBox.from_dict(d["box"]) if d.get("box") else None, mesh,
                d.get("visible_pixels", 0)))
        return cls(data["name"], data["seed"], tuple(data["room_size"]), entities,
                   [tuple(p) for p in data.get("proximal_edges", [])])


def layout_model(e: SceneEntity) -> CadModel:
    """A layout element (floor, wall, ceiling: a box slab) as a one-link CAD model with a box collision.

    The slab keeps the entity's own frame (its pose, the identity for generated rooms), so the
    exported link pose equals the ground-truth pose; the collision is the mesh's bounding box,
    exact for the generator's axis-aligned slabs.
    """
    if e.mesh is None or len(e.mesh.faces) == 0:
        raise ValueError(f"layout entity {e.name!r} has no mesh")
    mesh = e.mesh.copy()
    mesh.apply_transform(np.linalg.inv(e.pose))
    lo, hi = mesh.bounds
    link = Link(name="body", mesh=mesh, color=(0.8, 0.8, 0.78, 1.0), collisions=(box_shape(lo, hi),))
    return CadModel(class_name=e.class_name, model_id=f"layout_{e.name}", links=(link,), joints=(),
                    features=bounding_box_features(mesh), source=f"layout:{e.name}")


def ground_truth_scene(gt: GroundTruthScene) -> ReplacedScene:
    """Every entity of a generated scene as a ``PlacedObject`` (parents before children).

    Objects get their procedural model (``model_seed``), pose, joint values, support parent and
    link; layout elements a box model (``layout_model``). Movable entities rest on floating
    joints, the rest on fixed ones; the generator's root ``"scene"`` is the map root.
    """
    objects = []
    for e in gt.entities:
        model = gt.model_of(e) if e.model_seed is not None else layout_model(e)
        assert model is not None
        parent = MAP_ROOT if e.parent in (ROOT, "", MAP_ROOT) else e.parent
        objects.append(PlacedObject(
            name=e.name, class_name=e.class_name, model=model, pose=e.pose, parent=parent,
            parent_link=e.parent_link if parent != MAP_ROOT else "", support="floating" if e.movable else "fixed",
            movable=e.movable, entity_id=e.id, joint_values=dict(e.joint_values), cad_id=model.model_id))
    scene = ReplacedScene(gt.name, objects)
    scene.validate()
    return scene


def _proximal_pairs(entities: list[SceneEntity], tolerance: float) -> list[tuple[str, str]]:
    """Pairs of non-supporting entities whose (tolerance-inflated) boxes overlap (Sec. 2.1)."""
    from shapely.geometry import Polygon

    parent = {e.name: e.parent for e in entities}
    lo = np.array([e.mesh.bounds[0] for e in entities]) - tolerance
    hi = np.array([e.mesh.bounds[1] for e in entities]) + tolerance
    overlap = np.all((lo[:, None] <= hi[None]) & (lo[None] <= hi[:, None]), axis=2)  # AABB prefilter
    polys = [Polygon(e.box.corners_xy()).buffer(tolerance) for e in entities]
    pairs = []
    for i, j in zip(*np.nonzero(np.triu(overlap, 1)), strict=True):
        a, b = entities[i], entities[j]
        if parent[a.name] == b.name or parent[b.name] == a.name:
            continue
        za = (a.box.center[2] - a.box.size[2] / 2, a.box.center[2] + a.box.size[2] / 2)
        zb = (b.box.center[2] - b.box.size[2] / 2, b.box.center[2] + b.box.size[2] / 2)
        if za[0] > zb[1] + tolerance or zb[0] > za[1] + tolerance:
            continue
        if polys[i].intersects(polys[j]):
            pairs.append((a.name, b.name))
    return pairs


def build_scene(num_objects: int, seed: int, name: str = "scene", layout: LayoutConfig | None = None,
                proximal_tolerance: float = 0.02) -> GroundTruthScene:
    """Generate a furnished room with about `num_objects` objects and its exact ground truth."""
    placed, room = RoomLayout(layout).generate(num_objects, seed)
    table = load_class_table()
    entities = []
    for i, p in enumerate(placed, start=1):
        info = table.by_name(p.class_name)
        mesh = p.mesh()
        yaw = float(np.arctan2(p.pose[1, 0], p.pose[0, 0]))
        entities.append(SceneEntity(
            id=i, name=p.name, class_name=p.class_name, class_id=info.id, category=info.category,
            is_thing=info.is_thing, movable=info.movable, pose=p.pose, parent=p.parent, parent_link=p.parent_link,
            joint_values=dict(p.joint_values), model_seed=p.seed if p.model is not None else None,
            box=GravityBox.of_points(mesh.vertices, yaw), mesh=mesh))
    return GroundTruthScene(name, seed, room, entities, _proximal_pairs(entities, proximal_tolerance))




def entity_from_ground_truth(e: SceneEntity, mesh: trimesh.Trimesh | None = None) -> Entity:
    """A ground-truth entity as the core ``Entity`` (optionally with another mesh, e.g. its observed part)."""
    m = e.mesh if mesh is None else mesh
    if m is None:
        raise ValueError(f"ground-truth entity {e.name!r} has no mesh")
    return Entity(e.id, e.class_name, np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64),
                  name=e.name, class_id=e.class_id, instance_id=e.id if e.is_thing else 0, category=e.category,
                  is_thing=e.is_thing, num_voxels=len(m.vertices))


def entities_from_ground_truth(scene: GroundTruthScene) -> list[Entity]:
    """Every entity of a ground-truth scene with its complete mesh (the paper's cg_map setting)."""
    return [entity_from_ground_truth(e) for e in scene.entities]
