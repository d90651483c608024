"""RGB-D data input: one frame type, loaders picked by path, bag writing, TF and image codecs."""

from panoptic_mapping.dataio.config import DataInputConfig, TopicConfig
from recon_core.frame import CameraIntrinsics, DatasetError, RGBDFrame, sanitize_depth

__all__ = ["CameraIntrinsics", "DataInputConfig", "DatasetError", "RGBDFrame", "TopicConfig", "sanitize_depth"]
