"""Configuration of the data input layer (bags and frame folders); mirrors `config/data.yaml`."""

from __future__ import annotations

from dataclasses import dataclass, field

from panoptic_mapping.gravity import GravityConfig
from recon_core.config import Settings


@dataclass
class TopicConfig(Settings):
    """Bag topics. Empty strings are auto-detected from the message types and topic names."""

    color: str = ""
    depth: str = ""
    camera_info: str = ""
    #: Optional ground-truth panoptic label image (32SC1), e.g. from `scene-recon generate`.
    labels: str = ""
    tf: str = "/tf"
    tf_static: str = "/tf_static"


@dataclass
class DataInputConfig(Settings):
    """How frames are read, synchronised and posed."""

    topics: TopicConfig = field(default_factory=TopicConfig)
    #: Fixed frame the camera poses are expressed in (bags); its up is found by `gravity`.
    map_frame: str = "map"
    #: Frame of the camera's optical axis; empty: the color image's header.frame_id.
    camera_frame: str = ""
    #: Approximate time synchronisation: max |t_color - t_depth| for a pair, seconds.
    sync_slop_s: float = 0.02
    #: Max time a pose may be extrapolated past the first/last TF sample, seconds.
    tf_max_extrapolation_s: float = 0.05
    #: Max gap between two TF samples that is still interpolated, seconds.
    tf_max_gap_s: float = 1.0
    #: True: frames without a pose are skipped (and counted); False: yielded with pose None.
    require_pose: bool = True
    #: Read only every `stride`-th synchronised frame, starting at `start`, at most `max_frames` (0: all).
    start: int = 0
    stride: int = 1
    max_frames: int = 0
    #: Override camera intrinsics [fx, fy, cx, cy] (folders without calibration, bags without info).
    intrinsics: list[float] = field(default_factory=list)
    #: Intrinsics from a file instead: 3x3 / 4x4 matrix text (3DMatch, ScanNet) or YAML with fx, fy, cx, cy.
    intrinsics_file: str = ""
    #: Folder datasets: depth PNG units per metre (TUM: 5000, 7-Scenes: 1000); 0 = dataset default.
    depth_scale: float = 0.0
    #: Which way is up in the input's world frame (auto: estimated from depth; z; a 4x4 file):
    #: poses are rotated into a gravity-aligned map frame before mapping (panoptic_mapping/gravity.py).
    gravity: GravityConfig = field(default_factory=GravityConfig)
