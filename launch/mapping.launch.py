"""Stages 1-2 on a recording: player -> segmentation service -> panoptic mapper (+ RViz markers).

    ros2 launch scene_recon mapping.launch.py source:=out/demo/scene backend:=oracle \
        ground_truth:=out/demo/scene_groundtruth
On a robot, leave `source` empty and remap the mapper's camera topics to the driver's.
`out:=FOLDER` (default scene_recon_data, as `bag.launch.py`): the mapper's checkpoints and saved maps go
to FOLDER/map, not into the current directory.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, PythonExpression
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    source = LaunchConfiguration("source")
    args = [
        DeclareLaunchArgument("source", default_value="", description="bag or frame folder to play (empty: live)"),
        DeclareLaunchArgument("rate", default_value="1.0"),
        DeclareLaunchArgument("backend", default_value="none", description="segmentation: onnx | oracle | none"),
        DeclareLaunchArgument("model", default_value="", description="exported .onnx model (backend onnx)"),
        DeclareLaunchArgument("model_config", default_value="", description="ONNX model config YAML (optional)"),
        DeclareLaunchArgument("classes", default_value="", description="class table YAML (default classes.yaml)"),
        DeclareLaunchArgument("ground_truth", default_value="", description="oracle: *_groundtruth folder"),
        DeclareLaunchArgument("noise_level", default_value="default"),
        DeclareLaunchArgument("mode", default_value="full", description="mapper: full | baseline"),
        DeclareLaunchArgument("out", default_value="scene_recon_data",
                              description="output folder: <out>/map (checkpoints, saved maps)"),
    ]
    segmentation = Node(
        package="scene_recon", executable="segmentation_service", name="segmentation_service", output="screen",
        # parameter names are the dotted keys of config/segmentation.yaml (ros_nodes/parameters.py)
        parameters=[{"backend": LaunchConfiguration("backend"),
                     "onnx.model": LaunchConfiguration("model"),
                     "onnx.model_config": LaunchConfiguration("model_config"),
                     "onnx.class_table": LaunchConfiguration("classes"),
                     "oracle.ground_truth": LaunchConfiguration("ground_truth"),
                     "oracle.level": LaunchConfiguration("noise_level")}],
    )
    mapper = Node(
        package="scene_recon", executable="panoptic_mapper", name="panoptic_mapper", output="screen",
        parameters=[{"mode": LaunchConfiguration("mode"), "class_table": LaunchConfiguration("classes"),
                     "data_root": PathJoinSubstitution([LaunchConfiguration("out"), "map"])}],
    )
    player = Node(
        package="scene_recon", executable="rgbd_player", name="rgbd_player", output="screen",
        condition=IfCondition(PythonExpression(["'", source, "' != ''"])),
        parameters=[{"source": source, "rate": LaunchConfiguration("rate"), "wait_for_subscribers": 1,
                     "labels_topic_in": "/ground_truth/panoptic_labels",
                     "wait_for_label_subscribers": PythonExpression(["1 if '", LaunchConfiguration("backend"),
                                                                     "' == 'oracle' else 0"])}],
    )
    return LaunchDescription([*args, segmentation, mapper, player])
