"""ROS parameters declared from the config schema, on real rclpy nodes created in this process."""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import pytest
from testsupport.ros import domain_id

from recon_core.config import ConfigError, Settings, flatten, load_config, setting, to_dict

pytestmark = pytest.mark.ros


@dataclass
class _Section(Settings):
    share: float = setting(0.5, min=0.0, max=1.0)
    offsets: list[int] = setting([1, 2], min=1)
    scales: list[float] = field(default_factory=list)


@dataclass
class _Schema(Settings):
    mode: str = setting("full", choices=("full", "baseline"))
    count: int = setting(3, min=1)
    enabled: bool = True
    names: list[str] = field(default_factory=lambda: ["a"])
    section: _Section = field(default_factory=_Section)
    levels: dict[str, _Section] = field(default_factory=lambda: {"low": _Section(share=0.1)})

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.levels["low"].share > self.section.share:
            raise ConfigError("levels.low.share must not exceed section.share")


@pytest.fixture
def ros_context():
    import rclpy

    os.environ["ROS_DOMAIN_ID"] = str(domain_id("spare1"))
    context = rclpy.Context()
    rclpy.init(context=context)
    yield context
    rclpy.shutdown(context=context)


def _node(context, *overrides):
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    return Node("schema_test", context=context, parameter_overrides=[Parameter(n, value=v) for n, v in overrides])


def _declared(node, prefix: str = "") -> dict[str, object]:
    """Parameters the helper declared (rclpy adds a few of its own)."""
    names = [n for n in node.list_parameters([], 0).names if n.startswith(prefix)]
    return {n: node.get_parameter(n) for n in names if n not in ("use_sim_time", "start_type_description_service")}


def test_declares_exactly_the_flattened_schema_keys_with_their_types(ros_context, tmp_path):
    from rclpy.parameter import Parameter

    from ros_nodes.parameters import declare_config

    path = tmp_path / "schema.yaml"
    path.write_text("count: 5\nsection: {share: 0.75}\nlevels:\n  low: {share: 0.2}\n  high: {share: 0.9}\n")
    node = _node(ros_context)
    try:
        cfg = declare_config(node, _Schema, path, prefix="stage.")
        params = _declared(node)
        keys = {f"stage.{k}" for k in flatten(to_dict(load_config(_Schema, path)))}
        assert set(params) == keys  # the file's second level ("high") is a schema key too
        expected = {
            "stage.mode": Parameter.Type.STRING, "stage.count": Parameter.Type.INTEGER,
            "stage.enabled": Parameter.Type.BOOL, "stage.names": Parameter.Type.STRING_ARRAY,
            "stage.section.share": Parameter.Type.DOUBLE, "stage.section.offsets": Parameter.Type.INTEGER_ARRAY,
            "stage.section.scales": Parameter.Type.DOUBLE_ARRAY,  # empty, still typed by the annotation
            "stage.levels.high.share": Parameter.Type.DOUBLE,
        }
        for name, ptype in expected.items():
            assert params[name].type_ == ptype, name
        assert params["stage.count"].value == 5 == cfg.count  # defaults come from the file
        assert params["stage.levels.high.share"].value == 0.9 == cfg.levels["high"].share
        assert node.describe_parameter("stage.section.share").additional_constraints == "in [0, 1]"
    finally:
        node.destroy_node()


def test_overrides_are_converted_and_checked_like_the_file(ros_context, capfd):
    from rclpy.parameter import Parameter

    from ros_nodes.parameters import declare_config

    node = _node(ros_context, ("section.share", 1), ("count", 7), ("section.scales", [1, 2]),
                 ("mode", "fast"), ("enabled", 1), ("section.offsets", [0]), ("levels.low.share", 0.9))
    try:
        cfg = declare_config(node, _Schema)
        # an int for a float is accepted, and the parameter then shows a double
        assert cfg.section.share == 1.0 and isinstance(cfg.section.share, float)
        assert node.get_parameter("section.share").type_ == Parameter.Type.DOUBLE
        assert cfg.section.scales == [1.0, 2.0]
        assert node.get_parameter("section.scales").type_ == Parameter.Type.DOUBLE_ARRAY
        assert cfg.count == 7
        # invalid ones keep the default, and the parameter shows the value in effect
        assert (cfg.mode, cfg.enabled, cfg.section.offsets) == ("full", True, [1, 2])
        assert node.get_parameter("mode").value == "full"
        assert node.get_parameter("enabled").type_ == Parameter.Type.BOOL
        # a cross-field condition sees the overrides accepted before it (share 1.0 here: 0.9 is fine)
        assert cfg.levels["low"].share == 0.9
    finally:
        node.destroy_node()
    err = capfd.readouterr().err
    assert "parameter 'mode': got 'fast'; valid values: ['full', 'baseline']; keeping 'full'" in err
    assert "parameter 'enabled': expected true/false, got 1" in err
    assert "parameter 'section.offsets': section.offsets[0]: got 0; allowed: >= 1" in err


def test_cross_field_violations_and_late_changes_are_refused(ros_context, capfd):
    from rclpy.parameter import Parameter

    from ros_nodes.parameters import declare_config

    node = _node(ros_context, ("levels.low.share", 0.9))  # above section.share (0.5)
    try:
        cfg = declare_config(node, _Schema)
        assert cfg.levels["low"].share == pytest.approx(0.1)
        result = node.set_parameters([Parameter("count", value=9)])[0]
        assert not result.successful and "start-up" in result.reason
        assert node.get_parameter("count").value == 3
    finally:
        node.destroy_node()
    assert "parameter 'levels.low.share': levels.low.share must not exceed section.share" in capfd.readouterr().err


def test_a_broken_file_falls_back_to_the_defaults(ros_context, tmp_path, capfd):
    from ros_nodes.parameters import declare_config

    path = tmp_path / "bad.yaml"
    path.write_text("count: 0\n")
    node = _node(ros_context)
    try:
        assert declare_config(node, _Schema, path).count == 3
    finally:
        node.destroy_node()
    assert "count: got 0; allowed: >= 1; using the built-in defaults of _Schema" in capfd.readouterr().err


def _node_schema(stage_cls, stage_yaml, node_cls) -> set[str]:
    keys = set(flatten(to_dict(node_cls())))
    if stage_cls is not None:
        keys |= {"config_file", *flatten(to_dict(load_config(stage_cls, stage_yaml)))}
    return keys


@pytest.mark.parametrize("which", ["mapper", "contact_graph", "segmentation", "player"])
def test_every_node_declares_its_schema(which):
    """The four nodes, built as their executables build them (global --ros-args), int for a float included."""
    import rclpy
    from rclpy.parameter import Parameter

    from recon_core.config import CONFIG_DIR

    os.environ["ROS_DOMAIN_ID"] = str(domain_id("spare2"))
    args = {
        "mapper": ["-p", "tsdf.voxel_size_m:=1", "-p", "publish_period_s:=3", "-p", "downsample:=0"],
        "contact_graph": ["-p", "support.a_th:=-1", "-p", "min_period_s:=2"],
        "segmentation": ["-p", "oracle.levels.hard.flicker:=1", "-p", "label_wait_s:=1"],
        "player": ["-p", "rate:=2", "-p", "wait_timeout_s:=-1"],
    }[which]
    rclpy.init(args=["--ros-args", *args])
    try:
        if which == "mapper":
            from panoptic_mapping.config import MapperConfig
            from ros_nodes.mapper_node import MapperNode, MapperNodeConfig

            node = MapperNode()
            schema = _node_schema(MapperConfig, CONFIG_DIR / "mapper.yaml", MapperNodeConfig)
            assert (node.config.tsdf.voxel_size_m, node.publish_period_s, node.config.downsample) == (1.0, 3.0, 1)
            floats = ["tsdf.voxel_size_m", "publish_period_s"]
        elif which == "contact_graph":
            from ros_nodes.contact_graph_node import ContactGraphNode, ContactGraphNodeConfig
            from scene_graph.config import SceneGraphConfig

            node = ContactGraphNode()
            schema = _node_schema(SceneGraphConfig, CONFIG_DIR / "scene_graph.yaml", ContactGraphNodeConfig)
            assert (node.builder.cfg.support.a_th, node.min_period_s) == (-1.0, 2.0)
            floats = ["support.a_th", "min_period_s"]
        elif which == "segmentation":
            from panoptic_mapping.segmentation import SegmentationConfig
            from ros_nodes.segmentation_service import SegmentationService, SegmentationServiceConfig

            node = SegmentationService()
            schema = _node_schema(SegmentationConfig, CONFIG_DIR / "segmentation.yaml", SegmentationServiceConfig)
            assert (node.config.oracle.levels["hard"].flicker, node.label_wait_s) == (1.0, 1.0)
            floats = ["oracle.levels.hard.flicker", "label_wait_s"]
        else:
            from ros_nodes.rgbd_player import RGBDPlayer, RGBDPlayerConfig

            node = RGBDPlayer()
            schema = _node_schema(None, None, RGBDPlayerConfig)
            assert (node.rate, node.wait_timeout_s) == (2.0, 30.0)
            floats = ["rate", "wait_timeout_s"]
        try:
            assert set(_declared(node)) == schema
            for name in floats:
                assert node.get_parameter(name).type_ == Parameter.Type.DOUBLE, name
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown()


@dataclass
class _Optional(Settings):
    distance: float | None = None
    count: int = setting(3, min=1)
    section: _Section = field(default_factory=_Section)


def test_an_optional_setting_is_a_parameter_without_a_warning(ros_context, capfd):
    """`float | None` (the CAD replacer's replace.plane_distance) is a double parameter, not set while
    None: no start-up warning for a correct configuration (issue 24, item 5)."""
    from rclpy.parameter import Parameter

    from ros_nodes.parameters import declare_config

    node = _node(ros_context)
    try:
        cfg = declare_config(node, _Optional, prefix="replace.")
        assert cfg.distance is None and node.get_parameter("replace.distance").type_ == Parameter.Type.NOT_SET
    finally:
        node.destroy_node()
    node = _node(ros_context, ("replace.distance", 0.02))
    try:
        cfg = declare_config(node, _Optional, prefix="replace.")
        assert cfg.distance == 0.02 and node.get_parameter("replace.distance").type_ == Parameter.Type.DOUBLE
    finally:
        node.destroy_node()
    assert "cannot be a ROS parameter" not in capfd.readouterr().err


def test_an_unknown_parameter_is_warned_about_with_the_nearest_name(ros_context, capfd):
    from ros_nodes.parameters import declare_config, warn_unknown_parameters

    node = _node(ros_context, ("cuont", 4), ("section.shar", 0.3), ("share", 0.3), ("zzqqxx", 1), ("count", 5),
                 ("use_sim_time", True))
    try:
        declare_config(node, _Schema)
        unknown = warn_unknown_parameters(node)
    finally:
        node.destroy_node()
    assert unknown == {"cuont": "count", "section.shar": "section.share", "share": "section.share", "zzqqxx": ""}
    err = capfd.readouterr().err
    assert "unknown parameter 'cuont' is ignored; did you mean 'count'?" in err
    assert "unknown parameter 'zzqqxx' is ignored; `ros2 param list` shows the valid names" in err


@pytest.mark.parametrize("which", ["mapper", "cad_replacer"])
def test_nodes_start_and_stop_with_clean_logs(which, tmp_path):
    """A node started with a correct configuration (and one misspelled parameter) logs no warning but the
    one naming the nearest valid parameter; SIGINT stops it with exit 0 and no exception text (rclpy's
    `The following exception was never retrieved: cannot use Destroyable ...`)."""
    import signal
    import subprocess
    import sys
    import time

    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain_id("spare1")))
    module, extra = {"mapper": ("ros_nodes.mapper_node", ["-p", f"data_root:={tmp_path}", "-p", "voxel_size:=2",
                                                          "-p", "status_period_s:=0.2"]),
                     "cad_replacer": ("ros_nodes.cad_replacer_node", ["-p", f"output_dir:={tmp_path}",
                                                                      "-p", "replace.plane_distanse:=0.01"])}[which]
    proc = subprocess.Popen([sys.executable, "-m", module, "--ros-args", *extra], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    time.sleep(8.0)  # up, timers and services running on their executor threads
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0, out[-3000:]
    assert "never retrieved" not in out and "Traceback" not in out and "Destroyable" not in out, out[-3000:]
    warnings = [line for line in out.splitlines() if "[WARN]" in line or "[ERROR]" in line]
    near = {"mapper": "'voxel_size' is ignored; did you mean 'tsdf.voxel_size_m'?",
            "cad_replacer": "'replace.plane_distanse' is ignored; did you mean 'replace.plane_distance'?"}[which]
    assert len(warnings) == 1 and near in warnings[0], warnings
