"""A wrong class flickered onto an object in two frames is no entity (issue 22, bench-office draw 1).

The oracle's noise called a chair `sofa` in two keyframes: two frames meet the birth rule
(`extraction.min_instance_frames` 2), the later frames outvote the sofa on the chair's surface, and what
the sofa keeps is a shred along a border (64 vertices on bench-office; here 65): a false `sofa` entity.
`extraction.min_observed_share` asks a thing entity to own at least that share of the surface one frame
showed of its instance; the shred owns 2 % of it, every real object more than all of it.
"""

from __future__ import annotations

import numpy as np
import pytest
from testsupport.tiny_room import EYES, IDS, INTR, render_frame, room_renderer, tiny_mapper_config

from panoptic_mapping.fusion import BACKGROUND, PanopticMasks
from panoptic_mapping.mapper import PanopticMapper, _face_area, _segment_area
from panoptic_mapping.panoptic_counts import PanopticCounts
from panoptic_mapping.pipeline import class_metas

FLOOR, TABLE, CUP, CHAIR, SOFA = 1, 10, 19, 12, 13
#: The five views and five more a little lower and aside: ten segmented frames.
VIEWS = EYES + [(x + 0.1, y + 0.1, z - 0.1) for x, y, z in EYES]


@pytest.fixture(scope="module")
def renderer():
    return room_renderer()


def _masks(gt: np.ndarray, chair_as_sofa: bool) -> PanopticMasks:
    """Ground-truth masks; with `chair_as_sofa` the chair's mask carries the class sofa (mask id 5)."""
    cls = np.array([BACKGROUND, FLOOR, TABLE, CUP, CHAIR, SOFA], np.int32)
    labels = gt.astype(np.int32)
    if chair_as_sofa:
        labels = np.where(gt == IDS["chair"], 5, labels)
    return PanopticMasks(labels, cls, cls > FLOOR, np.ones(6))


def _map(renderer, share: float, flicker: set[int]) -> tuple[PanopticMapper, list]:
    cfg = tiny_mapper_config(min_segment_points=40, min_segment_pixels=20)
    cfg.extraction.min_observed_share = share
    mapper = PanopticMapper(cfg, class_metas())
    for i, eye in enumerate(VIEWS):
        frame, gt = render_frame(renderer, eye, index=i)
        mapper.integrate(frame, _masks(gt, i in flicker))
    return mapper, mapper.entities()


def _things(ents: list) -> list[str]:
    return sorted(e.class_name for e in ents if e.is_thing)


def test_a_class_flickered_onto_an_object_in_two_frames_is_not_born(renderer):
    mapper, ents = _map(renderer, 0.25, flicker={0, 1})
    assert _things(ents) == ["chair", "cup", "table"]
    # without the rule the two frames' sofa is born: a shred of the chair, 2 % of what one frame showed of it
    plain, plain_ents = _map(renderer, 0.0, flicker={0, 1})
    assert _things(plain_ents) == ["chair", "cup", "sofa", "table"]
    sofa = next(e for e in plain_ents if e.class_name == "sofa")
    area = _face_area(np.asarray(sofa.vertices), np.asarray(sofa.faces), np.zeros(len(sofa.faces), np.int64))[0]
    assert area < 0.1 * plain.counts.instance_area[sofa.id]
    # every real object owns more of the map than one frame showed of it (the cup included: a few pixels a
    # frame, every one of them counted)
    for e in ents:
        if e.is_thing:
            own = _face_area(np.asarray(e.vertices), np.asarray(e.faces), np.zeros(len(e.faces), np.int64))[0]
            assert own > mapper.counts.instance_area[e.id], e.class_name


def test_without_the_flicker_the_rule_changes_nothing(renderer):
    _, ents = _map(renderer, 0.25, flicker=set())
    _, plain = _map(renderer, 0.0, flicker=set())
    assert _things(ents) == _things(plain) == ["chair", "cup", "table"]
    assert [len(e.vertices) for e in ents] == [len(e.vertices) for e in plain]


def test_segment_area_is_the_fronto_parallel_surface_of_the_pixels():
    """A wall 2 m away filling the image: every pixel covers (2 / fx) (2 / fy) m^2; sampled every 2nd pixel."""
    h, w = INTR.height, INTR.width
    seg = np.zeros((h, w), np.int64)
    seg[:, : w // 2] = 1
    seg[:, w // 2:] = 2
    pts = np.zeros((h, w, 3), np.float32)
    pts[..., 2] = 2.0
    area = _segment_area(seg[::2, ::2].ravel(), pts[::2, ::2], INTR.matrix, 2, 3)
    per_pixel = (2.0 / INTR.fx) * (2.0 / INTR.fy)
    assert area[0] == 0.0
    np.testing.assert_allclose(area[1:], [h * w / 2 * per_pixel] * 2, rtol=1e-9)


def test_instance_area_survives_saving_and_instance_merging():
    counts = PanopticCounts()
    counts.instance_area = {3: 0.5, 7: 0.25}
    counts.instance_frames = {3: 2, 7: 4}
    again = PanopticCounts.from_arrays(counts.to_arrays())
    assert again.instance_area == {3: 0.5, 7: 0.25}
    again.merge_instances(7, 3)
    assert again.instance_area == {3: 0.5} and again.instance_frames == {3: 6}
    # a map saved before the area was kept loads with none
    old = {k: v for k, v in counts.to_arrays().items() if not k.startswith("instance_area")}
    assert PanopticCounts.from_arrays(old).instance_area == {}
