"""`LabeledTSDF.extract_mesh` reads Open3D's "no confident surface" error as an empty mesh, and only that one:
any other extraction failure is raised. Read as "no surface", it had a node publish an empty map to its
consumers (a late joiner's entity message held 0 entities in a loaded CI run)."""

from __future__ import annotations

import numpy as np
import pytest

from panoptic_mapping.config import MapperConfig
from panoptic_mapping.tsdf_map import LabeledTSDF


def _tsdf_with_unconfident_blocks() -> LabeledTSDF:
    tsdf = LabeledTSDF(MapperConfig().tsdf)
    tsdf._flat_indices(np.array([[0.0, 0.0, 1.0], [0.5, 0.5, 1.0]]), activate=True)  # blocks, no integration
    assert tsdf.num_blocks > 0
    return tsdf


def test_blocks_without_a_confident_surface_give_an_empty_mesh():
    v, f, labels = _tsdf_with_unconfident_blocks().extract_mesh()
    assert v.shape == (0, 3) and f.shape == (0, 3) and labels.shape == (0,)


def test_another_extraction_failure_is_raised():
    tsdf = _tsdf_with_unconfident_blocks()

    class _Failing:
        def __init__(self, grid):
            self.grid = grid

        def hashmap(self):
            return self.grid.hashmap()

        def extract_triangle_mesh(self, weight_threshold: float):
            raise RuntimeError("[Open3D Error] MemoryManager: out of memory")

    tsdf.vbg = _Failing(tsdf.vbg)
    with pytest.raises(RuntimeError, match="out of memory"):
        tsdf.extract_mesh()
