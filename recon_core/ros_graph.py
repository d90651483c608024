"""The ROS 2 graph of the product as plain data: which nodes run, with which parameters and remappings.

One description serves every way of starting the graph: `scene-recon ros-run` (processes, tested
end to end) and the launch files `launch/reconstruct.launch.py` / `launch/bag.launch.py` (which
only turn each `NodeSpec` into a `launch_ros.actions.Node`). Whatever the launch files would start
is therefore what the runner's end-to-end test starts: there is no logic that only a launch run
exercises. It lives in the core, not in `ros_nodes`, because the CLI (`scene_recon`) and the ROS
adapters may not import each other, and because it imports nothing from ROS: it is names and values.

Parameter names are the nodes' own (the dotted keys of their config dataclasses, see
`ros_nodes.parameters`); a wrong name here is caught by the runner test (the node would not use it).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from recon_core.config import Preset, load_preset
from recon_core.errors import ConfigError

#: ROS package name of the executables (setup.py console scripts, `ros2 run scene_recon <executable>`).
PACKAGE = "scene_recon"
#: The oracle's ground-truth label topic (the player publishes it from generated bags).
LABELS_TOPIC = "/ground_truth/panoptic_labels"
BACKENDS = ("auto", "oracle", "onnx", "none")
#: Config files of the nodes in a config folder (the layout of `config/`).
CONFIG_FILES = {"segmentation_service": "segmentation.yaml", "panoptic_mapper": "mapper.yaml",
                "contact_graph": "scene_graph.yaml"}


@dataclass
class GraphOptions:
    """What a user chooses when starting the graph (the runner's options, the launch arguments)."""

    #: Bag (.mcap/.db3/folder) or frame folder to play; empty: a live camera publishes the topics.
    bag: str = ""
    rate: float = 1.0
    loop: bool = False
    start_offset_s: float = 0.0
    #: Camera topics the mapper subscribes to (the player publishes the defaults).
    color_topic: str = "/camera/color/image_raw"
    depth_topic: str = "/camera/depth/image_rect_raw"
    camera_info_topic: str = "/camera/color/camera_info"
    #: REP-105 fixed frame the camera poses are looked up in, and the frame of every output.
    map_frame: str = "map"
    #: Frame id the player gives images and poses (live: the driver's own).
    camera_frame: str = "camera_color_optical_frame"
    #: Segmentation backend: auto = onnx with a model, oracle with ground truth, else none.
    backend: str = "auto"
    model: str = ""
    model_config: str = ""
    classes: str = ""
    ground_truth: str = ""
    noise_level: str = "default"
    #: Folder with the layout of `config/` (mapper.yaml, segmentation.yaml, scene_graph.yaml); empty: defaults.
    config_dir: str = ""
    #: None: sim time when playing a bag (the player publishes /clock), wall time live.
    use_sim_time: bool | None = None
    #: Output folder: the mapper's data root (checkpoints, saved maps) in <out>/map, the scene in <out>/scene.
    out: str = "scene_recon_data"
    seeds_per_class: int = 10
    method: str = "ours"
    #: Period (s) of the mapper's status topic (the runner's progress line reads it).
    status_period_s: float = 1.0
    #: Speed/accuracy preset (fast | balanced | accurate: config/presets/NAME.yaml, or a YAML path); empty: none.
    #: Applied to the nodes' parameters as `--preset` applies it to `scene-recon map/graph/replace`.
    preset: str = ""

    def resolved_ground_truth(self) -> str:
        """The oracle's ground truth: the option, else a generated bag's `<bag>_groundtruth` folder beside it
        (as `scene-recon map` finds it), else ""."""
        if self.ground_truth or not self.bag:
            return self.ground_truth
        bag = Path(self.bag).expanduser()
        if bag.is_file():  # the bare .mcap/.db3 inside the bag folder
            bag = bag.parent
        beside = bag.with_name(bag.name + "_groundtruth")
        return str(beside) if (beside / "scene.json").is_file() else ""

    def resolved_backend(self) -> str:
        """The backend `auto` stands for with these options (the rule of `scene-recon map`)."""
        if self.backend != "auto":
            return self.backend
        if self.model or self.model_config:
            return "onnx"
        return "oracle" if self.resolved_ground_truth() else "none"

    def sim_time(self) -> bool:
        return bool(self.bag) if self.use_sim_time is None else bool(self.use_sim_time)


@dataclass
class NodeSpec:
    """One node of the graph: how `ros2 run`/launch and the runner start it."""

    name: str
    executable: str  # console script (setup.py), for `ros2 run` / launch_ros
    module: str  # `python -m <module>`, for the runner
    parameters: dict[str, Any] = field(default_factory=dict)
    remappings: list[tuple[str, str]] = field(default_factory=list)
    #: Parameters on top of `parameters` when the runner restarts the node after it died (the mapper
    #: resumes from its newest checkpoint); the other nodes rejoin from the transient-local topics.
    respawn_parameters: dict[str, Any] = field(default_factory=dict)

    def respawned(self) -> NodeSpec:
        """The spec a restarted node runs with."""
        return NodeSpec(self.name, self.executable, self.module, {**self.parameters, **self.respawn_parameters},
                        list(self.remappings), dict(self.respawn_parameters))

    def ros_args(self, params_file: str | Path | None = None) -> list[str]:
        """The `--ros-args` part of a command line starting this node (parameters from `params_file`,
        written by `params_yaml`; without it, as `-p name:=value` pairs)."""
        args = ["--ros-args", "-r", f"__node:={self.name}"]
        for src, dst in self.remappings:
            args += ["-r", f"{src}:={dst}"]
        if params_file is not None:
            return [*args, "--params-file", str(params_file)]
        for key, value in self.parameters.items():
            args += ["-p", f"{key}:={_yaml_scalar(value)}"]
        return args

    def params_yaml(self) -> dict[str, Any]:
        """The node's parameters as a ROS parameter file (`{name: {ros__parameters: ...}}`)."""
        return {self.name: {"ros__parameters": dict(self.parameters)}}


def _yaml_scalar(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return "''" if value == "" else f"'{value}'" if ":" in value or value.strip() != value else value
    return repr(value)


#: Where each section of a preset lands: (node, parameter prefix). The `data` section (how a recording is
#: read) goes to the player, key by key (`PRESET_DATA_PARAMETERS`).
PRESET_NODES = {"mapper": ("panoptic_mapper", ""), "scene_graph": ("contact_graph", ""),
                "cad": ("cad_replacer", "replace.")}
#: A preset's `data` keys the player honours (the player's parameter of the same name).
PRESET_DATA_PARAMETERS = ("stride",)


def preset_parameters(preset: Preset | None, bag: bool) -> dict[str, dict[str, Any]]:
    """Node name -> parameters a preset sets: its mapper / scene_graph / cad overrides under the nodes'
    own names (the dotted keys of the same config dataclasses, so the same values `--preset` gives the
    CLI stages) and, when a recording is played (`bag`), its `data.stride` as the player's `stride`.
    A live camera is not thinned (no node reads a live stream with a stride). A `data` key no node
    honours is refused rather than silently dropped."""
    if preset is None:
        return {}
    out: dict[str, dict[str, Any]] = {}
    for section, (node, prefix) in PRESET_NODES.items():
        values = {prefix + key: value for key, value in preset.section(section).items()}
        if values:
            out[node] = values
    data = preset.section("data")
    unknown = sorted(set(data) - set(PRESET_DATA_PARAMETERS))
    if unknown:
        raise ConfigError(f"preset {preset.name!r}: data key(s) {unknown} have no node parameter (the ROS graph "
                          f"honours {list(PRESET_DATA_PARAMETERS)} of the data section)")
    if bag and data:
        out["rgbd_player"] = {key: data[key] for key in PRESET_DATA_PARAMETERS if key in data}
    return out


def graph_nodes(opts: GraphOptions) -> list[NodeSpec]:
    """The nodes of the whole pipeline (segmentation, mapper, contact graph, CAD replacer and, with a
    bag, the player), in start order: consumers before producers, so no frame waits for discovery.
    A preset's parameters come first; the explicit options of `opts` win over them."""
    preset = preset_parameters(load_preset(opts.preset or None), bool(opts.bag))
    nodes = _graph_nodes(opts)
    for spec in nodes:
        if spec.name in preset:
            spec.parameters = {**preset[spec.name], **spec.parameters}
    return nodes


def _graph_nodes(opts: GraphOptions) -> list[NodeSpec]:
    sim = opts.sim_time()
    backend = opts.resolved_backend()
    out = Path(opts.out).expanduser()
    map_root, scene_dir = str(out / "map"), str(out / "scene")
    common: dict[str, Any] = {"use_sim_time": sim}

    def config_file(node: str) -> dict[str, Any]:
        return {"config_file": str(Path(opts.config_dir) / CONFIG_FILES[node])} if opts.config_dir else {}

    segmentation = NodeSpec("segmentation_service", "segmentation_service", "ros_nodes.segmentation_service", {
        **common, **config_file("segmentation_service"), "backend": backend,
        "onnx.model": opts.model, "onnx.model_config": opts.model_config, "onnx.class_table": opts.classes,
        "oracle.ground_truth": opts.resolved_ground_truth() if backend == "oracle" else opts.ground_truth,
        "oracle.level": opts.noise_level,
    })
    mapper = NodeSpec("panoptic_mapper", "panoptic_mapper", "ros_nodes.mapper_node", {
        **common, **config_file("panoptic_mapper"), "map_frame": opts.map_frame,
        "color_topic": opts.color_topic, "depth_topic": opts.depth_topic, "camera_info_topic": opts.camera_info_topic,
        "use_segmentation": backend != "none", "class_table": opts.classes, "data_root": map_root,
        "status_period_s": float(opts.status_period_s),
        # a recording is integrated in its recorded order, as `scene-recon run` does: the same map; and
        # a longer queue, since frames wait behind keyframes there (30 dropped one of 60 320x240 frames)
        "in_order": bool(opts.bag), "max_queue": 120 if opts.bag else 30,
        # the player's /tf is reliable: a reliable reader gets the poses sent while discovery completes (a
        # best-effort one lost the first 6 of a bag on a loaded machine), and a frame whose camera info or
        # pose comes late that way waits for it longer than a live camera's would
        "tf_reliable": bool(opts.bag), "tf_wait_s": 3.0 if opts.bag else 0.5,
    }, respawn_parameters={"resume": True})
    graph = NodeSpec("contact_graph", "contact_graph_node", "ros_nodes.contact_graph_node", {
        **common, **config_file("contact_graph"), "mesh_root": map_root,
    })
    replacer = NodeSpec("cad_replacer", "cad_replacer", "ros_nodes.cad_replacer_node", {
        **common, "output_dir": scene_dir, "mesh_root": map_root, "seeds_per_class": int(opts.seeds_per_class),
        "replace.method": opts.method,
    })
    nodes = [segmentation, mapper, graph, replacer]
    if opts.bag:
        nodes.append(NodeSpec("rgbd_player", "rgbd_player", "ros_nodes.rgbd_player", {
            # the player is the clock: it never runs on sim time itself
            "source": opts.bag, "rate": float(opts.rate), "loop": bool(opts.loop),
            "start_offset_s": float(opts.start_offset_s), "publish_clock": sim,
            "map_frame": opts.map_frame, "camera_frame": opts.camera_frame,
            "color_topic": opts.color_topic, "depth_topic": opts.depth_topic,
            "camera_info_topic": opts.camera_info_topic,
            # start once the mapper listens (and the oracle service, which reads the labels): no frame lost
            "wait_for_subscribers": 1, "labels_topic_in": LABELS_TOPIC if backend == "oracle" else "",
            # the player sees its writers match before the readers have matched them: samples sent in between
            # are lost to a best-effort reader and come late to a reliable one (the mapper's /tf is reliable
            # with bags, `tf_reliable`); 0.5 s after the counts went up was not always enough
            "wait_grace_s": 1.5,
            "wait_for_label_subscribers": 1 if backend == "oracle" else 0,
        }))
    return nodes


#: Launch arguments (name, default, description) shared by both launch files; None: required.
_COMMON_ARGUMENTS: list[tuple[str, str | None, str]] = [
    ("color_topic", GraphOptions.color_topic, "color image topic (sensor_msgs/Image)"),
    ("depth_topic", GraphOptions.depth_topic, "depth image topic registered to color (16UC1 mm or 32FC1 m)"),
    ("camera_info_topic", GraphOptions.camera_info_topic, "camera info of the color camera"),
    ("map_frame", GraphOptions.map_frame, "REP-105 fixed frame (gravity-aligned, z up): poses and outputs"),
    ("backend", GraphOptions.backend, "segmentation: auto | onnx | oracle | none"),
    ("model", "", "exported .onnx detector/segmenter (backend onnx)"),
    ("model_config", "", "ONNX model config YAML (config/segmentation/*.yaml)"),
    ("classes", "", "class table YAML (default config/classes.yaml)"),
    ("ground_truth", "", "oracle: the generated bag's *_groundtruth folder"),
    ("noise_level", GraphOptions.noise_level, "oracle: clean | default | hard"),
    ("config_dir", "", "folder with mapper.yaml, segmentation.yaml, scene_graph.yaml (default: the package's)"),
    ("out", GraphOptions.out, "output folder: <out>/map (checkpoints, saved maps), <out>/scene (URDF, meshes)"),
    ("seeds_per_class", str(GraphOptions.seeds_per_class), "procedural CAD models per class"),
    ("method", GraphOptions.method, "CAD replacement: ours | paper"),
    ("preset", "", "speed/accuracy preset: fast | balanced | accurate (config/presets/NAME.yaml) or a YAML file; "
     "empty: the config files as they are"),
]
LIVE_ARGUMENTS = [*_COMMON_ARGUMENTS, ("use_sim_time", "false", "nodes on /clock time (true/false)")]
BAG_ARGUMENTS: list[tuple[str, str | None, str]] = [
    ("bag", None, "bag (.mcap/.db3/folder) or frame folder to play"),
    ("rate", "1.0", "playback speed factor"),
    ("loop", "false", "start over at the end"),
    ("start_offset_s", "0.0", "skip the recording's first seconds"),
    ("camera_frame", GraphOptions.camera_frame, "frame id the player gives images and poses"),
    *_COMMON_ARGUMENTS,
    ("use_sim_time", "true", "nodes on the player's /clock (true/false)"),
]


def options_from_strings(values: dict[str, str]) -> GraphOptions:
    """GraphOptions from launch-argument strings (`ros2 launch ... rate:=0.5 loop:=true`)."""
    opts = GraphOptions()
    for name, text in values.items():
        if not hasattr(opts, name):
            raise KeyError(f"unknown launch argument {name!r}")
        default = getattr(opts, name)
        if name == "use_sim_time":
            setattr(opts, name, None if text in ("", "auto") else _bool(text))
        elif isinstance(default, bool):
            setattr(opts, name, _bool(text))
        elif isinstance(default, int):
            setattr(opts, name, int(text))
        elif isinstance(default, float):
            setattr(opts, name, float(text))
        else:
            setattr(opts, name, text)
    return opts


def _bool(text: str) -> bool:
    low = text.strip().lower()
    if low in ("true", "1", "yes", "on"):
        return True
    if low in ("false", "0", "no", "off", ""):
        return False
    raise ValueError(f"not a boolean: {text!r}")


__all__ = ["BACKENDS", "BAG_ARGUMENTS", "LABELS_TOPIC", "LIVE_ARGUMENTS", "PACKAGE", "GraphOptions", "NodeSpec",
           "graph_nodes", "options_from_strings", "preset_parameters"]
