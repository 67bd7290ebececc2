"""ROS 2 nodes: message conversions, parameters and threading over the ROS-free core."""
