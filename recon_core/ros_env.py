"""Make the project venv's ROS 2 wheels usable with nothing sourced, without touching a stock install.

The PyPI ROS 2 wheels resolve packages through the ament index, which needs AMENT_PREFIX_PATH.
Inside the project venv it points at the venv prefix (where the interfaces are built). Where a
ROS 2 installation is sourced, the variable is already set and is left alone. DDS discovery
settings (ROS_AUTOMATIC_DISCOVERY_RANGE, ROS_DOMAIN_ID) are never touched here: on a robot,
discovery must reach the network.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path


def ensure_ros_environment() -> None:
    if os.environ.get("AMENT_PREFIX_PATH"):
        return
    prefix = Path(sys.prefix)
    if (prefix / "share" / "ament_index").is_dir():
        os.environ["AMENT_PREFIX_PATH"] = str(prefix)
