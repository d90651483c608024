"""Nothing non-finite reaches a URDF, and every pose written round-trips (hypothesis, bounded)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from recon_core.kinematic_tree import format_number, format_vector, rpy_of

STABILITY = settings(max_examples=40, deadline=None, derandomize=True)


@STABILITY
@given(rpy=st.tuples(st.floats(-np.pi, np.pi), st.sampled_from([-np.pi / 2, np.pi / 2, 0.0, 1e-9, np.pi / 2 - 1e-9]),
                     st.floats(-np.pi, np.pi)),
       xyz=st.tuples(*[st.floats(-1e6, 1e6)] * 3))
def test_rpy_and_numbers_round_trip_even_at_gimbal_lock(rpy, xyz):
    r = Rotation.from_euler("xyz", rpy).as_matrix()  # URDF: fixed axes x, y, z
    back = rpy_of(r)
    assert np.all(np.isfinite(back))
    np.testing.assert_allclose(Rotation.from_euler("xyz", back).as_matrix(), r, atol=1e-7)
    text = format_vector(np.r_[xyz, back])
    np.testing.assert_array_equal(np.array(text.split(), float), np.r_[xyz, back])  # exact (17 digits)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_numbers_are_refused_by_the_urdf_writer(bad):
    with pytest.raises(ValueError, match="non-finite"):
        format_number(bad)
    with pytest.raises(ValueError, match="non-finite"):
        format_vector([0.0, bad, 1.0])
