"""The one description of the ROS graph (recon_core.ros_graph): the launch files' arguments give the node set
the runner starts (so the runner's end-to-end test covers the launch files), and every parameter it sets
is one the node declares (a misspelt name would otherwise be silently ignored by the node)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from recon_core.config import iter_settings
from recon_core.ros_graph import BAG_ARGUMENTS, LIVE_ARGUMENTS, GraphOptions, graph_nodes, options_from_strings


def _runner_options(argv: list[str]) -> GraphOptions:
    from scene_recon.cli import build_parser
    from scene_recon.commands.ros_run_cmd import graph_options

    return graph_options(build_parser().parse_args(argv))


def _launch_options(arguments, **given: str) -> GraphOptions:
    values = {name: default for name, default, _ in arguments if default is not None}
    values.update(given)
    return options_from_strings(values)


def _declared(node: str) -> set[str]:
    """Every parameter name the node declares (its config dataclasses; `config_file`, `use_sim_time`)."""
    from cad_replacement.replace_config import CadReplacementConfig
    from panoptic_mapping.config import MapperConfig
    from panoptic_mapping.segmentation import SegmentationConfig
    from ros_nodes.cad_replacer_node import CadReplacerNodeConfig
    from ros_nodes.contact_graph_node import ContactGraphNodeConfig
    from ros_nodes.mapper_node import MapperNodeConfig
    from ros_nodes.rgbd_player import RGBDPlayerConfig
    from ros_nodes.segmentation_service import SegmentationServiceConfig
    from scene_graph.config import SceneGraphConfig

    configs = {"segmentation_service": [("", SegmentationConfig), ("", SegmentationServiceConfig)],
               "panoptic_mapper": [("", MapperConfig), ("", MapperNodeConfig)],
               "contact_graph": [("", SceneGraphConfig), ("", ContactGraphNodeConfig)],
               "cad_replacer": [("", CadReplacerNodeConfig), ("replace.", CadReplacementConfig)],
               "rgbd_player": [("", RGBDPlayerConfig)]}[node]
    names = {"use_sim_time"} | ({"config_file"} if node not in ("cad_replacer", "rgbd_player") else set())
    return names | {prefix + s.key for prefix, cls in configs for s in iter_settings(cls())}


def test_bag_launch_arguments_give_the_runners_nodes(tmp_path):
    bag = tmp_path / "rec"
    bag.mkdir()
    out = tmp_path / "out"
    runner = graph_nodes(_runner_options(["ros-run", "--bag", str(bag), "--out", str(out)]))
    launch = graph_nodes(_launch_options(BAG_ARGUMENTS, bag=str(bag), out=str(out)))
    assert [vars(s) for s in runner] == [vars(s) for s in launch]
    assert [s.name for s in runner] == ["segmentation_service", "panoptic_mapper", "contact_graph", "cad_replacer",
                                        "rgbd_player"]
    player = runner[-1].parameters
    assert player["publish_clock"] and all(s.parameters["use_sim_time"] for s in runner[:-1])
    assert not player.get("use_sim_time", False)  # the player is the clock
    assert runner[1].parameters["in_order"]  # a recording integrates in recorded order (= scene-recon run)


def test_live_launch_arguments_give_the_runners_nodes(tmp_path):
    out = str(tmp_path / "out")
    argv = ["ros-run", "--live", "--out", out, "--color-topic", "/cam/rgb", "--depth-topic", "/cam/depth",
            "--camera-info-topic", "/cam/info", "--map-frame", "odom", "--segmenter", "onnx", "--model", "m.onnx"]
    runner = graph_nodes(_runner_options(argv))
    launch = graph_nodes(_launch_options(LIVE_ARGUMENTS, out=out, color_topic="/cam/rgb", depth_topic="/cam/depth",
                                         camera_info_topic="/cam/info", map_frame="odom", backend="onnx",
                                         model="m.onnx"))
    assert [vars(s) for s in runner] == [vars(s) for s in launch]
    assert [s.name for s in runner] == ["segmentation_service", "panoptic_mapper", "contact_graph", "cad_replacer"]
    mapper = runner[1].parameters
    assert (mapper["color_topic"], mapper["depth_topic"], mapper["camera_info_topic"], mapper["map_frame"]) == (
        "/cam/rgb", "/cam/depth", "/cam/info", "odom")
    assert not mapper["use_sim_time"] and not mapper["in_order"]
    assert runner[0].parameters["backend"] == "onnx" and runner[0].parameters["onnx.model"] == "m.onnx"


def test_auto_backend_finds_the_ground_truth_beside_a_bag(tmp_path):
    bag = tmp_path / "rec"
    bag.mkdir()
    assert GraphOptions(bag=str(bag)).resolved_backend() == "none"
    (tmp_path / "rec_groundtruth").mkdir()
    (tmp_path / "rec_groundtruth" / "scene.json").write_text("{}")
    nodes = graph_nodes(GraphOptions(bag=str(bag)))
    assert nodes[0].parameters["backend"] == "oracle"
    assert nodes[0].parameters["oracle.ground_truth"] == str(tmp_path / "rec_groundtruth")
    assert nodes[-1].parameters["wait_for_label_subscribers"] == 1


@pytest.mark.parametrize("bag", [True, False])
def test_every_parameter_is_declared_by_its_node(bag, tmp_path):
    opts = GraphOptions(bag=str(tmp_path) if bag else "", config_dir=str(tmp_path), backend="oracle")
    for spec in graph_nodes(opts):
        unknown = set(spec.parameters) - _declared(spec.name)
        assert not unknown, (spec.name, unknown)


def test_parameter_file_and_command_line(tmp_path):
    spec = graph_nodes(GraphOptions(bag="/data/rec: 1", out=str(tmp_path)))[-1]
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump(spec.params_yaml()))
    assert yaml.safe_load(path.read_text())["rgbd_player"]["ros__parameters"]["source"] == "/data/rec: 1"
    args = spec.ros_args(path)
    assert args[:3] == ["--ros-args", "-r", "__node:=rgbd_player"] and args[-2:] == ["--params-file", str(path)]
    inline = spec.ros_args()
    assert "source:='/data/rec: 1'" in inline and "loop:=false" in inline


def test_launch_argument_strings():
    opts = options_from_strings({"rate": "2", "loop": "true", "use_sim_time": "auto", "seeds_per_class": "4"})
    assert (opts.rate, opts.loop, opts.use_sim_time, opts.seeds_per_class) == (2.0, True, None, 4)
    with pytest.raises(KeyError, match="unknown launch argument"):
        options_from_strings({"bagg": "x"})
    with pytest.raises(ValueError, match="not a boolean"):
        options_from_strings({"loop": "maybe"})


def test_the_launch_files_use_the_shared_description():
    """The launch files (launch_ros is not installable here) hold no node list or parameter of their own."""
    root = Path(__file__).resolve().parents[2] / "launch"
    for name, arguments in (("bag.launch.py", "BAG_ARGUMENTS"), ("reconstruct.launch.py", "LIVE_ARGUMENTS")):
        text = (root / name).read_text()
        assert f"from recon_core.ros_graph import {arguments}, PACKAGE, graph_nodes, options_from_strings" in text
        assert "graph_nodes(opts)" in text and "parameters=[spec.parameters]" in text
        compile(text, name, "exec")


@pytest.mark.parametrize("name", ["fast", "balanced", "accurate"])
def test_a_preset_sets_the_nodes_parameters_as_the_cli_preset(name, tmp_path):
    """`ros-run --preset NAME` and the launch files' `preset:=NAME` give the same nodes, whose parameters
    hold the preset's overrides under the nodes' names: the configs the nodes build equal the CLI's."""
    from cad_replacement.replace_config import CadReplacementConfig
    from panoptic_mapping.config import MapperConfig
    from recon_core.config import CONFIG_DIR, build_config, load_config, load_preset, preset_overrides
    from scene_graph.config import load_scene_graph_config

    bag = tmp_path / "rec"
    bag.mkdir()
    out = str(tmp_path / "out")
    runner = graph_nodes(_runner_options(["ros-run", "--bag", str(bag), "--out", out, "--preset", name]))
    launch = graph_nodes(_launch_options(BAG_ARGUMENTS, bag=str(bag), out=out, preset=name))
    assert [vars(s) for s in runner] == [vars(s) for s in launch]
    nodes = {s.name: s.parameters for s in runner}
    for node, params in nodes.items():
        assert not set(params) - _declared(node), node
    preset = load_preset(name)

    def own(node: str, cls, prefix: str = "") -> dict:
        keys = {s.key for s in iter_settings(cls())}
        return {k[len(prefix):]: v for k, v in nodes[node].items() if k.startswith(prefix) and k[len(prefix):] in keys}

    mapper_cli = load_config(MapperConfig, CONFIG_DIR / "mapper.yaml", preset_overrides(preset, "mapper"))
    assert load_config(MapperConfig, CONFIG_DIR / "mapper.yaml", own("panoptic_mapper", MapperConfig)) == mapper_cli
    graph_cli = load_scene_graph_config(None, preset_overrides(preset, "scene_graph"))
    assert load_scene_graph_config(None, own("contact_graph", type(graph_cli))) == graph_cli
    cad_cli = build_config(CadReplacementConfig, {}, preset_overrides(preset, "cad", {"method": "ours"}))
    assert build_config(CadReplacementConfig, {}, own("cad_replacer", CadReplacementConfig, "replace.")) == cad_cli
    assert nodes["rgbd_player"].get("stride", 1) == preset.section("data").get("stride", 1)
    assert nodes["cad_replacer"]["replace.method"] == "ours"  # the explicit options win over a preset


def test_preset_values_and_errors(tmp_path):
    from recon_core.errors import ConfigError
    from recon_core.ros_graph import preset_parameters

    fast = {s.name: s.parameters for s in graph_nodes(GraphOptions(bag=str(tmp_path), preset="fast"))}
    assert fast["panoptic_mapper"]["keyframes.label_every_n_frames"] == 0 and fast["panoptic_mapper"]["downsample"] == 2
    assert fast["contact_graph"]["planes.ransac_iterations"] == 100 and fast["cad_replacer"]["replace.top_k"] == 6
    assert fast["rgbd_player"]["stride"] == 2
    live = {s.name: s.parameters for s in graph_nodes(GraphOptions(preset="fast"))}
    assert "rgbd_player" not in live and live["panoptic_mapper"]["downsample"] == 2  # a live camera is not thinned
    plain = {s.name: s.parameters for s in graph_nodes(GraphOptions(bag=str(tmp_path)))}
    assert "stride" not in plain["rgbd_player"] and "downsample" not in plain["panoptic_mapper"]
    with pytest.raises(ConfigError, match="unknown preset"):
        graph_nodes(GraphOptions(preset="fastest"))
    odd = tmp_path / "odd.yaml"
    odd.write_text("data:\n  max_frames: 10\n")
    from recon_core.config import load_preset

    with pytest.raises(ConfigError, match="no node parameter"):
        preset_parameters(load_preset(odd), bag=True)
