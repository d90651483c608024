"""Physics check of an exported scene folder: do the movable objects stay where they were put?

A physically plausible scene (paper Sec. 4.5) is one a simulator can load and in which things at
rest stay at rest. ``check_pybullet`` and ``check_mujoco`` load a folder written by
``cad_replacement.export.export_scene``, simulate ``seconds`` of gravity and report, per movable
object, how far it moved: the largest displacement of the corners of its collision bounding box
(so a tipped-over bottle counts by how far its top travelled, not only its base).

PyBullet loads a URDF ``floating`` joint as fixed, so the check loads ``static.urdf`` (the scene
without movable objects) as one fixed-base multibody at its joint values and every movable object
from ``objects/<name>.urdf`` as its own free body at its pose from ``joint_states.json``, with
the inertials from the files (``URDF_USE_INERTIA_FROM_FILE``). MuJoCo loads ``scene.xml`` as it is.
"""

from __future__ import annotations

import contextlib
import json
import logging
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yourdfpy
from numpy.typing import NDArray

#: An object counts as still when it moved less than this (m) during the check.
STILL_THRESHOLD = 0.02

log = logging.getLogger(__name__)


@dataclass
class PhysicsReport:
    """Result of one engine on one scene folder."""

    engine: str
    folder: str
    seconds: float
    loaded: bool
    errors: list[str] = field(default_factory=list)
    displacement: dict[str, float] = field(default_factory=dict)  # object -> metres
    wall_time: float = 0.0

    @property
    def still(self) -> list[str]:
        return [k for k, v in self.displacement.items() if v < STILL_THRESHOLD]

    @property
    def still_fraction(self) -> float:
        """Share of movable objects that stayed (1.0 for a scene without movable objects)."""
        if not self.displacement:
            return 1.0 if self.loaded else 0.0
        return len(self.still) / len(self.displacement)

    def to_dict(self) -> dict[str, Any]:
        return {"engine": self.engine, "folder": self.folder, "seconds": self.seconds, "loaded": self.loaded,
                "errors": self.errors, "displacement": self.displacement, "still_fraction": self.still_fraction,
                "moved": sorted(set(self.displacement) - set(self.still)), "wall_time": self.wall_time}


def _states(folder: Path) -> dict[str, Any]:
    data: dict[str, Any] = json.loads((folder / "joint_states.json").read_text(encoding="utf-8"))
    return data


def _corners(lo: NDArray[np.float64], hi: NDArray[np.float64]) -> NDArray[np.float64]:
    idx = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    return np.where(idx == 0, lo, hi)


def _collision_corners(urdf_path: Path) -> NDArray[np.float64]:
    """Corners of the bounding box of an object's collision geometry in its root link frame."""
    with warnings.catch_warnings():  # yourdfpy 0.0.60 calls trimesh's deprecated Scene.dump internally
        warnings.simplefilter("ignore", DeprecationWarning)
        robot = yourdfpy.URDF.load(str(urdf_path), build_scene_graph=True, load_meshes=True,
                                   load_collision_meshes=True, build_collision_scene_graph=True)
    scene = robot.collision_scene
    if scene is None or scene.is_empty:
        scene = robot.scene
    lo, hi = scene.bounds
    base = scene.graph.get(robot.base_link)[0] if robot.base_link in scene.graph.nodes else np.eye(4)
    pts = _corners(np.asarray(lo), np.asarray(hi))
    return (np.linalg.inv(base) @ np.c_[pts, np.ones(8)].T).T[:, :3]


def _displacement(corners: NDArray[np.float64], before: NDArray[np.float64], after: NDArray[np.float64]) -> float:
    h = np.c_[corners, np.ones(len(corners))]
    return float(np.linalg.norm((h @ before.T - h @ after.T)[:, :3], axis=1).max())


# ---------------------------------------------------------------------------- PyBullet
def check_pybullet(folder: str | Path, seconds: float = 2.0, timestep: float = 1.0 / 240.0,
                   solver_iterations: int = 50) -> PhysicsReport:
    """Simulate the scene folder in PyBullet (DIRECT mode) and measure the movable objects' drift.

    What PyBullet prints from C (its build time, a ``b3Warning`` per link without inertial data) is
    captured at the file-descriptor level and shown on stderr only with ``-v`` (INFO logging)."""
    with _engine_output("pybullet"):
        return _check_pybullet(folder, seconds, timestep, solver_iterations)


def _engine_output(engine: str) -> contextlib.AbstractContextManager:
    from scene_recon.native_output import native_output_captured

    return native_output_captured(show=log.isEnabledFor(logging.INFO), label=f"{engine} output")


def _check_pybullet(folder: str | Path, seconds: float, timestep: float, solver_iterations: int) -> PhysicsReport:
    import pybullet as pb

    folder = Path(folder)
    report = PhysicsReport("pybullet", str(folder), seconds, loaded=False)
    start = time.perf_counter()
    states = _states(folder)
    client = pb.connect(pb.DIRECT)
    try:
        pb.setGravity(0.0, 0.0, -9.81, physicsClientId=client)
        pb.setPhysicsEngineParameter(fixedTimeStep=timestep, numSolverIterations=solver_iterations,
                                     physicsClientId=client)
        flags = pb.URDF_USE_INERTIA_FROM_FILE
        try:
            static = pb.loadURDF(str(folder / "static.urdf"), useFixedBase=True, flags=flags, physicsClientId=client)
        except pb.error as exc:
            report.errors.append(f"static.urdf: {exc}")
            return report
        values = states.get("joints", {})
        for k in range(pb.getNumJoints(static, physicsClientId=client)):
            info = pb.getJointInfo(static, k, physicsClientId=client)
            name = info[1].decode()
            if info[2] in (pb.JOINT_REVOLUTE, pb.JOINT_PRISMATIC):
                pb.resetJointState(static, k, values.get(name, 0.0), physicsClientId=client)
                # hinge/runner friction as in the MJCF: a velocity motor towards 0 with a bounded force
                # (PyBullet's default motor); stillness does not depend on it, pushes do
                pb.setJointMotorControl2(static, k, pb.VELOCITY_CONTROL, targetVelocity=0.0, force=20.0,
                                         physicsClientId=client)
        bodies: dict[str, tuple[int, NDArray[np.float64], NDArray[np.float64]]] = {}
        for name, obj in states["objects"].items():
            if not obj["movable"]:
                continue
            path = folder / obj["urdf"]
            pose = np.asarray(obj["pose"], dtype=np.float64)
            quat = _xyzw(pose[:3, :3])
            try:
                body = pb.loadURDF(str(path), pose[:3, 3].tolist(), quat, flags=flags, physicsClientId=client)
            except pb.error as exc:
                report.errors.append(f"{obj['urdf']}: {exc}")
                continue
            for k in range(pb.getNumJoints(body, physicsClientId=client)):
                info = pb.getJointInfo(body, k, physicsClientId=client)
                if info[2] in (pb.JOINT_REVOLUTE, pb.JOINT_PRISMATIC):
                    pb.resetJointState(body, k, values.get(info[1].decode(), 0.0), physicsClientId=client)
            bodies[name] = (body, _pb_link_pose(pb, client, body), _collision_corners(path))
        report.loaded = not report.errors
        for _ in range(round(seconds / timestep)):
            pb.stepSimulation(physicsClientId=client)
        for name, (body, before, corners) in bodies.items():
            report.displacement[name] = _displacement(corners, before, _pb_link_pose(pb, client, body))
    finally:
        pb.disconnect(physicsClientId=client)
        report.wall_time = time.perf_counter() - start
    return report


def _xyzw(rotation: NDArray[np.float64]) -> list[float]:
    from scipy.spatial.transform import Rotation

    return [float(v) for v in Rotation.from_matrix(rotation).as_quat()]  # x, y, z, w (PyBullet's order)


def _pb_link_pose(pb: Any, client: int, body: int) -> NDArray[np.float64]:
    """Pose of the base *link frame* (PyBullet reports the base's inertial frame)."""
    from scipy.spatial.transform import Rotation

    pos, orn = pb.getBasePositionAndOrientation(body, physicsClientId=client)
    local_pos, local_orn = pb.getDynamicsInfo(body, -1, physicsClientId=client)[3:5]
    inv_pos, inv_orn = pb.invertTransform(local_pos, local_orn)
    p, q = pb.multiplyTransforms(pos, orn, inv_pos, inv_orn)
    t = np.eye(4)
    t[:3, :3] = Rotation.from_quat(q).as_matrix()
    t[:3, 3] = p
    return t


# ---------------------------------------------------------------------------- MuJoCo
def check_mujoco(folder: str | Path, seconds: float = 2.0) -> PhysicsReport:
    """Simulate ``scene.xml`` in MuJoCo (its own timestep) and measure the movable objects' drift (MuJoCo's
    own console output captured as PyBullet's, see ``check_pybullet``)."""
    with _engine_output("mujoco"):
        return _check_mujoco(folder, seconds)


def _check_mujoco(folder: str | Path, seconds: float) -> PhysicsReport:
    import mujoco

    folder = Path(folder)
    report = PhysicsReport("mujoco", str(folder), seconds, loaded=False)
    start = time.perf_counter()
    states = _states(folder)
    try:
        model = mujoco.MjModel.from_xml_path(str(folder / "scene.xml"))
    except Exception as exc:  # mujoco raises ValueError with the compiler's message
        report.errors.append(f"scene.xml: {exc}")
        report.wall_time = time.perf_counter() - start
        return report
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    report.loaded = True
    bodies: dict[str, tuple[int, NDArray[np.float64], NDArray[np.float64]]] = {}
    for name, obj in states["objects"].items():
        if not obj["movable"]:
            continue
        bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, obj["link"])
        if bid < 0:
            report.errors.append(f"scene.xml has no body {obj['link']!r}")
            continue
        bodies[name] = (bid, _mj_pose(data, bid), _collision_corners(folder / obj["urdf"]))
    steps = round(seconds / model.opt.timestep)
    mujoco.mj_step(model, data, nstep=steps)
    for name, (bid, before, corners) in bodies.items():
        report.displacement[name] = _displacement(corners, before, _mj_pose(data, bid))
    if not np.all(np.isfinite(data.qpos)):
        report.errors.append("simulation diverged (non-finite state)")
    report.wall_time = time.perf_counter() - start
    return report


def _mj_pose(data: Any, body: int) -> NDArray[np.float64]:
    t = np.eye(4)
    t[:3, :3] = np.asarray(data.xmat[body]).reshape(3, 3)
    t[:3, 3] = data.xpos[body]
    return t


__all__ = ["STILL_THRESHOLD", "PhysicsReport", "check_mujoco", "check_pybullet"]
