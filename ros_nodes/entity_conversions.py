"""PanopticEntity messages <-> the core's Entity, plus RViz markers of the panoptic map."""

from __future__ import annotations

import colorsys
from pathlib import Path

import numpy as np
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from scene_recon_interfaces.msg import OrientedBox, PanopticEntity
from shape_msgs.msg import Mesh, MeshTriangle
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from recon_core.entity import Entity
from recon_core.errors import EntityError, InputError, PathConfinementError
from recon_core.geometry.box_fit import fit_gravity_box
from recon_core.geometry.observed_space import ObservedSpace
from recon_core.paths import confined_uri

CATEGORY = {"layout": PanopticEntity.CATEGORY_LAYOUT, "rigid": PanopticEntity.CATEGORY_RIGID,
            "articulated": PanopticEntity.CATEGORY_ARTICULATED}
CATEGORY_NAME = {v: k for k, v in CATEGORY.items()}


def oriented_box_msg(center: np.ndarray, size: np.ndarray, yaw: float) -> OrientedBox:
    """OrientedBox message of a gravity-aligned box (pure-yaw quaternion)."""
    return OrientedBox(
        center=Pose(position=Point(x=float(center[0]), y=float(center[1]), z=float(center[2])),
                    orientation=Quaternion(z=float(np.sin(yaw / 2)), w=float(np.cos(yaw / 2)))),
        size=Vector3(x=float(size[0]), y=float(size[1]), z=float(size[2])))


def box_msg(vertices: np.ndarray) -> OrientedBox:
    """Gravity-aligned box of a vertex set (empty -> zero box at the origin)."""
    if len(vertices) == 0:
        return oriented_box_msg(np.zeros(3), np.zeros(3), 0.0)
    box = fit_gravity_box(vertices)
    return oriented_box_msg(box.center, box.size, box.yaw)


def mesh_msg(vertices: np.ndarray, faces: np.ndarray) -> Mesh:
    v = np.asarray(vertices, np.float64)
    if not np.all(np.isfinite(v)):
        raise ValueError("mesh vertices must be finite")
    # (from Python lists: iterating numpy rows made numpy scalars and took 4x longer)
    return Mesh(triangles=_triangles(faces), vertices=[Point(x=x, y=y, z=z) for x, y, z in v.tolist()])


_FAST_TRIANGLES = "_vertex_indices" in getattr(MeshTriangle, "__slots__", ())


def _triangles(faces: np.ndarray) -> list[MeshTriangle]:
    """MeshTriangle messages of a face array. The generated constructor validates the fixed-size array
    (2 us a triangle: 0.2 s for a 100k-face map, at every publication); the rows are uint32 already, so
    they are set directly on the generated `_vertex_indices` slot (a third of the time)."""
    rows = np.ascontiguousarray(faces, np.uint32)
    if not _FAST_TRIANGLES:
        return [MeshTriangle(vertex_indices=r) for r in rows]
    out = []
    for r in rows:
        t = MeshTriangle.__new__(MeshTriangle)
        t._check_fields = False
        t._vertex_indices = r
        out.append(t)
    return out


def entity_to_msg(e: Entity, include_mesh: bool = True, mesh_uri: str = "") -> PanopticEntity:
    msg = PanopticEntity(id=int(e.id), class_id=int(e.class_id), class_name=e.class_name,
                         instance_id=int(e.instance_id), is_thing=bool(e.is_thing),
                         category=CATEGORY.get(e.category, PanopticEntity.CATEGORY_UNKNOWN),
                         confidence=float(e.confidence), revision=int(e.revision), mesh_uri=mesh_uri,
                         fringe_vertices=len(e.vertices) - e.core_vertices if e.core_vertices >= 0 else 0)
    msg.box = box_msg(e.vertices)
    if include_mesh and len(e.faces):
        msg.mesh = mesh_msg(e.vertices, e.faces)
    if e.observed_space is not None:
        space = e.observed_space
        msg.observed_origin = [float(v) for v in space.origin]
        msg.observed_cell = float(space.cell)
        msg.observed_shape = list(space.shape)
        msg.observed_bits = space.packed().tobytes()
    return msg


def observed_space_from_msg(msg: PanopticEntity) -> ObservedSpace | None:
    """The entity's observed-space grid (None when the message carries none); a malformed one is an
    EntityError."""
    if not len(msg.observed_shape):
        return None
    try:
        return ObservedSpace.from_packed(list(msg.observed_origin), float(msg.observed_cell),
                                         tuple(int(n) for n in msg.observed_shape),
                                         np.frombuffer(bytes(msg.observed_bits), np.uint8))
    except InputError as exc:
        raise EntityError(f"entity {msg.id}: {exc}") from exc


#: The mapper node's default output root (`data_root`); consumers read meshes by URI only under their
#: `mesh_root` parameter, which defaults to it.
DEFAULT_MAP_ROOT = "scene_recon_data/map"
#: Largest mesh file read by `mesh_uri` (bytes): a message must not make a node read a huge file.
MAX_MESH_FILE_BYTES = 512 * 2**20
#: Mesh formats read by `mesh_uri` (by suffix); anything else is refused before it is opened.
MESH_SUFFIXES = (".ply", ".stl", ".obj", ".off", ".glb", ".gltf")


def mesh_from_msg(msg: PanopticEntity, mesh_root: str | Path | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of an entity: the inline mesh, else the file behind `mesh_uri` (file:// or a path).

    A `mesh_uri` is read only when it names a mesh file under `mesh_root` (the mapper's output root;
    None: by-reference meshes are refused), see `recon_core.paths.confined_uri`. Raises ValueError
    when the reference is refused or is not a readable mesh (whatever the file holds).
    """
    v = np.array([[p.x, p.y, p.z] for p in msg.mesh.vertices], np.float64).reshape(-1, 3)
    f = np.array([t.vertex_indices for t in msg.mesh.triangles], np.int64).reshape(-1, 3)
    if len(v) == 0 and msg.mesh_uri:
        try:
            path = confined_uri(mesh_root, msg.mesh_uri)
        except PathConfinementError as exc:
            raise ValueError(f"entity {msg.id}: mesh_uri {exc}") from None
        if path.suffix.lower() not in MESH_SUFFIXES:
            raise ValueError(f"entity {msg.id}: mesh_uri {msg.mesh_uri!r} is not a mesh file "
                             f"({', '.join(MESH_SUFFIXES)})")
        if not path.is_file():
            raise ValueError(f"entity {msg.id}: cannot read mesh_uri {msg.mesh_uri!r}: no such file")
        if path.stat().st_size > MAX_MESH_FILE_BYTES:
            raise ValueError(f"entity {msg.id}: mesh_uri {msg.mesh_uri!r} is larger than {MAX_MESH_FILE_BYTES} bytes")
        v, f = _read_mesh(path, msg)
    return v, f


def _read_mesh(path: Path, msg: PanopticEntity) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    try:
        geom = trimesh.load(path, force="mesh", process=False)
        v = np.asarray(geom.vertices, np.float64).reshape(-1, 3)
        f = np.asarray(getattr(geom, "faces", np.zeros((0, 3))), np.int64).reshape(-1, 3)
    except MemoryError:
        raise
    except Exception as exc:  # a text file, a truncated PLY, an image: whatever trimesh raises, it is no mesh
        raise ValueError(f"entity {msg.id}: mesh_uri {msg.mesh_uri!r} is not a readable mesh "
                         f"({type(exc).__name__}: {exc})") from None
    if len(v) == 0:
        raise ValueError(f"entity {msg.id}: mesh_uri {msg.mesh_uri!r} holds no vertices")
    return v, f


def msg_to_entity(msg: PanopticEntity, mesh_root: str | Path | None = None) -> Entity:
    """A PanopticEntity (inline mesh, or a ``mesh_uri`` under `mesh_root`) as the core entity; a bad or
    refused mesh is an EntityError.

    An unknown category is left empty so the contact-graph builder takes it from the class table.
    """
    try:
        v, f = mesh_from_msg(msg, mesh_root)
    except ValueError as exc:
        raise EntityError(str(exc)) from exc
    return Entity(int(msg.id), msg.class_name or "unknown", v, f, class_id=int(msg.class_id),
                  instance_id=int(msg.instance_id), is_thing=bool(msg.is_thing),
                  category=CATEGORY_NAME.get(msg.category, ""), confidence=float(msg.confidence),
                  revision=int(msg.revision), num_voxels=len(v),
                  core_vertices=len(v) - int(msg.fringe_vertices) if 0 < msg.fringe_vertices <= len(v) else -1,
                  observed_space=observed_space_from_msg(msg))


def entity_color(entity_id: int) -> ColorRGBA:
    h = (entity_id * 0.61803398875) % 1.0
    r, g, b = colorsys.hsv_to_rgb(h, 0.65, 0.9)
    return ColorRGBA(r=r, g=g, b=b, a=1.0)


def map_markers(entities: list[Entity], frame_id: str, stamp) -> MarkerArray:
    """One TRIANGLE_LIST per entity (coloured by entity) and a text label above it."""
    out = MarkerArray()
    out.markers.append(Marker(action=Marker.DELETEALL))
    for e in entities:
        if not len(e.faces):
            continue
        tri = np.asarray(e.vertices)[np.asarray(e.faces).reshape(-1)]
        m = Marker(type=Marker.TRIANGLE_LIST, action=Marker.ADD, ns="panoptic_map", id=int(e.id))
        m.header.frame_id, m.header.stamp = frame_id, stamp
        m.pose.orientation.w = 1.0
        m.scale = Vector3(x=1.0, y=1.0, z=1.0)
        m.color = entity_color(int(e.id))
        m.points = [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in tri]
        out.markers.append(m)
        t = Marker(type=Marker.TEXT_VIEW_FACING, action=Marker.ADD, ns="panoptic_labels", id=int(e.id))
        t.header.frame_id, t.header.stamp = frame_id, stamp
        top = np.asarray(e.vertices).max(axis=0)
        mid = np.asarray(e.vertices).mean(axis=0)
        t.pose.position = Point(x=float(mid[0]), y=float(mid[1]), z=float(top[2] + 0.1))
        t.pose.orientation.w = 1.0
        t.scale.z = 0.12
        t.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0)
        t.text = f"{e.class_name} {e.id}"
        out.markers.append(t)
    return out
