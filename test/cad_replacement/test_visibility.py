"""Which CAD samples the observation could have seen (``alignment.visible_samples``) under mapped noise.

A mapped surface's normals scatter by 10-20 degrees. The coverage tests pool normals within
``BIN_REACH_DEG`` of a direction bin and measure face offsets from the observed object's centre,
so the front of a book 3.6 m from the map origin still counts as seen and the AE stays two-sided.
"""

from __future__ import annotations

import numpy as np

from cad_replacement.alignment import FaceAreas, observed_area_per_bin, visible_samples

CENTRE = np.array([3.0, -2.0, 0.8])
SIZE = np.array([0.2, 0.04, 0.25])  # a book standing with its cover towards -y


def _front(n: int, rng: np.random.Generator, tilt_deg: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Points on the book's -y face and their normals tilted by up to ``tilt_deg``; area per point."""
    u = rng.uniform(-0.5, 0.5, (n, 2))
    pts = CENTRE + np.c_[u[:, 0] * SIZE[0], np.full(n, -0.5 * SIZE[1]), u[:, 1] * SIZE[2]]
    nrm = np.tile([0.0, -1.0, 0.0], (n, 1)) + np.tan(np.radians(tilt_deg)) * rng.uniform(-1, 1, (n, 3)) * [1, 0, 1]
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return pts, nrm, SIZE[0] * SIZE[2] / n


def test_a_noisy_mapped_front_makes_the_cad_front_seen() -> None:
    rng = np.random.default_rng(0)
    obs_pts, obs_nrm, obs_area = _front(800, rng, tilt_deg=20.0)
    cad_pts, cad_nrm, cad_area = _front(300, rng, tilt_deg=0.0)
    bin_area = observed_area_per_bin(obs_nrm, obs_area)
    every = np.ones(len(cad_pts), dtype=bool)
    faces = FaceAreas.build(obs_nrm, obs_pts, obs_area, CENTRE)
    seen = visible_samples(cad_nrm, every, bin_area, cad_area, 0.25, samples_map=cad_pts, face_area=faces)
    assert seen.mean() > 0.9
    # Offsets from the map origin (3.6 m away) spread the scattered face over many slabs: not seen.
    far = FaceAreas.build(obs_nrm, obs_pts, obs_area)
    assert visible_samples(cad_nrm, every, bin_area, cad_area, 0.25, samples_map=cad_pts, face_area=far).mean() < 0.5


def test_a_face_the_observation_never_showed_stays_unseen() -> None:
    rng = np.random.default_rng(1)
    obs_pts, obs_nrm, obs_area = _front(800, rng, tilt_deg=20.0)
    back_pts = obs_pts + np.array([0.0, SIZE[1], 0.0])
    back_nrm = np.tile([0.0, 1.0, 0.0], (len(back_pts), 1))  # the cover at the back: never observed
    faces = FaceAreas.build(obs_nrm, obs_pts, obs_area, CENTRE)
    seen = visible_samples(back_nrm, np.ones(len(back_pts), dtype=bool), observed_area_per_bin(obs_nrm, obs_area),
                           obs_area, 0.25, samples_map=back_pts, face_area=faces)
    assert not seen.any()
