"""Stamped input streams without ROS: approximate-time synchronisation and a TF tree buffer."""
