"""Generated bags use MCAP chunk compression (issue 25): smaller, and read back bit-identical.

A small generated recording (real renders: noisy colour, 16-bit depth, label images) is written
with each chunk compression and without; every bag must read back the same messages byte for
byte and the same frames through the loader, and the compressed ones must be much smaller.
Uncompressed bags (all bags written before) still read.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from panoptic_mapping.dataio import DataInputConfig
from panoptic_mapping.dataio.bag_writer import MCAP_COMPRESSIONS, RGBDBagWriter
from panoptic_mapping.dataio.registry import open_dataset


def _storage_file(bag: Path) -> Path:
    (f,) = bag.glob("*.mcap")
    return f


def _chunk_compressions(path: Path) -> set[str]:
    """The compression named by every chunk record of an MCAP file (walked record by record)."""
    data = path.read_bytes()
    assert data[:8] == b"\x89MCAP0\r\n"
    pos, found = 8, set()
    while pos + 9 <= len(data):
        op, length = data[pos], int.from_bytes(data[pos + 1 : pos + 9], "little")
        if op == 0x06:  # Chunk: start, end, uncompressed size (3 x u64), crc (u32), compression (string)
            n = int.from_bytes(data[pos + 9 + 28 : pos + 9 + 32], "little")
            found.add(data[pos + 9 + 32 : pos + 9 + 32 + n].decode())
        if op == 0x02:  # Footer
            break
        pos += 9 + length
    assert found, "no chunk"
    return found


def _raw_messages(bag: Path) -> list[tuple[str, int, bytes]]:
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as reader:
        return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]


def _frames(bag: Path):
    cfg = DataInputConfig()
    cfg.topics.labels = "/ground_truth/panoptic_labels"
    with open_dataset(bag, cfg) as loader:
        return list(loader)


@pytest.fixture(scope="module")
def generated(tmp_path_factory) -> tuple[Path, list]:
    """A generated 640x480 recording (default compression) and its frames as read."""
    from scene_recon.synthetic.generate import GenerateConfig, generate_recording

    out = tmp_path_factory.mktemp("gen") / "rec"
    summary = generate_recording(out, GenerateConfig(objects=4, frames=6, seed=1), progress=False)
    assert summary["compression"] == "lz4"
    return out, _frames(out)


def _rewrite(frames, path: Path, compression: str) -> Path:
    with RGBDBagWriter(path, compression=compression) as w:
        for f in frames:
            w.write_frame(f.timestamp_ns, f.color, f.depth, f.intrinsics, f.pose, f.extras["labels"])
    return path


def test_generated_bag_is_chunk_compressed_and_at_most_half_the_raw_size(generated, tmp_path):
    bag, frames = generated
    assert len(frames) == 6
    assert _chunk_compressions(_storage_file(bag)) == {"lz4"}
    raw = _rewrite(frames, tmp_path / "raw", "none")
    assert _chunk_compressions(_storage_file(raw)) == {""}
    size, raw_size = _storage_file(bag).stat().st_size, _storage_file(raw).stat().st_size
    assert size <= 0.5 * raw_size, (size, raw_size)  # demo: 830 MB -> ~360 MB (0.43)
    # the same messages, byte for byte, from the same frames compressed and not
    assert _raw_messages(_rewrite(frames, tmp_path / "lz4", "lz4")) == _raw_messages(raw)


@pytest.fixture(scope="module")
def uncompressed_frames(generated, tmp_path_factory) -> list:
    """The generated frames written again without compression (a bag as written before) and read."""
    return _frames(_rewrite(generated[1], tmp_path_factory.mktemp("raw") / "raw", "none"))


@pytest.mark.parametrize("compression", MCAP_COMPRESSIONS)
def test_every_compression_reads_back_bit_identical_frames(generated, uncompressed_frames, tmp_path, compression):
    _, frames = generated
    bag = _rewrite(frames, tmp_path / compression, compression)
    assert _chunk_compressions(_storage_file(bag)) == {"" if compression == "none" else compression}
    again = _frames(bag)
    assert len(again) == len(frames) == len(uncompressed_frames)
    for a, b, raw in zip(frames, again, uncompressed_frames, strict=True):
        for f in (a, raw):  # the generated (lz4) bag and the uncompressed one give the same frames
            assert f.timestamp_ns == b.timestamp_ns
            assert f.intrinsics == b.intrinsics
            np.testing.assert_array_equal(f.color, b.color)
            np.testing.assert_array_equal(f.depth, b.depth)
            np.testing.assert_array_equal(f.extras["labels"], b.extras["labels"])
        np.testing.assert_array_equal(raw.pose, b.pose)  # same TF bytes written
        np.testing.assert_allclose(a.pose, b.pose, atol=1e-12)  # TF -> matrix -> TF round trip
        assert b.extras["labels"].dtype == np.int32


def test_each_image_has_a_chunk_of_its_own(generated):
    """Readers pick chunks by channel: the TF pass and a colour/depth pass decompress nothing else."""
    from rosbags.rosbag2.storage_mcap import McapReader

    bag, frames = generated
    reader = McapReader(_storage_file(bag))
    reader.open()
    try:
        topics = [sorted(reader.channels[cid].topic for cid in c.channel_count) for c in reader.chunks]
        counts = [sum(c.channel_count.values()) for c in reader.chunks]
    finally:
        reader.close()
    images = {"/camera/color/image_raw", "/camera/depth/image_rect_raw", "/ground_truth/panoptic_labels"}
    image_chunks = [(t, n) for t, n in zip(topics, counts, strict=True) if images & set(t)]
    assert len(image_chunks) == 3 * len(frames)
    assert all(len(t) == 1 and n == 1 for t, n in image_chunks)
    assert len(topics) == 4 * len(frames)  # + one chunk of TF and camera info per frame


def test_zstd_is_smaller_than_lz4(generated, tmp_path):
    _, frames = generated
    sizes = {c: _storage_file(_rewrite(frames, tmp_path / c, c)).stat().st_size for c in ("lz4", "zstd")}
    assert sizes["zstd"] < sizes["lz4"], sizes


def test_bad_compression_settings_are_refused(tmp_path):
    with pytest.raises(ValueError, match="compression must be one of"):
        RGBDBagWriter(tmp_path / "a", compression="gzip")
    with pytest.raises(ValueError, match="db3 bags are written uncompressed"):
        RGBDBagWriter(tmp_path / "b", storage="db3", compression="lz4")
    assert RGBDBagWriter(tmp_path / "c", storage="db3").compression == "none"
    assert RGBDBagWriter(tmp_path / "d").compression == "lz4"
    assert not any(tmp_path.iterdir())  # nothing is written before the bag is opened
