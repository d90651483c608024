"""`ros_nodes.dds_profile`: which Fast DDS profile a node's process gets, and that Fast DDS reads it.

The rules are checked on plain dicts (the caller's environment is never touched). The profile shipped
in config/ is then handed to a real Fast DDS participant started the way every node starts
(`ros_nodes.runner.init_ros`) that sends a reliable message to itself: Fast DDS must parse the file
without an error, and a broken file in its place must give Fast DDS's XML parser error, so the check
sees what Fast DDS read."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from testsupport.ros import domain_id

from ros_nodes.dds_profile import DEFAULT_PROFILE, PROFILE_ENV, apply_dds_profile, choose_profile

ROOT = Path(__file__).resolve().parents[2]


def test_default_is_the_shipped_profile():
    env: dict[str, str] = {}
    choice = apply_dds_profile(env)
    assert choice.path == DEFAULT_PROFILE and DEFAULT_PROFILE.is_file() and not choice.problem
    assert env == {"FASTDDS_DEFAULT_PROFILES_FILE": str(DEFAULT_PROFILE)}
    assert apply_dds_profile({"RMW_IMPLEMENTATION": "rmw_fastrtps_dynamic_cpp"}).path == DEFAULT_PROFILE
    assert apply_dds_profile({"RMW_FASTRTPS_USE_QOS_FROM_XML": "0"}).path == DEFAULT_PROFILE


@pytest.mark.parametrize("env", [
    {"FASTDDS_DEFAULT_PROFILES_FILE": "/etc/site.xml"},  # the user's own profile wins
    {"FASTRTPS_DEFAULT_PROFILES_FILE": "/etc/site.xml"},  # (its name before Fast DDS 3)
    {"FASTDDS_DEFAULT_PROFILES_FILE": ""},
    {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"},  # not Fast DDS
    {PROFILE_ENV: "none"},
    {"RMW_FASTRTPS_USE_QOS_FROM_XML": "1"},  # QoS from XML: a profile without QoS would reset the nodes' QoS
    {PROFILE_ENV: ""},
])
def test_left_alone(env):
    before = dict(env)
    choice = apply_dds_profile(env)
    assert choice.path is None and not choice.problem and env == before, choice.note


def test_another_file_and_a_missing_one(tmp_path):
    mine = tmp_path / "mine.xml"
    mine.write_text("<dds/>", encoding="utf-8")
    assert choose_profile({PROFILE_ENV: str(mine)}).path == mine
    missing = choose_profile({PROFILE_ENV: str(tmp_path / "nope.xml")})
    assert missing.path is None and missing.problem and "nope.xml" in missing.note


_NODE = """
import sys, time
from ros_nodes.runner import init_ros
import rclpy
from std_msgs.msg import String
from ros_nodes.qos import SENSOR_RECORDING
init_ros([])
node = rclpy.create_node("dds_profile_check")
got = []
node.create_subscription(String, "dds_profile_check", lambda m: got.append(m.data), SENSOR_RECORDING)
pub = node.create_publisher(String, "dds_profile_check", SENSOR_RECORDING)
end = time.monotonic() + 20
while not got and time.monotonic() < end:
    pub.publish(String(data="hello"))
    rclpy.spin_once(node, timeout_sec=0.1)
import os
print("PROFILE", os.environ.get("FASTDDS_DEFAULT_PROFILES_FILE"), "GOT", got[:1], flush=True)
node.destroy_node()
rclpy.try_shutdown()
"""


def _run_node(extra: dict[str, str]) -> str:
    env = {k: v for k, v in os.environ.items() if k not in ("FASTDDS_DEFAULT_PROFILES_FILE",
                                                             "FASTRTPS_DEFAULT_PROFILES_FILE", PROFILE_ENV)}
    env.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_DOMAIN_ID=str(domain_id("spare1")), **extra)
    run = subprocess.run([sys.executable, "-c", _NODE], env=env, cwd=ROOT, capture_output=True, text=True,
                         timeout=60)
    out = run.stdout + run.stderr
    assert run.returncode == 0, out
    return out


def test_fast_dds_reads_the_shipped_profile_without_error(tmp_path):
    out = _run_node({})
    assert f"PROFILE {DEFAULT_PROFILE} GOT ['hello']" in out, out
    assert "XMLPARSER" not in out and "Error" not in out, out
    # the same check sees a profile Fast DDS cannot parse (so it is Fast DDS reading the file named)
    broken = tmp_path / "broken.xml"
    broken.write_text(DEFAULT_PROFILE.read_text(encoding="utf-8").replace("heartbeat_period", "heartbeat_periodX"),
                      encoding="utf-8")
    out = _run_node({PROFILE_ENV: str(broken)})
    assert "XMLPARSER" in out and "heartbeat_periodX" in out, out
