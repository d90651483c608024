"""All four stages on a live RGB-D camera: segmentation, mapper, contact graph, CAD replacer.

    ros2 launch scene_recon reconstruct.launch.py \\
        color_topic:=/camera/color/image_raw depth_topic:=/camera/aligned_depth_to_color/image_raw \\
        camera_info_topic:=/camera/color/camera_info map_frame:=map backend:=onnx model:=/path/model.onnx \\
        preset:=fast
    rviz2 -d $(ros2 pkg prefix scene_recon)/share/scene_recon/config/scene.rviz

The camera pose comes from TF (map_frame -> the images' frame id), so a SLAM/odometry node must
publish it. The node list and every parameter come from `recon_core.ros_graph.graph_nodes`, the
description `scene-recon ros-run --live` starts as processes; this file only declares the
arguments and turns each NodeSpec into a launch_ros Node. `preset:=fast|balanced|accurate` applies
config/presets/NAME.yaml to the nodes' parameters, as `--preset` does for the CLI (a live camera is
not thinned: a preset's data.stride applies to recordings).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from recon_core.ros_graph import LIVE_ARGUMENTS, PACKAGE, graph_nodes, options_from_strings


def _nodes(context):
    opts = options_from_strings({name: LaunchConfiguration(name).perform(context) for name, _, _ in LIVE_ARGUMENTS})
    return [Node(package=PACKAGE, executable=spec.executable, name=spec.name, output="screen",
                 parameters=[spec.parameters], remappings=spec.remappings) for spec in graph_nodes(opts)]


def generate_launch_description() -> LaunchDescription:
    args = [DeclareLaunchArgument(name, default_value=default, description=doc)
            for name, default, doc in LIVE_ARGUMENTS if default is not None]
    return LaunchDescription([*args, OpaqueFunction(function=_nodes)])
