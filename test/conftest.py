"""Test-wide settings: DDS stays on loopback, on a domain of the test run's own."""

from __future__ import annotations

import os
import sys
from pathlib import Path

# Set before any rclpy import: these machines allow loopback traffic only.
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
# A caller's ROS_DOMAIN_ID is honoured by every ROS test (testsupport.ros.domain_id); without one, each
# test picks its own. Remember which it was before giving the variable a default.
os.environ.setdefault("SCENE_RECON_TEST_CALLER_DOMAIN", os.environ.get("ROS_DOMAIN_ID", ""))
os.environ.setdefault("ROS_DOMAIN_ID", "17")
if not os.environ.get("AMENT_PREFIX_PATH") and (Path(sys.prefix) / "share" / "ament_index").is_dir():
    os.environ["AMENT_PREFIX_PATH"] = sys.prefix

REPO_ROOT = Path(__file__).resolve().parent.parent

# Shared test helpers (test/support/testsupport) import as `testsupport.*` under --import-mode=importlib.
# Only test/support goes on sys.path: test/ itself would shadow the real packages with its mirrors.
sys.path.insert(0, str(Path(__file__).resolve().parent / "support"))
