"""Checkpoints of the map: generations written atomically, damaged ones reported and skipped."""

from __future__ import annotations

import json
import logging
import shutil

import numpy as np
import pytest

from panoptic_mapping.checkpoint import Checkpointer, CheckpointStore
from panoptic_mapping.config import CheckpointConfig, MapperConfig
from panoptic_mapping.dataio import CameraIntrinsics, RGBDFrame
from panoptic_mapping.mapper import PanopticMapper
from recon_core.errors import CheckpointError, StorageError

INTR = CameraIntrinsics(80.0, 80.0, 39.5, 29.5, 80, 60)


def _mapper(frames: int) -> PanopticMapper:
    """A small map: a wall seen `frames` times from slightly different places."""
    mapper = PanopticMapper(MapperConfig())
    for i in range(frames):
        pose = np.eye(4)
        pose[0, 3] = 0.02 * i
        depth = np.full((60, 80), 1.5, np.float32)
        mapper.integrate(RGBDFrame(np.zeros((60, 80, 3), np.uint8), depth, INTR, pose, i * 10**8, index=i), None)
    return mapper


@pytest.fixture
def store(tmp_path):
    """Three generations (1, 2, 3 frames); keep=2 leaves generations 2 and 3."""
    s = CheckpointStore(tmp_path / "checkpoints", keep=2)
    for n in (1, 2, 3):
        s.save(_mapper(n), {"frames_read": n}, {"poses": np.zeros((n, 4, 4))})
    return s


def test_generations_rotate_and_the_newest_loads_with_its_progress(store):
    assert [g for g, _ in store.generations()] == [3, 2]
    ckpt = store.load_latest()
    assert ckpt.generation == 3 and ckpt.progress["frames_read"] == 3 and not ckpt.skipped
    assert ckpt.mapper.frames_integrated == 3 and ckpt.arrays["poses"].shape == (3, 4, 4)
    assert not list(store.folder.glob(".gen-*"))  # no temporary folder left behind


def _truncate_npz(gen):
    p = gen / "map.npz"
    p.write_bytes(p.read_bytes()[:1000])
    return "map.npz"


def _bad_json(gen):
    (gen / "map.json").write_text('{"format_version": 1, "config": {', encoding="utf-8")
    return "map.json"


def _mismatched_pair(gen):
    """map.npz of generation 2 under generation 3's map.json, the manifest made to agree: the pair check."""
    from panoptic_mapping.checkpoint import _sha256

    shutil.copy(gen.parent / "gen-000002" / "map.npz", gen / "map.npz")
    manifest = json.loads((gen / "checkpoint.json").read_text())
    manifest["files"]["map.npz"]["sha256"] = _sha256(gen / "map.npz")[0]
    (gen / "checkpoint.json").write_text(json.dumps(manifest))
    return "map.npz"


def _bad_manifest(gen):
    (gen / "checkpoint.json").write_text("not json", encoding="utf-8")
    return "checkpoint.json"


def _missing_file(gen):
    (gen / "map.json").unlink()
    return "map.json"


@pytest.mark.parametrize("damage", [_truncate_npz, _bad_json, _mismatched_pair, _bad_manifest, _missing_file])
def test_a_damaged_newest_checkpoint_is_named_and_the_older_one_used(store, damage, caplog):
    newest = store.generations()[0][1]
    name = damage(newest)
    with caplog.at_level(logging.WARNING, logger="panoptic_mapping.checkpoint"):
        ckpt = store.load_latest()
    assert ckpt.generation == 2 and ckpt.progress["frames_read"] == 2
    assert len(ckpt.skipped) == 1 and str(newest / name) in ckpt.skipped[0]
    assert any(str(newest / name) in r.getMessage() for r in caplog.records if r.levelno == logging.WARNING)
    with pytest.raises(CheckpointError, match=name.replace(".", r"\.")):
        CheckpointStore.read(newest)


def test_no_usable_checkpoint_is_an_error_naming_every_file(store):
    for _, gen in store.generations():
        _truncate_npz(gen)
    with pytest.raises(CheckpointError) as err:
        store.load_latest()
    assert "gen-000003/map.npz" in str(err.value) and "gen-000002/map.npz" in str(err.value)
    assert isinstance(err.value, StorageError)


def test_a_generation_killed_mid_write_is_invisible(store, tmp_path):
    tmp = store.folder / ".gen-000004.tmp-999999999"  # what a kill -9 during save leaves
    tmp.mkdir()
    (tmp / "map.npz").write_bytes(b"PK\x03\x04partial")
    assert store.load_latest().generation == 3
    store.save(_mapper(1))
    assert [g for g, _ in store.generations()] == [4, 3] and not tmp.exists()


def test_saved_map_pair_is_checked(tmp_path):
    _mapper(2).save(tmp_path / "a")
    _mapper(3).save(tmp_path / "b")
    shutil.copy(tmp_path / "b" / "map.npz", tmp_path / "a" / "map.npz")
    with pytest.raises(CheckpointError, match=r"a/map\.npz does not belong to map\.json"):
        PanopticMapper.load(tmp_path / "a")
    (tmp_path / "b" / "map.json").write_text("{", encoding="utf-8")
    with pytest.raises(CheckpointError, match=r"b/map\.json: damaged"):
        PanopticMapper.load(tmp_path / "b")
    # a map saved before checksums existed: damage is still reported, naming the file
    _mapper(1).save(tmp_path / "c")
    meta = json.loads((tmp_path / "c" / "map.json").read_text())
    del meta["npz_sha256"]
    (tmp_path / "c" / "map.json").write_text(json.dumps(meta))
    (tmp_path / "c" / "map.npz").write_bytes((tmp_path / "c" / "map.npz").read_bytes()[:500])
    with pytest.raises(CheckpointError, match=r"c/map\.npz: damaged"):
        PanopticMapper.load(tmp_path / "c")


def test_checkpointer_fires_by_frames_or_by_time(tmp_path):
    now = [0.0]
    cp = Checkpointer(CheckpointStore(tmp_path), CheckpointConfig(every_n_frames=10, every_s=5.0), clock=lambda: now[0])
    cp.start(0)
    assert not cp.due(9) and cp.due(10)
    mapper = _mapper(3)
    cp.save(mapper)
    assert cp.saved == 1 and cp.last_cost_s > 0 and not cp.due(3)
    now[0] = 5.0
    assert not cp.due(3) and cp.due(4)  # time passed, but only a new frame makes a checkpoint worth it
    assert not Checkpointer(CheckpointStore(tmp_path), CheckpointConfig(enabled=False)).due(1000)
