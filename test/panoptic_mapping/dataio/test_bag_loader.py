"""Real bags (both storages) written, read back through the loaders, checked pixel-exact."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from testsupport.rawbag import RawBag, camera_info, image, tf_message

from panoptic_mapping.dataio import CameraIntrinsics, DataInputConfig, DatasetError
from panoptic_mapping.dataio.bag import RosbagLoader
from panoptic_mapping.dataio.bag_writer import T_LINK_OPTICAL, RGBDBagWriter
from panoptic_mapping.dataio.registry import detect_format, open_dataset
from panoptic_mapping.dataio.transforms import make_transform, quat_to_matrix

K = (300.0, 310.0, 31.5, 23.5)
W, H = 64, 48
PERIOD = 33_333_333
T0 = 5 * 10**9


def yaw_quat(yaw: float) -> np.ndarray:
    return np.array([0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)])


def random_frames(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    colors = rng.integers(0, 256, (n, H, W, 3), dtype=np.uint8)
    depths = (rng.integers(300, 6000, (n, H, W)) / 1000.0).astype(np.float32)
    return colors, depths


@pytest.mark.parametrize("storage", ["mcap", "db3"])
def test_writer_round_trip_pixel_exact(tmp_path: Path, storage: str):
    colors, depths = random_frames(6)
    intr = CameraIntrinsics(*K, width=W, height=H)
    poses = [make_transform([0.1 * i, -0.2, 1.4], yaw_quat(0.3 * i)) @ T_LINK_OPTICAL for i in range(6)]
    labels = np.arange(W * H, dtype=np.int32).reshape(H, W)
    bag = tmp_path / f"rec_{storage}"
    with RGBDBagWriter(bag, storage=storage) as writer:
        for i in range(6):
            writer.write_frame(T0 + i * PERIOD, colors[i], depths[i], intr, poses[i], labels=labels + i)
    assert detect_format(bag) == "rosbag2"
    assert (bag / f"{bag.name}.{storage}").is_file()
    cfg = DataInputConfig()
    cfg.topics.labels = "/ground_truth/panoptic_labels"
    with open_dataset(bag, cfg) as loader:
        frames = list(loader)
        assert loader.skips.as_dict() == dict.fromkeys(loader.skips.as_dict(), 0)
    assert len(frames) == 6
    for i, f in enumerate(frames):
        np.testing.assert_array_equal(f.color, colors[i])
        assert f.depth.dtype == np.float32
        np.testing.assert_allclose(f.depth, depths[i], atol=1e-6)  # written in whole mm: exact
        assert f.intrinsics == intr
        np.testing.assert_allclose(f.pose, poses[i], atol=1e-12)
        assert f.timestamp_ns == T0 + i * PERIOD
        np.testing.assert_array_equal(f.extras["labels"], labels + i)
    # the bare storage file opens too
    with RosbagLoader(bag / f"{bag.name}.{storage}") as loader:
        assert sum(1 for _ in loader) == 6


ENCODINGS = [("rgb8", lambda c: c), ("bgr8", lambda c: c[:, :, ::-1]),
             ("rgba8", lambda c: np.dstack([c, np.full(c.shape[:2], 7, np.uint8)])),
             ("bgra8", lambda c: np.dstack([c[:, :, ::-1], np.full(c.shape[:2], 7, np.uint8)]))]


@pytest.mark.parametrize("storage", ["mcap", "db3"])
@pytest.mark.parametrize(("encoding", "to_wire"), ENCODINGS, ids=[e for e, _ in ENCODINGS])
def test_color_encodings_and_32fc1_depth_with_row_padding(tmp_path, storage, encoding, to_wire):
    colors, depths = random_frames(2, seed=3)
    bag = RawBag()
    for i in range(2):
        t = T0 + i * PERIOD
        bag.add("/cam/color/image_raw", image(t, "opt", encoding, to_wire(colors[i]), step_pad=8))
        bag.add("/cam/aligned_depth_to_color/image_raw", image(t, "opt", "32FC1", depths[i], step_pad=4))
        bag.add("/cam/color/camera_info", camera_info(t, "opt", K, W, H))
        bag.add("/tf", tf_message([(t, "map", "opt", np.zeros(3), np.array([0, 0, 0, 1.0]))]))
    path = bag.write(tmp_path / "enc", storage)
    with open_dataset(path) as loader:
        frames = list(loader)
        assert loader.topics["depth"] == "/cam/aligned_depth_to_color/image_raw"
    assert len(frames) == 2
    for i, f in enumerate(frames):
        np.testing.assert_array_equal(f.color, colors[i])
        np.testing.assert_array_equal(f.depth, depths[i])


def test_mono8_and_bigendian_16uc1(tmp_path):
    rng = np.random.default_rng(1)
    gray = rng.integers(0, 256, (H, W), dtype=np.uint8)
    mm = rng.integers(1, 65535, (H, W)).astype(">u2")
    bag = RawBag()
    bag.add("/rgb/image", image(T0, "opt", "mono8", gray))
    bag.add("/depth/image", image(T0, "opt", "16UC1", mm, bigendian=1))
    bag.add("/rgb/camera_info", camera_info(T0, "opt", K, W, H))
    bag.add("/tf_static", tf_message([(0, "map", "opt", np.ones(3), np.array([0, 0, 0, 1.0]))]))
    with open_dataset(bag.write(tmp_path / "mono")) as loader:
        (f,) = list(loader)
    np.testing.assert_array_equal(f.color, np.repeat(gray[:, :, None], 3, axis=2))
    np.testing.assert_allclose(f.depth, mm.astype(np.float64) / 1000.0, rtol=1e-6)
    np.testing.assert_allclose(f.pose[:3, 3], [1, 1, 1])


@pytest.mark.parametrize("storage", ["mcap", "db3"])
def test_multi_hop_tf_chain_with_interpolation(tmp_path, storage):
    """map -> odom (dynamic) -> base_link (dynamic) -> camera_link (static) -> optical (static)."""
    colors, depths = random_frames(5, seed=2)
    bag = RawBag()
    # Dynamic edges sampled at 10 Hz, images at 30 Hz between samples: poses must be interpolated.
    def odom(t):
        return np.array([0.5 * t, 0.0, 0.0]), yaw_quat(0.1 * t)

    def base(t):
        return np.array([0.0, 0.2 * t, 0.0]), yaw_quat(-0.4 * t)

    for k in range(0, 8):
        t = T0 + k * 100_000_000
        ts = (t - T0) * 1e-9
        bag.add("/tf", tf_message([(t, "map", "odom", *odom(ts)), (t, "odom", "base_link", *base(ts))]))
    cam_t, cam_q = np.array([0.1, 0.0, 1.2]), np.array([0.0, np.sin(0.1), 0.0, np.cos(0.1)])
    opt_q = np.array([-0.5, 0.5, -0.5, 0.5])  # the standard link -> optical rotation
    bag.add("/tf_static", tf_message([(T0, "base_link", "camera_link", cam_t, cam_q),
                                      (T0, "camera_link", "camera_color_optical_frame", np.zeros(3), opt_q)]),
            log_time=T0)
    stamps = [T0 + 50_000_000 + i * PERIOD for i in range(5)]
    for i, t in enumerate(stamps):
        bag.add("/camera/color/image_raw", image(t, "camera_color_optical_frame", "rgb8", colors[i]))
        bag.add("/camera/depth/image_rect_raw",
                image(t, "camera_color_optical_frame", "16UC1", np.round(depths[i] * 1000).astype("<u2")))
        bag.add("/camera/color/camera_info", camera_info(t, "camera_color_optical_frame", K, W, H))
    with open_dataset(bag.write(tmp_path / "chain", storage)) as loader:
        frames = list(loader)
    assert len(frames) == 5
    for f, t in zip(frames, stamps, strict=False):
        ts = (t - T0) * 1e-9
        # linear translation + yaw interpolation of each edge equals the closed form here because each
        # edge's yaw and translation are linear in time
        expected = (make_transform(*odom(ts)) @ make_transform(*base(ts)) @ make_transform(cam_t, cam_q)
                    @ make_transform(np.zeros(3), opt_q))
        np.testing.assert_allclose(f.pose, expected, atol=1e-9)
        # optical convention: z axis of the camera looks along the base's x axis (tilted by the static pitch)
        assert np.isclose(np.linalg.det(f.pose[:3, :3]), 1.0)
    np.testing.assert_allclose(quat_to_matrix(opt_q) @ [0, 0, 1], [1, 0, 0], atol=1e-12)


def test_approximate_sync_pairs_nearest_color(tmp_path):
    colors, depths = random_frames(12, seed=4)
    bag = RawBag()
    bag.add("/tf_static", tf_message([(0, "map", "opt", np.zeros(3), np.array([0, 0, 0, 1.0]))]), log_time=0)
    bag.add("/camera/color/camera_info", camera_info(T0, "opt", K, W, H))
    # color at 60 Hz (12 frames), depth at 30 Hz stamped 3 ms after every second color
    for i in range(12):
        t = T0 + i * PERIOD // 2
        bag.add("/camera/color/image_raw", image(t, "opt", "rgb8", colors[i]))
        if i % 2 == 0:
            bag.add("/camera/depth/image_rect_raw", image(t + 3_000_000, "opt", "32FC1", depths[i]))
    with open_dataset(bag.write(tmp_path / "sync")) as loader:
        frames = list(loader)
        skips = loader.skips
    assert len(frames) == 6
    for k, f in enumerate(frames):
        np.testing.assert_array_equal(f.color, colors[2 * k])  # not the color 13.7 ms later
    assert skips.unpaired_color == 6


# ------------------------------------------------------------------ bad input
def _simple_bag(tmp_path: Path, n: int = 4, **kw) -> Path:
    colors, depths = random_frames(n, seed=5)
    intr = CameraIntrinsics(*K, width=W, height=H)
    path = tmp_path / kw.pop("name", "simple")
    with RGBDBagWriter(path, **kw) as w:
        for i in range(n):
            w.write_frame(T0 + i * PERIOD, colors[i], depths[i], intr, np.eye(4))
    return path


@pytest.mark.parametrize("compression", ["none", "lz4", "zstd", "db3"])
def test_truncated_bag_yields_the_frames_before_the_cut(tmp_path, caplog, compression):
    """A recorder killed mid-write: no summary, no footer, no metadata.yaml; frames before the cut are read."""
    n = 40  # ~0.6 MB: zstd compresses in 128 kB blocks, a cut-off chunk decodes block by block
    colors, depths = random_frames(n, seed=5)
    intr = CameraIntrinsics(*K, width=W, height=H)
    path = tmp_path / "full"
    storage = "db3" if compression == "db3" else "mcap"
    # chunk compression (lz4 is the writer's default for mcap; zstd as `ros2 bag record
    # --compression-mode storage`), or none: a bag written before issue 25
    writer = RGBDBagWriter(path, storage=storage, compression=None if storage == "db3" else compression)
    with writer as w:
        for i in range(n):
            w.write_frame(T0 + i * PERIOD, colors[i], depths[i], intr, np.eye(4))
    data = (path / f"full.{storage}").read_bytes()
    killed = tmp_path / "killed"  # what a killed recorder leaves: the storage file only, cut short
    killed.mkdir()
    (killed / f"killed_0.{storage}").write_bytes(data[: len(data) * 6 // 10])
    assert detect_format(killed) == "rosbag2"
    with caplog.at_level(logging.WARNING), open_dataset(killed) as loader:
        frames = list(loader)
        assert loader.truncated and loader.damage
    assert "reading the frames before the cut" in caplog.text
    assert 1 <= len(frames) < n
    for i, f in enumerate(frames):  # the frames read are the first ones, pixel exact
        np.testing.assert_array_equal(f.color, colors[i])
        np.testing.assert_allclose(f.depth, depths[i], atol=1e-6)
        assert f.timestamp_ns == T0 + i * PERIOD
    assert len(frames) >= (n // 4 if compression == "zstd" else n // 2)  # what lies before the cut is read
    # cut inside the file header: nothing to salvage, a clear error
    (tmp_path / "stub.mcap").write_bytes(data[:30])
    with pytest.raises(DatasetError, match="cannot open bag"):
        RosbagLoader(tmp_path / "stub.mcap")
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 100)
    with pytest.raises(DatasetError):
        RosbagLoader(garbage)


def test_bag_without_depth_or_camera_info(tmp_path):
    colors, _ = random_frames(1)
    bag = RawBag()
    bag.add("/camera/color/image_raw", image(T0, "opt", "rgb8", colors[0]))
    bag.add("/camera/color/camera_info", camera_info(T0, "opt", K, W, H))
    with pytest.raises(DatasetError, match="no depth topic"):
        RosbagLoader(bag.write(tmp_path / "nodepth"))
    bag = RawBag()
    bag.add("/camera/color/image_raw", image(T0, "opt", "rgb8", colors[0]))
    bag.add("/camera/depth/image_raw", image(T0, "opt", "32FC1", np.ones((H, W), np.float32)))
    path = bag.write(tmp_path / "noinfo")
    with pytest.raises(DatasetError, match="CameraInfo"):
        RosbagLoader(path)
    cfg = DataInputConfig(intrinsics=list(K), require_pose=False)
    with RosbagLoader(path, cfg) as loader:
        (f,) = list(loader)
    assert f.intrinsics == CameraIntrinsics(*K, width=W, height=H) and f.pose is None


def test_unknown_encoding_and_size_mismatch_are_counted_skips(tmp_path, caplog):
    colors, depths = random_frames(3, seed=6)
    bag = RawBag()
    bag.add("/tf_static", tf_message([(0, "map", "opt", np.zeros(3), np.array([0, 0, 0, 1.0]))]), log_time=0)
    for i in range(3):
        t = T0 + i * PERIOD
        bag.add("/camera/color/camera_info", camera_info(t, "opt", K, W, H))
        enc = "yuv422" if i == 0 else "rgb8"
        col = colors[i] if i != 1 else colors[i][:, :32]
        bag.add("/camera/color/image_raw", image(t, "opt", enc, col))
        bag.add("/camera/depth/image_rect_raw", image(t, "opt", "32FC1", depths[i]))
    with caplog.at_level(logging.ERROR), open_dataset(bag.write(tmp_path / "bad")) as loader:
        frames = list(loader)
        assert loader.skips.bad_image == 2
    assert len(frames) == 1
    np.testing.assert_array_equal(frames[0].color, colors[2])
    assert "unsupported color encoding 'yuv422'" in caplog.text
    assert "differ in size" in caplog.text


def test_nan_inf_negative_depth_is_zeroed_and_counted(tmp_path):
    colors, depths = random_frames(2, seed=7)
    depths[0][0, :4] = [np.nan, np.inf, -1.0, -np.inf]
    depths[1][:] = np.nan  # a frame with no valid depth at all is skipped
    bag = RawBag()
    bag.add("/tf_static", tf_message([(0, "map", "opt", np.zeros(3), np.array([0, 0, 0, 1.0]))]), log_time=0)
    for i in range(2):
        t = T0 + i * PERIOD
        bag.add("/camera/color/camera_info", camera_info(t, "opt", K, W, H))
        bag.add("/camera/color/image_raw", image(t, "opt", "rgb8", colors[i]))
        bag.add("/camera/depth/image_rect_raw", image(t, "opt", "32FC1", depths[i]))
    with open_dataset(bag.write(tmp_path / "nan")) as loader:
        frames = list(loader)
        assert loader.skips.all_depth_invalid == 1
    (f,) = frames
    assert f.invalid_depth_pixels == 4
    np.testing.assert_array_equal(f.depth[0, :4], 0.0)
    assert np.all(np.isfinite(f.depth))


def test_missing_tf_and_non_monotonic_stamps(tmp_path):
    colors, depths = random_frames(5, seed=8)
    bag = RawBag()
    # TF only covers the first 2 frames; frame 3 has a stamp going backwards.
    for k in range(3):
        t = T0 + k * PERIOD // 2
        bag.add("/tf", tf_message([(t, "map", "opt", np.array([k, 0, 0.0]), np.array([0, 0, 0, 1.0]))]))
    stamps = [T0, T0 + PERIOD, T0 + 2 * PERIOD, T0 + PERIOD // 2, T0 + 4 * PERIOD]
    for i, t in enumerate(stamps):
        log_time = T0 + i * PERIOD
        bag.add("/camera/color/camera_info", camera_info(t, "opt", K, W, H), log_time)
        bag.add("/camera/color/image_raw", image(t, "opt", "rgb8", colors[i]), log_time)
        bag.add("/camera/depth/image_rect_raw", image(t, "opt", "32FC1", depths[i]), log_time)
    path = bag.write(tmp_path / "tf")
    with open_dataset(path, DataInputConfig(tf_max_extrapolation_s=0.01)) as loader:
        frames = list(loader)
        skips = loader.skips
    assert [f.timestamp_ns for f in frames] == [T0, T0 + PERIOD]
    assert skips.no_pose == 2 and skips.non_monotonic == 2  # color and depth of frame 3
    with open_dataset(path, DataInputConfig(require_pose=False, tf_max_extrapolation_s=0.01)) as loader:
        frames = list(loader)
    assert [f.pose is None for f in frames] == [False, False, True, True]


def test_topic_selection_errors_name_the_option(tmp_path):
    colors, depths = random_frames(1)
    bag = RawBag()
    for topic in ("/a/color/image_raw", "/b/color/image_raw"):
        bag.add(topic, image(T0, "opt", "rgb8", colors[0]))
    bag.add("/a/depth/image_raw", image(T0, "opt", "32FC1", depths[0]))
    bag.add("/a/color/camera_info", camera_info(T0, "opt", K, W, H))
    path = bag.write(tmp_path / "two")
    with pytest.raises(DatasetError, match="--color-topic"):
        RosbagLoader(path)
    cfg = DataInputConfig(require_pose=False)
    cfg.topics.color = "/b/color/image_raw"
    with RosbagLoader(path, cfg) as loader:
        assert loader.topics["camera_info"] == "/a/color/camera_info"
        assert len(list(loader)) == 1
    cfg.topics.color = "/nope"
    with pytest.raises(DatasetError, match="'/nope' is not in"):
        RosbagLoader(path, cfg)


def test_stride_start_max_frames(tmp_path):
    path = _simple_bag(tmp_path, n=8, storage="db3")
    with open_dataset(path, DataInputConfig(start=1, stride=3, max_frames=2)) as loader:
        frames = list(loader)
    assert [f.timestamp_ns for f in frames] == [T0 + PERIOD, T0 + 4 * PERIOD]
