"""Two real rclpy nodes in separate processes exchange a custom service call and a TFMessage."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from testsupport.ros import domain_id

from panoptic_mapping.dataio.transforms import make_transform

PEERS = Path(__file__).parent / "peers"
pytestmark = pytest.mark.ros


def _env(domain: int) -> dict[str, str]:
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["ROS_DOMAIN_ID"] = str(domain)
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).resolve().parents[2]), env.get("PYTHONPATH", "")])
    return env


def test_service_call_and_tf_across_processes():
    env = _env(domain_id("dds_exchange"))
    server = subprocess.Popen([sys.executable, str(PEERS / "segmentation_peer.py")], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        client = subprocess.run([sys.executable, str(PEERS / "client_peer.py")], env=env,
                                capture_output=True, text=True, timeout=90)
    finally:
        server.terminate()
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            server.kill()
    assert client.returncode == 0, client.stderr
    result = json.loads(client.stdout.strip().splitlines()[-1])
    assert result["success"], result
    assert result["message"] == "threshold peer"
    # 64x48 image, columns 40..63 bright: 24*48 pixels of segment 2, the rest segment 1.
    assert result["label_counts"] == {"1": 40 * 48, "2": 24 * 48}
    seg = {s["id"]: s for s in result["segments"]}
    assert seg[2]["class_name"] == "table" and seg[2]["is_thing"]
    assert seg[2]["box"] == [40, 0, 24, 48]
    assert seg[1]["box"] == [0, 0, 40, 48]
    assert result["tf"]["parent"] == "map" and result["tf"]["child"] == "camera_link"
    expected = make_transform([1.0, 2.0, 3.0], [0.0, 0.0, np.sin(0.25), np.cos(0.25)])
    np.testing.assert_allclose(np.array(result["tf"]["matrix"]), expected, atol=1e-12)
