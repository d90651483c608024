"""Volumetric panoptic mapping (paper Sec. 3) and the RGB-D data input layer. ROS-free."""
