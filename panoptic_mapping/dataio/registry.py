"""Pick a loader by looking at a path (like kiss-icp's dataloaders), and describe what it holds."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from panoptic_mapping.dataio.bag import RosbagLoader, is_bag
from panoptic_mapping.dataio.config import DataInputConfig
from panoptic_mapping.dataio.folders import (
    ScanNetLoader,
    SevenScenesLoader,
    TumLoader,
    is_scannet,
    is_seven_scenes,
    is_tum,
)
from recon_core.frame import DatasetError

#: (name, detector, loader class), tried in order.
LOADERS: list[tuple[str, Callable[[Path], bool], type]] = [
    ("rosbag2", is_bag, RosbagLoader),
    ("tum", is_tum, TumLoader),
    ("7scenes", is_seven_scenes, SevenScenesLoader),
    ("scannet", is_scannet, ScanNetLoader),
]


def detect_format(path: str | Path) -> str:
    """Name of the loader for `path`; raises DatasetError saying what was expected."""
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path} does not exist")
    for name, detect, _ in LOADERS:
        if detect(path):
            return name
    raise DatasetError(
        f"{path} is not a recognised RGB-D source. Expected a ROS 2 bag (.mcap/.db3 file or a folder with "
        "metadata.yaml or .mcap/.db3 files), a TUM folder (rgb.txt + depth.txt), a 7-Scenes / 3DMatch folder "
        "(frame-XXXXXX.color.png, also in rgbd-frames/ or seq-XX/) or a ScanNet export (color/, depth/, pose/, "
        "intrinsic/)"
    )


def open_dataset(path: str | Path, config: DataInputConfig | None = None) -> Any:
    """Open `path` with the matching loader; the result iterates `RGBDFrame`s and has `.skips`."""
    name = detect_format(path)
    loader_cls = next(cls for n, _, cls in LOADERS if n == name)
    return loader_cls(Path(path), config or DataInputConfig())
