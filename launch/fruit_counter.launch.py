"""Launch the fruit_counter node with config/fruit_counter.yaml (ROS 2 Jazzy).

    ros2 launch fruitnerfpp_ros fruit_counter.launch.py
    ros2 launch fruitnerfpp_ros fruit_counter.launch.py params_file:=/path/to/my.yaml output_dir:=/data/run1 \
        namespace:=robot1 sim:=true

With ``sim:=true`` an orchard_sim node publishes a generated synthetic drive on the default topics; with
``rviz:=true`` RViz2 shows the outputs (rviz/fruit_counter.rviz, installed under share/fruitnerfpp_ros/rviz; RViz2
itself comes from the ROS 2 desktop install). foxglove/fruit_counter.json is the same view as a Foxglove layout.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    share = get_package_share_directory('fruitnerfpp_ros')
    default_params = os.path.join(share, 'config', 'fruit_counter.yaml')
    params_file = LaunchConfiguration('params_file')
    namespace = LaunchConfiguration('namespace')
    return LaunchDescription([
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='ROS 2 params file of fruit_counter'),
        DeclareLaunchArgument('namespace', default_value='', description='namespace of the nodes'),
        DeclareLaunchArgument('output_dir', default_value='',
                              description="run directory ('' = ~/.ros/fruitnerfpp/run_<UTC time>)"),
        DeclareLaunchArgument('log_level', default_value='info', description='ROS log level'),
        DeclareLaunchArgument('sim', default_value='false', description='also start orchard_sim'),
        DeclareLaunchArgument('rviz', default_value='false',
                              description='also start RViz2 with rviz/fruit_counter.rviz (fixed frame map)'),
        Node(
            package='fruitnerfpp_ros',
            executable='fruit_counter',
            name='fruit_counter',
            namespace=namespace,
            parameters=[params_file, {'output_dir': LaunchConfiguration('output_dir')}],
            ros_arguments=['--log-level', LaunchConfiguration('log_level')],
            output='screen',
            emulate_tty=True,
        ),
        Node(
            package='fruitnerfpp_ros',
            executable='orchard_sim',
            name='orchard_sim',
            namespace=namespace,
            output='screen',
            condition=IfCondition(LaunchConfiguration('sim')),
        ),
        Node(
            package='rviz2',
            executable='rviz2',
            name='rviz2',
            arguments=['-d', os.path.join(share, 'rviz', 'fruit_counter.rviz')],
            output='screen',
            condition=IfCondition(LaunchConfiguration('rviz')),
        ),
    ])
