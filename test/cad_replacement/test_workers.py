"""Objects replaced in worker processes: the same scene as in-process, and a dead pool costs nothing."""

from __future__ import annotations

import dataclasses
import logging
import os
import signal

import numpy as np
import pytest

from cad_replacement.cad.library import CadLibrary
from cad_replacement.replace_config import CadReplacementConfig
from cad_replacement.replacer import CadReplacer
from cad_replacement.workers import ReplaceWorkers, resolve_workers, usable_cpus
from scene_graph.builder import ContactGraphBuilder
from scene_graph.config import load_scene_graph_config
from scene_recon.synthetic.scene import build_scene, entities_from_ground_truth


@pytest.fixture(scope="module")
def room():
    builder = ContactGraphBuilder(load_scene_graph_config())
    builder.update(entities_from_ground_truth(build_scene(8, 5)))
    return builder.build(name="room"), builder.node_entities(), CadLibrary(seeds_per_class=3)


def _summary(result):
    return {o.name: (o.cad_id, o.pose, o.scale, o.joint_values) for o in result.scene}


def _assert_same(a, b):
    assert set(a) == set(b)
    for name, (cad_id, pose, scale, joints) in a.items():
        assert b[name][0] == cad_id, name
        np.testing.assert_allclose(b[name][1], pose, atol=1e-9, err_msg=name)
        np.testing.assert_allclose(b[name][2], scale, atol=1e-9, err_msg=name)
        assert b[name][3] == pytest.approx(joints, abs=1e-9), name


@pytest.fixture(scope="module")
def in_process(room):
    graph, nodes, library = room
    replacer = CadReplacer(library, CadReplacementConfig(workers=1))
    result = replacer.replace(graph, nodes)
    assert not replacer.workers_running
    return _summary(result)


def test_workers_place_every_object_exactly_as_in_process(room, in_process):
    graph, nodes, library = room
    things = sum(1 for n in graph.nodes.values() if n.category != "layout" and n.id in nodes)
    assert things >= 4
    with CadReplacer(library, CadReplacementConfig(workers=2, parallel_min_objects=4)) as replacer:
        result = replacer.replace(graph, nodes)
        assert replacer.workers_running
        _assert_same(in_process, _summary(result))
        assert all(r.candidates for r in result.records if r.kind == "cad")
        # an update of one entity goes to the (warm) workers too, and re-matches only that entity
        target = next(n for n in graph.nodes.values() if n.category != "layout" and n.id in nodes)
        bumped = dict(nodes)
        bumped[target.id] = dataclasses.replace(nodes[target.id], revision=nodes[target.id].revision + 1)
        again = replacer.replace(graph, bumped)
        assert again.rematched == 1
        _assert_same(in_process, _summary(again))
    assert not replacer.workers_running  # closed by the context manager


def test_a_killed_worker_pool_falls_back_to_in_process_replacement(room, in_process, caplog):
    graph, nodes, library = room
    pool = ReplaceWorkers(library, 2)
    try:
        config = CadReplacementConfig(workers=2, parallel_min_objects=4)
        CadReplacer(library, config, workers=pool).replace(graph, nodes)
        assert pool.started
        for proc in list(pool._pool._processes.values()):  # type: ignore[union-attr]
            os.kill(proc.pid, signal.SIGKILL)
        replacer = CadReplacer(library, config, workers=pool)  # nothing cached
        with caplog.at_level(logging.WARNING, logger="cad_replacement.workers"):
            result = replacer.replace(graph, nodes)
        _assert_same(in_process, _summary(result))
        assert pool.failed and not pool.started
        assert any("replacing in this process" in r.getMessage() for r in caplog.records)
    finally:
        pool.close()


def test_small_scenes_stay_in_process_and_the_worker_count_is_checked(room):
    graph, nodes, library = room
    things = sum(1 for n in graph.nodes.values() if n.category != "layout" and n.id in nodes)
    config = CadReplacementConfig(workers=2, parallel_min_objects=things + 1)
    replacer = CadReplacer(library, config)
    replacer.replace(graph, nodes)
    assert not replacer.workers_running
    assert resolve_workers(0) == min(usable_cpus(), 4) and resolve_workers(3) == 3
    with pytest.raises(ValueError, match="workers"):
        CadReplacementConfig(workers=-1)


def test_workers_start_single_threaded_and_leave_this_environment_alone(room, monkeypatch):
    _graph, _nodes, library = room
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "7")
    pool = ReplaceWorkers(library, 2)
    try:
        started = pool._ensure()
        assert started is not None
        for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
            assert started.submit(os.getenv, name).result(timeout=60) == "1", name
    finally:
        pool.close()
    assert "OPENBLAS_NUM_THREADS" not in os.environ and os.environ["OMP_NUM_THREADS"] == "7"


def test_thread_limits_apply_in_their_block_only():
    import open3d as o3d
    import scipy.linalg  # noqa: F401  (scipy's own OpenBLAS)

    from cad_replacement.workers import open3d_threads
    from scene_graph.blas import _openblas_libraries, single_blas_thread

    libs = _openblas_libraries()
    assert len(libs) >= 2  # numpy's and scipy's copies
    before = [getter() for _setter, getter in libs]
    o3d_before = o3d.utility.get_max_threads()
    with single_blas_thread(), open3d_threads(1):
        assert [getter() for _setter, getter in libs] == [1] * len(libs)
        assert o3d.utility.get_max_threads() == 1
    assert [getter() for _setter, getter in libs] == before
    assert o3d.utility.get_max_threads() == o3d_before


def test_the_fork_server_and_the_command_line_import_scipy_without_its_docstring_step(room):
    """``skip_scipy_docstring_notes``: SciPy's functions work and keep the docstrings SciPy wrote; the
    workers (forked from the fork server, which loads ``cad_replacement.workers`` first) have it too."""
    import subprocess
    import sys

    _graph, _nodes, library = room
    pool = ReplaceWorkers(library, 2)
    try:
        started = pool._ensure()
        assert started is not None
        probe = "__import__('scipy._lib._array_api', fromlist=['_']).FunctionDoc.__name__"
        assert started.submit(eval, probe).result(timeout=60) == "_DocAsIs"
    finally:
        pool.close()
    code = ("from cad_replacement.workers import skip_scipy_docstring_notes; skip_scipy_docstring_notes(); "
            "import numpy as np, scipy.special, scipy.spatial; from scipy._lib import _array_api; "
            "assert _array_api.FunctionDoc.__name__ == '_DocAsIs'; "
            "assert abs(scipy.special.logsumexp(np.zeros(4)) - np.log(4)) < 1e-12; "
            "assert scipy.spatial.cKDTree(np.eye(3)).query([1, 0, 0])[1] == 0; "
            "assert scipy.special.logsumexp.__doc__ and 'Parameters' in scipy.special.logsumexp.__doc__")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
