"""The mapper node fed by a real bag over DDS (player -> mapper <-> segmentation service) produces entities."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest
import yaml
from testsupport.ros import domain_id, play_recording

from scene_recon.synthetic.generate import GenerateConfig, generate_recording
from scene_recon.synthetic.scene import GroundTruthScene

pytestmark = pytest.mark.ros


def _small_recording(path):
    cfg = GenerateConfig(objects=6, frames=30, seed=3)
    cam = cfg.sensor.camera
    cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy = 320, 240, 262.5, 262.5, 159.5, 119.5
    return generate_recording(path, cfg, progress=False)


def test_mapper_node_maps_a_bag_with_the_segmentation_service(tmp_path):
    import rclpy
    from scene_recon_interfaces.srv import ExtractEntities, SaveMap, SegmentImage

    from ros_nodes.entity_conversions import msg_to_entity

    summary = _small_recording(tmp_path / "rec")
    gt = GroundTruthScene.load(summary["ground_truth"])
    mapper_cfg = tmp_path / "mapper.yaml"
    mapper_cfg.write_text(yaml.safe_dump({"downsample": 1, "keyframes": {"min_translation_m": 0.1}}))
    domain = str(domain_id("mapper"))
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=domain)
    os.environ["ROS_DOMAIN_ID"] = domain
    py = sys.executable
    procs = [
        subprocess.Popen([py, "-m", "ros_nodes.segmentation_service", "--ros-args", "-p", "backend:=oracle",
                          "-p", f"oracle.ground_truth:={summary['ground_truth']}", "-p", "oracle.level:=clean"],
                         env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True),
        subprocess.Popen([py, "-m", "ros_nodes.mapper_node", "--ros-args", "-p", f"config_file:={mapper_cfg}",
                          "-p", "publish_period_s:=1.0", "-p", f"data_root:={tmp_path}",
                          "-p", "gravity_window_frames:=4", "-p", "gravity_stride:=2"],
                         env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True),
    ]
    rclpy.init()
    node = rclpy.create_node("mapper_checker")
    try:
        extract = node.create_client(ExtractEntities, "extract_entities")
        save = node.create_client(SaveMap, "save_map")
        seg_ready = node.create_client(SegmentImage, "segment_image")
        assert extract.wait_for_service(timeout_sec=60) and seg_ready.wait_for_service(timeout_sec=60)
        player = play_recording(py, summary["bag"], env, "wait_for_label_subscribers:=1",
                                "labels_topic_in:=/ground_truth/panoptic_labels")
        assert player.returncode == 0, player.stdout + player.stderr
        time.sleep(3.0)  # let the mapper drain its queue
        future = extract.call_async(ExtractEntities.Request(include_meshes=True))
        rclpy.spin_until_future_complete(node, future, timeout_sec=120)
        res = future.result()
        saved = None
        if res is not None:
            fut = save.call_async(SaveMap.Request(path=str(tmp_path / "saved")))
            rclpy.spin_until_future_complete(node, fut, timeout_sec=60)
            saved = fut.result()
    finally:
        node.destroy_node()
        rclpy.shutdown()
        for p in procs:
            p.terminate()
        logs = [p.communicate(timeout=20)[0] for p in procs]
    assert res is not None and res.success, ("extract_entities did not answer", [log[-3000:] for log in logs])
    assert saved is not None and saved.success and (tmp_path / "saved" / "map.npz").is_file()
    # the gravity check of the first frames: the generated world is z up, the TF map frame trusted
    import json

    gravity = json.loads((tmp_path / "saved" / "map.json").read_text())["gravity"]
    assert gravity["mode"] == "tf" and not gravity["applied"] and gravity["estimate"]["ok"], gravity
    assert gravity["estimate"]["angle_from_z_deg"] < 2.0 and "+z is up" in gravity["note"]
    ents = [msg_to_entity(m) for m in res.entities.entities]
    seen_classes = {e.class_name for e in gt.entities if e.visible_pixels > 2000}
    mapped = {e.class_name for e in ents if e.class_id >= 0}  # (entity 0 = unclaimed surface, class -1)
    assert "floor" in mapped, logs[1][-3000:]
    assert len(mapped & seen_classes) >= 3, (mapped, seen_classes, logs[1][-2000:])
    assert all(len(e.vertices) > 0 and len(e.faces) > 0 for e in ents)
    assert mapped <= {e.class_name for e in gt.entities}
