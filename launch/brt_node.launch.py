# Copyright hjrno_ros developers. Licensed under the Apache License, Version 2.0.
"""Launch brt_node under a Nav2 lifecycle manager (docs/nav2.md).

    ros2 launch hjrno_ros brt_node.launch.py                      # the package's config/brt_node.yaml
    ros2 launch hjrno_ros brt_node.launch.py params_file:=/path/to/brt_node.yaml use_sim_time:=true \
        cmd_vel_in:=cmd_vel_smoothed cmd_vel_out:=cmd_vel map:=map odom:=odom namespace:=robot1

The launch argument ``autostart`` is the lifecycle manager's, under the name Nav2's bringup gives it:
``lifecycle_manager_brt`` (Nav2's nav2_lifecycle_manager) configures and activates brt_node when it is true.
brt_node's own parameter of the same name (plain mode: activate itself) is always overridden to False here, so
only the manager drives the node.  brt_node has no bond
(the bond library is not on PyPI), so the manager runs with ``bond_timeout: 0.0``.  The remappings act
on brt_node's default topic names (cmd_vel_smoothed, cmd_vel, map, odom); a params file that renames
those topics is used as it is.

The launch packages (launch, launch_ros) are not on PyPI: CI only compiles this file and checks the
names in it (test/ros/brt_node/test_launch.py).
"""
# ruff: noqa: I001  (this folder is named launch, so ruff would sort the launch package as first-party)

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.descriptions import ParameterFile


def generate_launch_description():
    share = get_package_share_directory('hjrno_ros')

    params_file = LaunchConfiguration('params_file')
    use_sim_time = LaunchConfiguration('use_sim_time')
    autostart = LaunchConfiguration('autostart')
    namespace = LaunchConfiguration('namespace')
    log_level = LaunchConfiguration('log_level')
    remappings = [
        ('cmd_vel_smoothed', LaunchConfiguration('cmd_vel_in')),
        ('cmd_vel', LaunchConfiguration('cmd_vel_out')),
        ('map', LaunchConfiguration('map')),
        ('odom', LaunchConfiguration('odom')),
    ]

    arguments = [
        DeclareLaunchArgument(
            'params_file', default_value=os.path.join(share, 'config', 'brt_node.yaml'),
            description='Full path to the brt_node parameters file'),
        DeclareLaunchArgument(
            'use_sim_time', default_value='false',
            description='Use the simulation (Gazebo) clock if true'),
        DeclareLaunchArgument(
            'autostart', default_value='true',
            description='The lifecycle manager configures and activates brt_node at start'),
        DeclareLaunchArgument(
            'namespace', default_value='',
            description='Top-level namespace'),
        DeclareLaunchArgument(
            'log_level', default_value='info',
            description='Log level'),
        DeclareLaunchArgument(
            'cmd_vel_in', default_value='cmd_vel_smoothed',
            description='Nominal command in (velocity_smoother output or collision_monitor output)'),
        DeclareLaunchArgument(
            'cmd_vel_out', default_value='cmd_vel',
            description='Filtered command out (the base)'),
        DeclareLaunchArgument(
            'map', default_value='map',
            description='OccupancyGrid topic: map_server map or a Nav2 costmap (map_kind costmap)'),
        DeclareLaunchArgument(
            'odom', default_value='odom',
            description='Odometry topic'),
    ]

    nodes = [
        Node(
            package='hjrno_ros',
            executable='brt_node',
            name='brt_node',
            namespace=namespace,
            output='screen',
            parameters=[
                ParameterFile(params_file, allow_substs=True),
                {'use_sim_time': use_sim_time, 'autostart': False},
            ],
            arguments=['--ros-args', '--log-level', log_level],
            remappings=remappings,
        ),
        Node(
            package='nav2_lifecycle_manager',
            executable='lifecycle_manager',
            name='lifecycle_manager_brt',
            namespace=namespace,
            output='screen',
            parameters=[
                {'use_sim_time': use_sim_time},
                {'autostart': autostart},
                {'node_names': ['brt_node']},
                {'bond_timeout': 0.0},
            ],
            arguments=['--ros-args', '--log-level', log_level],
        ),
    ]

    return LaunchDescription([*arguments, *nodes])
