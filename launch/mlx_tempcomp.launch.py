"""
Driver and compensation nodes, or both in one process, with parameter files, in a namespace.

    ros2 launch mlx_tempcomp mlx_tempcomp.launch.py \
        params_file:=my_gyro.yaml,fitted.yaml namespace:=left_imu single_process:=true

Needs a ROS install's launch and launch_ros. What it starts is decided by
``mlx_tempcomp.parameters.launch_plan`` from the arguments' text (see there:
the order of the files, relative sections in a namespace, a missing file).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, LogInfo, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from mlx_tempcomp.parameters.launch_plan import launch_plan


def _nodes(context):
    """Give the actions of the plan for the arguments of this launch (launch time)."""
    plan = launch_plan(
        LaunchConfiguration('params_file').perform(context),
        LaunchConfiguration('namespace').perform(context),
        LaunchConfiguration('single_process').perform(context),
        pushed_namespace=context.launch_configurations.get('ros_namespace'))
    return [LogInfo(msg=note) for note in plan.notes] + [
        Node(package='mlx_tempcomp', executable=node.executable, name=node.name,
             namespace=None if plan.namespace == '/' else plan.namespace,
             parameters=list(plan.params_files), output='screen')
        for node in plan.nodes]


def generate_launch_description():
    config = os.path.join(get_package_share_directory('mlx_tempcomp'), 'config',
                          'mlx_tempcomp.yaml')
    return LaunchDescription([
        DeclareLaunchArgument(
            'params_file', default_value=config,
            description='parameter files of both nodes, comma-separated, each over the ones '
                        'before it: the shipped config (or your copy), then the file '
                        'mlx-tempcomp wrote'),
        DeclareLaunchArgument(
            'namespace', default_value='',
            description="the nodes' namespace (e.g. left_imu); a file's sections named "
                        'after a node are resolved in it'),
        DeclareLaunchArgument(
            'single_process', default_value='false', choices=['true', 'false'],
            description='true: both nodes in one process (the bringup executable)'),
        OpaqueFunction(function=_nodes),
    ])
