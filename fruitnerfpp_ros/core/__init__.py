"""ROS-free core of fruitnerfpp_ros: data, fields, training, export, clustering, evaluation, synthetic data.

Nothing under ``core`` imports rclpy or ROS message packages.
"""
