"""Driver and compensation nodes with the package's parameter file (needs a full ROS install)."""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    default_params = os.path.join(get_package_share_directory('mlx_tempcomp'), 'config',
                                  'mlx_tempcomp.yaml')
    params = LaunchConfiguration('params_file')
    return LaunchDescription([
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='parameter YAML for both nodes'),
        Node(package='mlx_tempcomp', executable='driver_node', name='driver_node',
             parameters=[params], output='screen'),
        Node(package='mlx_tempcomp', executable='compensation_node', name='compensation_node',
             parameters=[params], output='screen'),
    ])
