"""Contact graphs (paper Sec. 2): boxes, planes, support and proximal relations. ROS-free."""
