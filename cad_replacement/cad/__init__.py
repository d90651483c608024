"""ROS-free, part-based parametric CAD library (paper Sec. 4.1: the CAD database).

Canonical frame of every model: z up, front = +x (doors open and drawers slide towards +x),
+y = the model's left; origin at the bottom centre of the axis-aligned bounding box of the closed
model (all joints at ``CadModel.zero_configuration()``, 0 for procedural models). Units: metres,
radians, kilograms.

Public API
----------
Types (``model``, ``feature_types``):
    CadModel(class_name, model_id, links, joints, features, params, source)
        .link_poses(joint_values=None) -> {link: 4x4}     forward kinematics (values clipped)
        .posed_link_meshes(joint_values=None) -> {link: Trimesh}  in the model frame
        .mesh(joint_values=None) -> Trimesh                whole object, links concatenated
        .size, .zero_configuration(), .movable_joints, .scaled(factors), .reframed(T)
    Link(name, mesh, color)             mesh in the link frame; procedural ones are watertight
    Joint(name, type, parent, child, origin, axis, lower, upper)   URDF semantics
    SupportSurface(height, polygon, clearance, link, enclosed)
    Plane(normal, d, area)  with n.x + d = 0 and an outward unit normal; .support
    ModelFeatures(box_center, box_size, planes, support_surfaces)

Procedural models (``procedural``):
    build_model(class_name: str, seed: int, *, overrides=None, target_size=None) -> CadModel
    CLASS_BUILDERS: Mapping[str, ClassBuilder]   supported classes and their parameter tables:
        articulated: fridge, microwave, cabinet, oven, dishwasher, wardrobe
        rigid: table, desk, chair, sofa, bed, shelf, monitor, bag, box, cup, bottle, book

Database and cache (``library``):
    CadLibrary(root=None, cache_dir=None, seeds_per_class=10, classes=None, class_table=None)
        .entries(class_name=None) -> [CadEntry]; .features(entry) -> ModelFeatures (cached JSON);
        .model(entry) -> CadModel; .candidates(class_name) -> [(CadEntry, ModelFeatures)]

External models (``urdf_import``, ``urdf_export``):
    import_urdf_model(path, *, class_name=None, model_id=None, meta=None,
                      compute_features=True, seed=0) -> CadModel      raises CadImportError
    export_urdf(model, mesh_dir, *, robot_name=None, density=None, class_table=None,
                mesh_format="stl", mesh_uri_prefix="", name_prefix="") -> str
    write_urdf(model, out_dir, ...) -> Path

Features (``features``), reusable on reconstructed meshes:
    extract_planes(mesh_or_points, *, normals=None, distance_threshold=0.03, iterations=200,
                   min_inlier_fraction=0.1, ...) -> [Plane]
    find_support_surfaces(mesh, ...) -> [SupportSurface]; gravity_aligned_box(points) -> OrientedBox
    mesh_features(mesh) / model_mesh_features(model) -> ModelFeatures

Class table (``classes``, file ``config/classes.yaml``):
    load_class_table(path=None) -> ClassTable  (.by_name, .by_id, .from_coco, .get_by_coco)
    ClassInfo(id, name, category, is_thing, movable, density, coco_names, confusable_with)
    UNKNOWN_CLASS_ID = -1
"""

from .classes import (
    UNKNOWN_CLASS_ID,
    ClassInfo,
    ClassTable,
    ClassTableError,
    UnknownClassError,
    load_class_table,
)
from .feature_types import ModelFeatures, Plane, SupportSurface
from .features import (
    OrientedBox,
    extract_planes,
    find_support_surfaces,
    gravity_aligned_box,
    mesh_features,
    model_mesh_features,
)
from .library import CacheStats, CadEntry, CadLibrary
from .model import CadModel, Joint, Link
from .procedural import CLASS_BUILDERS, ClassBuilder, UnknownCadClassError, build_model
from .urdf_export import export_urdf, write_urdf
from .urdf_import import CadImportError, ImportMeta, import_urdf_model

__all__ = [
    "CLASS_BUILDERS",
    "UNKNOWN_CLASS_ID",
    "CacheStats",
    "CadEntry",
    "CadImportError",
    "CadLibrary",
    "CadModel",
    "ClassBuilder",
    "ClassInfo",
    "ClassTable",
    "ClassTableError",
    "ImportMeta",
    "Joint",
    "Link",
    "ModelFeatures",
    "OrientedBox",
    "Plane",
    "SupportSurface",
    "UnknownCadClassError",
    "UnknownClassError",
    "build_model",
    "export_urdf",
    "extract_planes",
    "find_support_surfaces",
    "gravity_aligned_box",
    "import_urdf_model",
    "load_class_table",
    "mesh_features",
    "model_mesh_features",
    "write_urdf",
]
