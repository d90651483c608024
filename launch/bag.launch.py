"""All four stages on a recording: the player (with /clock) + segmentation, mapper, contact graph, CAD replacer.

    ros2 launch scene_recon bag.launch.py bag:=/path/to/scene.mcap [rate:=0.5] [backend:=oracle] [preset:=fast] ...
    rviz2 -d $(ros2 pkg prefix scene_recon)/share/scene_recon/config/scene.rviz

The node list and every parameter come from `recon_core.ros_graph.graph_nodes`, the description
`scene-recon ros-run --bag` starts as processes (and its end-to-end test checks); this file only
declares the arguments and turns each NodeSpec into a launch_ros Node. `preset:=fast|balanced|accurate`
applies config/presets/NAME.yaml to the nodes' parameters, as `--preset` does for the CLI (its
data.stride: the player plays every n-th frame pair).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from recon_core.ros_graph import BAG_ARGUMENTS, PACKAGE, graph_nodes, options_from_strings


def _nodes(context):
    opts = options_from_strings({name: LaunchConfiguration(name).perform(context) for name, _, _ in BAG_ARGUMENTS})
    return [Node(package=PACKAGE, executable=spec.executable, name=spec.name, output="screen",
                 parameters=[spec.parameters], remappings=spec.remappings) for spec in graph_nodes(opts)]


def generate_launch_description() -> LaunchDescription:
    args = [DeclareLaunchArgument(name, description=doc) if default is None
            else DeclareLaunchArgument(name, default_value=default, description=doc)
            for name, default, doc in BAG_ARGUMENTS]
    return LaunchDescription([*args, OpaqueFunction(function=_nodes)])
