"""`scene-recon ros-run`: the ROS 2 graph as separate processes (`processes`), watched by a small
client node in the runner's own process (`monitor`). The node set comes from `recon_core.ros_graph`,
the description the launch files use too."""
