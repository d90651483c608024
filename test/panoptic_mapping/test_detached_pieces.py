"""A thing's surface pieces beside its largest piece leave it (`extraction.detached_gap_m`, issue 22): a mask
that spilt over a depth edge onto something behind the object must not stretch its entity, while the legs
below a table top or a chair seat stay."""

from __future__ import annotations

import numpy as np
import pytest
from testsupport.tiny_room import IDS, box, render_frame, room_meshes, tiny_mapper_config

from panoptic_mapping.fusion import BACKGROUND, PanopticMasks
from panoptic_mapping.mapper import PanopticMapper, detached_pieces
from panoptic_mapping.pipeline import class_metas
from scene_recon.synthetic.items import RenderItem
from scene_recon.synthetic.renderer import RaycastRenderer


def _grid(lo, hi, step=0.02) -> np.ndarray:
    axes = [np.arange(a, b + 1e-9, step) for a, b in zip(lo, hi, strict=True)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def test_a_piece_beside_the_object_is_detached_legs_below_it_are_not():
    top = _grid([0, 0, 0.70], [0.8, 0.6, 0.72])
    legs = np.concatenate([_grid([x, y, 0.0], [x + 0.02, y + 0.02, 0.55]) for x in (0.02, 0.76) for y in (0.02, 0.56)])
    spill = _grid([1.4, 0.0, 0.6], [1.5, 0.1, 0.7])  # 60 cm beside the top
    pts = np.concatenate([top, legs, spill])
    drop = detached_pieces(pts, gap=0.2)
    assert drop[len(top) + len(legs):].all()
    assert not drop[:len(top) + len(legs)].any()


def test_nothing_is_detached_from_one_piece_or_when_the_pieces_beside_are_most_of_it():
    one = _grid([0, 0, 0], [0.3, 0.3, 0.3])
    assert not detached_pieces(one, gap=0.2).any()
    a, b = _grid([0, 0, 0], [0.2, 0.2, 0.2]), _grid([1.0, 0, 0], [1.2, 0.2, 0.2])
    assert not detached_pieces(np.concatenate([a, b]), gap=0.2).any()  # two equal halves: no verdict
    assert not detached_pieces(np.zeros((1, 3)), gap=0.2).any()


FLOOR, TABLE, CUP, CHAIR = 1, 10, 19, 12


@pytest.fixture(scope="module")
def spill_room():
    """The tiny room with a small box on the table 55 cm from the cup, unlabelled by itself."""
    meshes = room_meshes()
    meshes["stray"] = box([1.55, -0.62, 0.7], [1.63, -0.54, 0.76])
    return meshes


def _map(meshes, gap: float, fine: bool) -> list:
    """Every frame's cup mask also covers the stray box (a mask spilt onto a neighbour)."""
    renderer = RaycastRenderer([*[RenderItem(m, IDS[k], name=k) for k, m in meshes.items() if k != "stray"],
                                RenderItem(meshes["stray"], IDS["cup"], name="stray")])
    cfg = tiny_mapper_config(min_segment_points=40, min_segment_pixels=30)
    cfg.extraction.detached_gap_m = gap
    cfg.fine_surface.enabled = fine  # the 5 mm surface of small things carries the spilt label too
    mapper = PanopticMapper(cfg, class_metas())
    cls = np.array([BACKGROUND, FLOOR, TABLE, CUP, CHAIR], np.int32)
    eyes = [(0.3, y, z) for y in (-0.6, -0.2, 0.2) for z in (1.3, 1.6)]
    for i, eye in enumerate(eyes):
        frame, gt = render_frame(renderer, eye, target=(1.6, -0.3, 0.7), index=i)
        mapper.integrate(frame, PanopticMasks(gt.astype(np.int32), cls, cls > FLOOR, np.ones(5)))
    return mapper.entities()


def _cup_y_extent(ents) -> tuple[float, float]:
    cup = next(e for e in ents if e.class_name == "cup")
    return float(cup.vertices[:, 1].min()), float(cup.vertices[:, 1].max())


@pytest.mark.parametrize("fine", [True, False])
def test_the_cup_entity_loses_the_stray_box_its_masks_spilt_onto(spill_room, fine):
    lo, hi = _cup_y_extent(_map(spill_room, gap=0.0, fine=fine))
    assert lo < -0.5  # the paper's extraction: the cup reaches the stray box
    lo, hi = _cup_y_extent(_map(spill_room, gap=0.2, fine=fine))
    assert lo > -0.15 and hi < 0.15  # the cup (y -0.05..0.05) and its fringe alone
