"""Fast DDS writer timing for the nodes: a sample a reliable reader lost is resent within 0.1 s, not 3 s.

A reliable DDS writer resends what a reader missed only after the reader has answered one of the
writer's heartbeats, and Fast DDS sends those every 3 s by default; the reader delivers in order, so
one lost sample holds every later one until then. Beside 640x480 image pairs at 30 Hz, one lost /tf
sample of the player held every pose for 3 s while the mapper's queue filled with ~100 frames it could
not pose (30 Hz bag, bench-kitchen, 2 cores: 3.5-4.0 s from the first frame queued to the first one
integrated in 6 of 7 runs, 1.0-1.5 s, the gravity window alone, with the profile; docs/ROS.md). The same
holds for the 2 MB segmentation requests and their label answers.

`config/fastdds_writers.xml` sets the default writer profile's heartbeat to 0.1 s, nothing else: no
transport, discovery or QoS setting (ROS QoS still overrides XML QoS). It is applied to each node's own
process (`ros_nodes.runner.init_ros`, before rclpy starts Fast DDS) only where the environment names no
Fast DDS profile file, the middleware is Fast DDS and QoS are not taken from XML
(`RMW_FASTRTPS_USE_QOS_FROM_XML`: a profile without QoS would then reset the nodes' own); the caller's
environment is not changed.
`SCENE_RECON_DDS_PROFILE` names another file, or `none` leaves Fast DDS's defaults. A recording played
by another tool (`ros2 bag play`) gets the same with `FASTDDS_DEFAULT_PROFILES_FILE` set to this file.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping
from dataclasses import dataclass
from pathlib import Path

from recon_core.config import CONFIG_DIR

#: Names another profile file for the nodes, or `none` / `off` / empty for Fast DDS's defaults.
PROFILE_ENV = "SCENE_RECON_DDS_PROFILE"
#: Fast DDS's own variables naming a profile file (the second is the name before Fast DDS 3).
FASTDDS_PROFILE_ENVS = ("FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE")
#: The project's profile (installed with the default configuration).
DEFAULT_PROFILE = CONFIG_DIR / "fastdds_writers.xml"
#: rmw_fastrtps's switch that takes QoS from XML profiles instead of the code (the project's profile has none).
QOS_FROM_XML_ENV = "RMW_FASTRTPS_USE_QOS_FROM_XML"
#: The middleware the ROS 2 wheels and distributions use when RMW_IMPLEMENTATION is unset.
DEFAULT_RMW = "rmw_fastrtps_cpp"


@dataclass(frozen=True)
class ProfileChoice:
    """What `choose_profile` decided: the file to hand Fast DDS (None: nothing set) and why."""

    path: Path | None
    note: str
    problem: bool = False  # the user asked for something that cannot be applied


def choose_profile(environ: MutableMapping[str, str]) -> ProfileChoice:
    """The profile file for a node started with `environ`; see the module docstring for the rules."""
    for name in FASTDDS_PROFILE_ENVS:
        if name in environ:
            return ProfileChoice(None, f"Fast DDS profile from {name}={environ[name]!r} (the project's not applied)")
    rmw = environ.get("RMW_IMPLEMENTATION", "") or DEFAULT_RMW
    if not rmw.startswith("rmw_fastrtps"):
        return ProfileChoice(None, f"middleware {rmw}: no Fast DDS profile applied")
    if environ.get(QOS_FROM_XML_ENV, "").strip() not in ("", "0"):
        # rmw_fastrtps then takes every QoS from XML profiles instead of the node's: ours names none, and would
        # turn the nodes' reliable, transient-local outputs into Fast DDS's default QoS
        return ProfileChoice(None, f"{QOS_FROM_XML_ENV}={environ[QOS_FROM_XML_ENV]!r}: QoS come from the user's XML "
                             "profiles; the project's is not applied")
    choice = environ.get(PROFILE_ENV)
    if choice is not None and choice.strip().lower() in ("", "none", "off"):
        return ProfileChoice(None, f"{PROFILE_ENV}={choice!r}: Fast DDS's default writer timing")
    path = Path(choice) if choice else DEFAULT_PROFILE
    if not path.is_file():
        source = f"{PROFILE_ENV}={choice!r}" if choice else "the installed default configuration"
        return ProfileChoice(None, f"Fast DDS profile {path} not found ({source}): Fast DDS's default writer "
                             "timing (a lost reliable sample waits up to 3 s)", problem=True)
    return ProfileChoice(path, f"Fast DDS writer profile {path} (set {PROFILE_ENV}=none for Fast DDS's defaults)")


def apply_dds_profile(environ: MutableMapping[str, str] | None = None) -> ProfileChoice:
    """Name the chosen profile file to Fast DDS in `environ` (default: this process's environment, read by
    Fast DDS when rclpy starts it); call before `rclpy.init`."""
    env = os.environ if environ is None else environ
    choice = choose_profile(env)
    if choice.path is not None:
        env["FASTDDS_DEFAULT_PROFILES_FILE"] = str(choice.path)
    return choice


__all__ = ["DEFAULT_PROFILE", "PROFILE_ENV", "ProfileChoice", "apply_dds_profile", "choose_profile"]
