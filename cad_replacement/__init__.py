"""CAD library, CAD matching/alignment and kinematic-tree export (paper Sec. 4). ROS-free."""
