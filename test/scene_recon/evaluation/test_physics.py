"""Physics check: exported scenes load in PyBullet and MuJoCo and their movable objects stay put."""

from __future__ import annotations

import pytest
from testsupport.scenes import drawer_scene

from cad_replacement.export import export_scene
from scene_recon.evaluation.physics import STILL_THRESHOLD, check_mujoco, check_pybullet
from scene_recon.synthetic.scene import build_scene, ground_truth_scene


@pytest.fixture(scope="module")
def generated():
    """Seed 1 puts books and a bottle inside shelves: the case convex-hull collisions fail."""
    return ground_truth_scene(build_scene(20, 1))


@pytest.mark.parametrize("check", [check_pybullet, check_mujoco], ids=["pybullet", "mujoco"])
def test_generated_scene_loads_and_stays_still(generated, tmp_path, check):
    result = export_scene(generated, tmp_path / "scene", glb=False)
    report = check(result.folder, seconds=2.0)
    assert report.loaded and not report.errors
    assert set(report.displacement) == set(result.object_urdfs) and len(report.displacement) >= 10
    assert report.still_fraction >= 0.95, report.to_dict()["moved"]
    assert max(report.displacement.values()) < STILL_THRESHOLD


def test_visual_mesh_collisions_throw_objects_out_of_furniture(generated, tmp_path):
    """The naive export (each link collides as its visual mesh's hull) is what the check catches."""
    result = export_scene(generated, tmp_path / "naive", glb=False, visual_collisions=True)
    report = check_mujoco(result.folder, seconds=1.0)
    assert report.loaded
    assert report.still_fraction < 0.9


def test_a_broken_folder_reports_load_errors(tmp_path, generated):
    result = export_scene(generated, tmp_path / "scene", glb=False)
    result.mjcf.write_text("<mujoco><worldbody><geom type='mesh' mesh='missing'/></worldbody></mujoco>")
    report = check_mujoco(result.folder)
    assert not report.loaded and report.errors and report.still_fraction == 0.0


@pytest.mark.parametrize("check", [check_pybullet, check_mujoco], ids=["pybullet", "mujoco"])
def test_a_cup_in_an_open_drawer_stays_in_it(tmp_path, check):
    result = export_scene(drawer_scene(0.6), tmp_path / "drawer", glb=False)
    report = check(result.folder, seconds=2.0)
    assert report.loaded and not report.errors
    assert report.displacement["cup_1"] < 0.005 and report.displacement["bottle_1"] < 0.005, report.displacement
    assert report.displacement["box_1"] > 0.5  # this scene has no floor: the box falls, and the check sees it
