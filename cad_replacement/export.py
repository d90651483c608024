"""Export a ``ReplacedScene`` as one folder for simulators and viewers (paper Sec. 4.5).

``export_scene(scene, out_dir)`` writes::

    scene.urdf          the whole scene, root link ``map``: layout and fixed furniture on fixed
                        joints, movable objects on ``floating`` joints to the link they rest on,
                        CAD joints (revolute/prismatic with limits, effort, velocity) kept
    joint_states.json   current joint values and every object's pose (forward kinematics)
    static.urdf         the scene without its movable objects (one fixed-base multibody)
    objects/<name>.urdf each movable object alone (with what is fixed onto it), for engines that
                        load a URDF floating joint as fixed (PyBullet): load it at its pose
    scene.xml           MJCF for MuJoCo: movable objects are top-level bodies with a free joint
                        at their pose; fixed furniture and layout nest under the world with their
                        hinge/slide joints (``ref`` = current value, so the body sits where FK
                        puts it); primitives become MuJoCo geoms, convex pieces STL meshes
    scene.glb           the visual meshes merged for viewers
    meshes/             per-link visual meshes (STL, coloured by the URDF/MJCF material) and
                        convex collision pieces, referenced by relative paths

Collision geometry comes from the CAD links (``Link.collisions``: exact primitives for procedural
models) or, for meshes without primitives, from a convex decomposition
(``cad_replacement.collision.mesh_collisions``), never the concave visual mesh as one hull.
Inertials: a link's own (``Link.inertial``, e.g. measured data of an imported asset) or mass =
collision volume x class density with the full inertia tensor of the pieces. Layout links are
massless (static); a movable or articulated link without a density is an error, not a guess.

Every file is written atomically (``recon_core.io``); every number must be finite.
"""

from __future__ import annotations

import functools
import json
import time
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np
import trimesh
from numpy.typing import NDArray

from cad_replacement.cad.model import Link
from cad_replacement.collision import inertial_from_shapes, mesh_collisions
from cad_replacement.scene_model import MAP_ROOT, PlacedObject, ReplacedScene
from recon_core.classes import ClassTable, load_class_table
from recon_core.errors import InputError, UnknownClassError
from recon_core.io import write_bytes_atomic, write_text_atomic
from recon_core.kinematic_tree import (
    CollisionShape,
    Inertial,
    Joint,
    KinematicTree,
    TreeLink,
    export_mesh_file,
    format_number,
    format_vector,
)
from recon_core.names import unique_names, urdf_name

EXPORT_FORMAT_VERSION = 1
#: Separator between an object's name and its link/joint names (``cabinet_1__door0``).
SEP = "__"
MESH_DIR = "meshes"
OBJECTS_DIR = "objects"
DEFAULT_RGBA = (0.7, 0.7, 0.7, 1.0)


@dataclass(frozen=True)
class MjcfOptions:
    """Simulation settings written into ``scene.xml``.

    What keeps resting objects still is the collision geometry (exact primitives instead of
    convex hulls of hollow links); measured on generated scenes (seeds 0-5, 20 objects) and a cup
    in an open drawer, MuJoCo's own defaults (Euler, pyramidal cone, no joint damping) leave
    every movable object within 0.5 mm in 2 s as these settings do. The settings are for what
    happens when something pushes: the implicit-fast integrator and the elliptic cone with
    ``impratio`` > 1 give stiffer, non-creeping friction; hinges and runners carry damping and dry
    friction (``frictionloss``) like real furniture, so a bumped door does not swing on freely;
    ``armature`` stabilises light door and drawer links. 2 ms is MuJoCo's default step.
    """

    timestep: float = 0.002
    integrator: str = "implicitfast"
    cone: str = "elliptic"
    impratio: float = 10.0
    friction: tuple[float, float, float] = (0.8, 0.005, 0.0001)
    joint_damping: float = 2.0
    joint_frictionloss: float = 1.0
    joint_armature: float = 0.01


@dataclass(frozen=True)
class ExportResult:
    """Paths of everything ``export_scene`` wrote and a summary of the scene."""

    folder: Path
    urdf: Path
    mjcf: Path
    glb: Path | None
    joint_states: Path
    static_urdf: Path
    object_urdfs: dict[str, Path] = field(default_factory=dict)
    links: int = 0
    joints: int = 0
    collision_shapes: int = 0
    seconds: float = 0.0

    @property
    def movable(self) -> tuple[str, ...]:
        return tuple(self.object_urdfs)


# ---------------------------------------------------------------------------- scene -> tree
def link_name(obj: PlacedObject, link: str) -> str:
    return obj.name if link == obj.model.root_link else f"{obj.name}{SEP}{link}"


def _density(class_name: str, table: ClassTable) -> float | None:
    try:
        value = table.by_name(class_name).density
    except UnknownClassError:
        return None
    return None if value is None else float(value)


def link_physics(link: Link, density: float | None, *, needs_mass: bool, where: str,
                 cache_dir: str | Path | None = None) -> tuple[tuple[CollisionShape, ...], Inertial | None]:
    """Collision shapes and inertial of one CAD link (see the module doc for the rules)."""
    shapes = link.collisions if link.collisions is not None else mesh_collisions(link.mesh, cache_dir)
    inertial = link.inertial
    if inertial is None and density is not None and shapes:
        inertial = inertial_from_shapes(shapes, density)
    if inertial is None and needs_mass:
        raise InputError(f"{where}: a moving link needs a mass, but its class has no density "
                         "(config/classes.yaml) and the link no inertial")
    return shapes, inertial


def scene_to_tree(scene: ReplacedScene, *, class_table: ClassTable | None = None,
                  cache_dir: str | Path | None = None, visual_collisions: bool = False) -> KinematicTree:
    """The scene as one kinematic tree rooted at the scene's frame (``map`` unless the map was built in
    another, e.g. the mapper node's gravity-aligned ``map_gravity``), names prefixed by the object name.

    An object's root link is named after the object, its other links ``<object>__<link>``, its
    joints ``<object>__<joint>``; the support joint ``<parent link>__to__<object>`` is fixed or
    floating (``PlacedObject.support``) with the object's pose relative to the carrying link at
    the current joint values. Names are made URDF-safe and unique here, so the writer keeps them
    and every subtree written from this tree refers to the same mesh files.

    ``visual_collisions`` makes every link collide as its visual mesh (the engines then use its
    convex hull): the naive export, kept only as the baseline of ``benchmarks/bench_export.py``.
    """
    scene.validate()
    table = class_table if class_table is not None else load_class_table()
    root = scene.frame_id or MAP_ROOT  # the TF frame the poses are in: the URDF's root link and TF parent
    raw_links: list[TreeLink] = [TreeLink(root, None, 0.0, None)]
    raw_joints: list[Joint] = []
    values: dict[str, float] = {}
    link_pose: dict[str, NDArray[np.float64]] = {root: np.eye(4)}
    for obj in scene:
        model = obj.model
        density = _density(obj.class_name, table)
        poses = obj.link_poses()
        moving_links = {j.child for j in model.movable_joints}
        for lk in model.links:
            name = link_name(obj, lk.name)
            needs_mass = (obj.support == "floating" and lk.name == model.root_link) or lk.name in moving_links
            shapes, inertial = link_physics(lk, density, needs_mass=needs_mass,
                                            where=f"object {obj.name!r} link {lk.name!r}", cache_dir=cache_dir)
            rgba = tuple(float(c) for c in lk.color) if lk.color is not None else DEFAULT_RGBA
            raw_links.append(TreeLink(name, lk.mesh, 0.0, rgba,  # type: ignore[arg-type]
                                      collisions=None if visual_collisions else shapes, inertial=inertial))
            link_pose[name] = poses[lk.name]
        zero = model.zero_configuration()
        for j in model.joints:
            jname = f"{obj.name}{SEP}{j.name}"
            raw_joints.append(Joint(jname, j.type, link_name(obj, j.parent), link_name(obj, j.child), j.origin,
                                    j.axis, j.lower, j.upper, j.effort, j.velocity))
            if j.movable:
                values[jname] = j.clip(obj.joint_values.get(j.name, zero.get(j.name, 0.0)))
        if obj.parent == MAP_ROOT:
            parent_name = root
        else:
            parent = scene.object(obj.parent)
            parent_name = link_name(parent, obj.parent_link or parent.model.root_link)
        origin = np.linalg.inv(link_pose[parent_name]) @ obj.pose
        origin[3] = (0.0, 0.0, 0.0, 1.0)
        raw_joints.append(Joint(f"{parent_name}{SEP}to{SEP}{obj.name}", obj.support, parent_name,
                                link_name(obj, model.root_link), origin))
    # URDF-safe unique names up front: subtrees and the MJCF then agree on every name and file.
    link_map = dict(zip([lk.name for lk in raw_links], unique_names(urdf_name(lk.name) for lk in raw_links),
                        strict=True))
    joint_names = unique_names(urdf_name(j.name) for j in raw_joints)
    links = [_renamed_link(lk, link_map[lk.name]) for lk in raw_links]
    joints = [Joint(n, j.type, link_map[j.parent], link_map[j.child], j.origin, j.axis, j.lower, j.upper, j.effort,
                    j.velocity) for j, n in zip(raw_joints, joint_names, strict=True)]
    renamed_values = {n: values[j.name] for j, n in zip(raw_joints, joint_names, strict=True) if j.name in values}
    tree = KinematicTree(urdf_name(scene.name, "scene"), link_map[root], links, joints, renamed_values)
    tree.validate()
    return tree


def _renamed_link(lk: TreeLink, name: str) -> TreeLink:
    return TreeLink(name, lk.mesh, lk.mass, lk.rgba, lk.collisions, lk.inertial)


def subtree(tree: KinematicTree, root: str, *, name: str | None = None, cut_floating: bool = True) -> KinematicTree:
    """The links reachable from ``root`` (not through floating joints when ``cut_floating``)."""
    children: dict[str, list[Joint]] = {}
    for j in tree.joints:
        if not (cut_floating and j.type == "floating"):
            children.setdefault(j.parent, []).append(j)
    keep, joints, stack = {root}, [], [root]
    while stack:
        for j in children.get(stack.pop(), []):
            keep.add(j.child)
            joints.append(j)
            stack.append(j.child)
    links = [lk for lk in tree.links if lk.name in keep]
    values = {j.name: tree.joint_values[j.name] for j in joints if j.name in tree.joint_values}
    return KinematicTree(name or root, root, links, joints, values)


# ---------------------------------------------------------------------------- MJCF
def _quat(rotation: NDArray[np.float64]) -> NDArray[np.float64]:
    return _quat_of(np.ascontiguousarray(rotation, dtype=np.float64).tobytes())


@functools.lru_cache(maxsize=1024)
def _quat_of(rotation: bytes) -> NDArray[np.float64]:
    """The quaternion of a rotation given by its bytes (most shapes of a scene share a few rotations: an
    eigen-decomposition each had cost 0.1-0.2 s a scene); the array is read only, shared by callers."""
    m = np.eye(4)
    m[:3, :3] = np.frombuffer(rotation, dtype=np.float64).reshape(3, 3)
    q = np.asarray(trimesh.transformations.quaternion_from_matrix(m), dtype=np.float64)  # w, x, y, z (MuJoCo's)
    q.setflags(write=False)
    return q


def _frame_attrs(t: NDArray[np.float64]) -> str:
    return f"pos={quoteattr(format_vector(t[:3, 3]))} quat={quoteattr(format_vector(_quat(t[:3, :3])))}"


def _geom_lines(link: TreeLink, indent: str, mesh_names: dict[str, str]) -> list[str]:
    lines = []
    rgba = quoteattr(format_vector(link.rgba or DEFAULT_RGBA))
    if link.mesh is not None and len(link.mesh.faces):
        lines.append(f'{indent}<geom class="visual" type="mesh" mesh={quoteattr(mesh_names[link.name])} rgba={rgba}/>')
        if link.collisions is None:  # the naive baseline: the visual mesh collides (as its convex hull)
            lines.append(f'{indent}<geom class="collision" type="mesh" mesh={quoteattr(mesh_names[link.name])}/>')
    for k, s in enumerate(link.collisions or ()):
        frame = _frame_attrs(s.origin)
        if s.kind == "box":
            geom = f'type="box" size={quoteattr(format_vector(0.5 * s.size))}'
        elif s.kind == "cylinder":
            geom = f'type="cylinder" size={quoteattr(format_vector([s.radius, 0.5 * s.length]))}'
        elif s.kind == "sphere":
            geom = f'type="sphere" size={quoteattr(format_number(s.radius))}'
        else:
            geom = f'type="mesh" mesh={quoteattr(mesh_names[f"{link.name}_collision_{k}"])}'
        lines.append(f'{indent}<geom class="collision" {geom} {frame}/>')
    if link.inertial is not None:
        i = link.inertial.inertia
        full = [i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]]
        lines.append(f"{indent}<inertial pos={quoteattr(format_vector(link.inertial.center_of_mass))}"
                     f" mass={quoteattr(format_number(link.inertial.mass))}"
                     f" fullinertia={quoteattr(format_vector(full))}/>")
    return lines


def _body_lines(tree: KinematicTree, link: str, frame: NDArray[np.float64], joint: Joint | None,
                children: Mapping[str, list[Joint]], links: Mapping[str, TreeLink], mesh_names: dict[str, str],
                opts: MjcfOptions, depth: int, free: bool = False) -> list[str]:
    ind = "  " * depth
    lines = [f"{ind}<body name={quoteattr(link)} {_frame_attrs(frame)}>"]
    if free:
        lines.append(f'{ind}  <freejoint name={quoteattr(link + "_free")}/>')
    if joint is not None and joint.movable:
        kind = "slide" if joint.type == "prismatic" else "hinge"
        value = tree.joint_values.get(joint.name, joint.zero_value)
        limits = ""
        if joint.type != "continuous":
            limits = f' limited="true" range={quoteattr(format_vector([joint.lower, joint.upper]))}'
        lines.append(f"{ind}  <joint name={quoteattr(joint.name)} type={quoteattr(kind)}"
                     f" axis={quoteattr(format_vector(joint.axis))} ref={quoteattr(format_number(value))}{limits}"
                     f" damping={quoteattr(format_number(opts.joint_damping))}"
                     f" frictionloss={quoteattr(format_number(opts.joint_frictionloss))}"
                     f" armature={quoteattr(format_number(opts.joint_armature))}/>")
    lines.extend(_geom_lines(links[link], ind + "  ", mesh_names))
    for j in children.get(link, []):
        if j.type == "floating":
            continue  # movable objects are top-level bodies
        child_frame = j.transform(tree.joint_values.get(j.name, j.zero_value))
        lines.extend(_body_lines(tree, j.child, child_frame, j, children, links, mesh_names, opts, depth + 1))
    lines.append(f"{ind}</body>")
    return lines


def mjcf_text(tree: KinematicTree, mesh_dir: str = MESH_DIR, mesh_format: str = "stl",
              options: MjcfOptions | None = None) -> str:
    """MJCF of a scene tree whose meshes were written by the URDF writer into ``mesh_dir``.

    Movable objects (children of floating joints) become top-level bodies with a free joint at
    their forward-kinematics pose: MuJoCo allows free joints on top-level bodies only.
    """
    opts = options or MjcfOptions()
    tree.validate()
    links = {lk.name: lk for lk in tree.links}
    children: dict[str, list[Joint]] = {}
    for j in tree.joints:
        children.setdefault(j.parent, []).append(j)
    poses = tree.link_poses()
    mesh_names: dict[str, str] = {}
    assets = []
    for lk in tree.links:
        files = []
        if lk.mesh is not None and len(lk.mesh.faces):
            files.append(lk.name)
        files.extend(f"{lk.name}_collision_{k}" for k, s in enumerate(lk.collisions or ()) if s.kind == "mesh")
        for stem in files:
            mesh_names[stem] = stem
            assets.append(f"    <mesh name={quoteattr(stem)} file={quoteattr(f'{stem}.{mesh_format}')}/>")
    n = format_number
    lines = [
        f"<mujoco model={quoteattr(tree.name)}>",
        f'  <compiler angle="radian" meshdir={quoteattr(mesh_dir)} autolimits="true" inertiafromgeom="false"/>',
        f"  <option timestep={quoteattr(n(opts.timestep))} integrator={quoteattr(opts.integrator)}"
        f" cone={quoteattr(opts.cone)} impratio={quoteattr(n(opts.impratio))}/>",
        "  <default>",
        f"    <geom friction={quoteattr(format_vector(opts.friction))}/>",
        '    <default class="visual"><geom contype="0" conaffinity="0" group="1" mass="0"/></default>',
        '    <default class="collision"><geom group="3" rgba="0.5 0.5 0.5 0.3"/></default>',
        "  </default>",
        "  <asset>",
        *assets,
        "  </asset>",
        "  <worldbody>",
        '    <light directional="true" pos="0 0 5" dir="0 0 -1"/>',
    ]
    root = tree.root  # the map root carries no geometry
    for j in children.get(root, []):
        if j.type != "floating":
            lines.extend(_body_lines(tree, j.child, j.transform(0.0), j, children, links, mesh_names, opts, 2))
    for j in tree.joints:
        if j.type == "floating":
            lines.extend(_body_lines(tree, j.child, poses[j.child], None, children, links, mesh_names, opts, 2,
                                     free=True))
    lines += ["  </worldbody>", "  <!-- generated by scene_recon -->", "</mujoco>"]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------- GLB
def scene_glb(tree: KinematicTree) -> bytes:
    """Visual meshes at their forward-kinematics poses, coloured, as one binary glTF."""
    poses = tree.link_poses()
    glb = trimesh.Scene()
    for lk in tree.links:
        if lk.mesh is None or not len(lk.mesh.faces):
            continue
        mesh = lk.mesh.copy()
        rgba = np.asarray(lk.rgba or DEFAULT_RGBA, dtype=np.float64)
        mesh.visual = trimesh.visual.ColorVisuals(mesh, face_colors=np.round(rgba * 255).astype(np.uint8))
        glb.add_geometry(mesh, node_name=lk.name, geom_name=lk.name, transform=poses[lk.name])
    data = glb.export(file_type="glb")
    return data if isinstance(data, bytes) else bytes(data)


# ---------------------------------------------------------------------------- export
def _check_finite(tree: KinematicTree) -> None:
    """Refuse NaN/inf anywhere before a file is written (the writers also refuse them per number)."""
    arrays: list[Any] = []
    for lk in tree.links:
        if lk.mesh is not None:
            arrays.append(lk.mesh.vertices)
        for s in lk.collisions or ():
            arrays += [s.origin, s.size, [s.radius, s.length]]
            if s.mesh is not None:
                arrays.append(s.mesh.vertices)
        if lk.inertial is not None:
            arrays += [[lk.inertial.mass], lk.inertial.center_of_mass, lk.inertial.inertia]
    arrays += [j.origin for j in tree.joints] + [list(tree.joint_values.values())]
    for a in arrays:
        if not np.all(np.isfinite(np.asarray(a, dtype=np.float64))):
            raise InputError(f"scene {tree.name!r}: non-finite number in the exported geometry")


def _poses_json(tree: KinematicTree, movable: Iterable[str], objects: Mapping[str, str]) -> dict[str, Any]:
    poses = tree.link_poses()
    movable = set(movable)
    return {
        "format_version": EXPORT_FORMAT_VERSION,
        "root": tree.root,
        "joints": {name: float(v) for name, v in tree.joint_values.items()},
        "objects": {
            name: {"link": link, "pose": poses[link].tolist(), "movable": link in movable,
                   "urdf": f"{OBJECTS_DIR}/{link}.urdf" if link in movable else "static.urdf"}
            for name, link in objects.items()
        },
    }


def export_scene(scene: ReplacedScene, out_dir: str | Path, *, class_table: ClassTable | None = None,
                 cache_dir: str | Path | None = None, mjcf_options: MjcfOptions | None = None,
                 glb: bool = True, visual_collisions: bool = False,
                 on_glb: Callable[[Path], None] | None = None) -> ExportResult:
    """Write the scene folder described in the module doc; returns the written paths.

    ``cache_dir`` holds convex decompositions of meshes without primitives (see
    ``cad_replacement.collision.convex_pieces``). ``scene.glb`` is written first and handed to
    ``on_glb`` at once, so a caller can start what reads it (``scene-recon replace``: the picture)
    while the rest is written.
    """
    start = time.perf_counter()
    out = Path(out_dir)
    tree = scene_to_tree(scene, class_table=class_table, cache_dir=cache_dir, visual_collisions=visual_collisions)
    _check_finite(tree)
    glb_path = None
    if glb:
        out.mkdir(parents=True, exist_ok=True)
        glb_path = write_bytes_atomic(out / "scene.glb", scene_glb(tree))
        if on_glb is not None:
            on_glb(glb_path)
    # every file below is written atomically with an fsync: the mesh files and the documents go to writer
    # threads (the fsyncs overlap each other and the documents' text, which this thread builds meanwhile)
    with ThreadPoolExecutor(MESH_WRITERS, thread_name_prefix="scene-writer") as pool:
        writes = _submit_meshes(pool, tree, out / MESH_DIR, "stl")

        def write(path: Path, text: str) -> Path:
            writes.append(pool.submit(write_text_atomic, path, text))
            return path

        urdf = write(out / "scene.urdf", tree.urdf_text(out / MESH_DIR, f"{MESH_DIR}/", "stl", write_meshes=False))
        movable = [j.child for j in tree.joints if j.type == "floating"]
        static = subtree(tree, tree.root, name=f"{tree.name}_static")
        static_urdf = write(out / "static.urdf",
                            static.urdf_text(out / MESH_DIR, f"{MESH_DIR}/", "stl", write_meshes=False))
        object_urdfs = {}
        for link in movable:
            part = subtree(tree, link, name=link)
            text = part.urdf_text(out / MESH_DIR, f"../{MESH_DIR}/", "stl", write_meshes=False)
            object_urdfs[link] = write(out / OBJECTS_DIR / f"{link}.urdf", text)
        link_of = dict(zip([o.name for o in scene], _root_link_names(scene, tree), strict=True))
        object_of = {link: name for name, link in link_of.items()}
        states = write(out / "joint_states.json",
                       json.dumps(_poses_json(tree, movable, link_of), indent=1, allow_nan=False))
        mjcf = write(out / "scene.xml", mjcf_text(tree, MESH_DIR, "stl", mjcf_options))
        for future in writes:
            future.result()  # the first error, as writing them in turn would raise it
    return ExportResult(
        folder=out, urdf=urdf, mjcf=mjcf, glb=glb_path, joint_states=states, static_urdf=static_urdf,
        object_urdfs={object_of[link]: p for link, p in object_urdfs.items()},
        links=len(tree.links), joints=len(tree.joints),
        collision_shapes=sum(len(lk.collisions or ()) for lk in tree.links),
        seconds=time.perf_counter() - start,
    )


#: Threads writing mesh files: each file is written atomically with an fsync (``recon_core.io``), and
#: one at a time the fsyncs were most of the export (177 files: 2 s of 3.3 s on a busy disk); in
#: parallel the file system commits them together.
MESH_WRITERS = 8


def _submit_meshes(pool: ThreadPoolExecutor, tree: KinematicTree, folder: Path, mesh_format: str) -> list[Future[Any]]:
    """Jobs of ``pool`` writing every mesh file ``KinematicTree.to_urdf`` references (same names and bytes)."""
    link_names, _ = tree.safe_names()
    # one job per mesh object (a mesh two links share is written by one thread: trimesh fills its
    # caches on first use)
    jobs: dict[int, tuple[trimesh.Trimesh, list[Path]]] = {}
    for link in tree.links:
        name = link_names[link.name]
        if link.mesh is not None and len(link.mesh.faces):
            jobs.setdefault(id(link.mesh), (link.mesh, []))[1].append(folder / f"{name}.{mesh_format}")
        for k, shape in enumerate(link.collisions or ()):
            if shape.kind not in ("box", "cylinder", "sphere"):
                assert shape.mesh is not None  # checked by CollisionShape
                jobs.setdefault(id(shape.mesh), (shape.mesh, []))[1].append(
                    folder / f"{name}_collision_{k}.{mesh_format}")
    if not jobs:
        return []
    folder.mkdir(parents=True, exist_ok=True)

    def write(mesh: trimesh.Trimesh, paths: list[Path]) -> None:
        for path in paths:
            export_mesh_file(mesh, path, mesh_format)

    return [pool.submit(write, mesh, paths) for mesh, paths in jobs.values()]


def _root_link_names(scene: ReplacedScene, tree: KinematicTree) -> list[str]:
    """Tree name of each object's root link (the scene tree's links follow the scene's order)."""
    names = []
    index = 1  # links[0] is the map root
    for obj in scene:
        names.append(tree.links[index + [lk.name for lk in obj.model.links].index(obj.model.root_link)].name)
        index += len(obj.model.links)
    return names


__all__ = [
    "ExportResult",
    "MjcfOptions",
    "export_scene",
    "link_name",
    "link_physics",
    "mjcf_text",
    "scene_glb",
    "scene_to_tree",
    "subtree",
]
