"""Play an RGB-D recording (bag or frame folder) as camera topics + TF.

    ros2 launch scene_recon play_recording.launch.py source:=/path/to/scene.mcap rate:=1.0
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    args = [
        DeclareLaunchArgument("source", description="bag (.mcap/.db3) or TUM / 7-Scenes folder"),
        DeclareLaunchArgument("rate", default_value="1.0", description="playback speed factor"),
        DeclareLaunchArgument("loop", default_value="false"),
        DeclareLaunchArgument("map_frame", default_value="map"),
    ]
    player = Node(
        package="scene_recon",
        executable="rgbd_player",
        name="rgbd_player",
        output="screen",
        parameters=[{
            "source": LaunchConfiguration("source"),
            "rate": LaunchConfiguration("rate"),
            "loop": LaunchConfiguration("loop"),
            "map_frame": LaunchConfiguration("map_frame"),
        }],
    )
    return LaunchDescription([*args, player])
