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
    Link(name, mesh, color, collisions, inertial)   mesh in the link frame (procedural ones are
        watertight) and its collision shapes (``cad_replacement.collision``: exact primitives)
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
    CadLibrary(root=None, cache_dir=None, seeds_per_class=10, layout_seed_factor=2, classes=None,
               class_table=None)
        .entries(class_name=None) -> [CadEntry]; .features(entry) -> ModelFeatures (cached JSON);
        .model(entry) -> CadModel; .candidates(class_name) -> [(CadEntry, ModelFeatures)]

External models (``urdf_import``, ``urdf_export``):
    import_urdf_model(path, *, class_name=None, model_id=None, meta=None, asset_root=None,
                      compute_features=True, collisions=True, seed=0) -> CadModel   raises CadImportError
    import_urdf_folder(folder, *, class_name=None, ...) -> [CadModel]   one model per URDF
        (layouts, package:// resolution, up axis: ``asset_files``, ``import_meta``)
    export_urdf(model, mesh_dir, *, robot_name=None, density=None, class_table=None,
                mesh_format="stl", mesh_uri_prefix="", name_prefix="") -> str
    write_urdf(model, out_dir, ...) -> Path

Features (``features``):
    find_support_surfaces(mesh, ...) -> [SupportSurface]
    mesh_features(mesh) / model_mesh_features(model) -> ModelFeatures
    (planes and their RANSAC detector are shared geometry: ``recon_core.geometry.plane(_fit)``;
    the class table is ``recon_core.classes``)
"""

from cad_replacement.cad.feature_types import ModelFeatures, SupportSurface
from cad_replacement.cad.features import find_support_surfaces, mesh_features, model_mesh_features
from cad_replacement.cad.library import CacheStats, CadEntry, CadLibrary
from cad_replacement.cad.model import CadModel, Joint, Link
from cad_replacement.cad.procedural import CLASS_BUILDERS, ClassBuilder, build_model
from cad_replacement.cad.urdf_export import export_urdf, write_urdf
from cad_replacement.cad.urdf_import import ImportMeta, import_urdf_folder, import_urdf_model

__all__ = [
    "CLASS_BUILDERS",
    "CacheStats",
    "CadEntry",
    "CadLibrary",
    "CadModel",
    "ClassBuilder",
    "ImportMeta",
    "Joint",
    "Link",
    "ModelFeatures",
    "SupportSurface",
    "build_model",
    "export_urdf",
    "find_support_surfaces",
    "import_urdf_folder",
    "import_urdf_model",
    "mesh_features",
    "model_mesh_features",
    "write_urdf",
]
