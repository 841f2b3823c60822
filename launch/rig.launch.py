"""Launch the panel_rig node in /rig with the paper's physics and the node parameters.

The physics file keeps its ``panel_rig:`` key (a node at the root); the node's own ``--params`` option
applies it in the /rig namespace too. rig.yaml is keyed ``/**`` and is passed as a normal params file.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch_ros.actions import Node

from launch import LaunchDescription


def generate_launch_description() -> LaunchDescription:
    config = os.path.join(get_package_share_directory("panel_rig"), "config")
    return LaunchDescription(
        [
            Node(
                package="panel_rig",
                executable="rig_node",
                name="panel_rig",
                namespace="rig",
                output="screen",
                arguments=["--params", os.path.join(config, "tang_dowell_2002.yaml")],
                parameters=[os.path.join(config, "rig.yaml")],
            )
        ]
    )
