"""What the launch files (``launch/*.launch.py``) share: each node of a graph with its
installed defaults, the recorder of the graphs that record themselves and the arguments
common to every graph.

Only the launch files import this module: ``launch`` and ``launch_ros`` are imported when a
graph is described, so the nodes themselves never need them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

#: arguments of every graph: (name, default, description with its unit)
COMMON_ARGUMENTS = (
    (
        'track_subscribers',
        '0',
        'your own subscribers on /mlkm/tracks (a tracker, ros2 topic echo) that '
        'association_node waits for before it publishes tracks [-]',
    ),
    ('log_level', 'info', 'log level of every node [-]'),
)


#: arguments of the graphs that record themselves (demo, stream): ``recorder``
RECORD_ARGUMENTS = (
    ('record', 'true', 'record the graph with bag_recorder (true/false) [-]'),
    ('bag_dir', '', "bag directory to write; '' = bags/rosbag2_<local time> [-]"),
)


def param_file(package: str, node: str) -> str:
    """The node's installed defaults, ``share/<package>/config/<node>.param.yaml``."""
    from ament_index_python.packages import get_package_share_directory

    return str(Path(get_package_share_directory(package)) / 'config' / f'{node}.param.yaml')


def flag(value: str) -> bool:
    """A launch argument's true/false."""
    return value.lower() in ('true', '1', 'yes')


def node(
    arg: dict[str, str],
    package: str,
    executable: str,
    params: dict[str, Any],
    namespace: str = '',
) -> Any:
    """``executable`` of ``package`` as a launch_ros Node named after it (in ``namespace``):
    its installed defaults, then ``params``; output on the screen, the graph's log level."""
    from launch_ros.actions import Node

    return Node(
        package=package,
        executable=executable,
        name=executable,
        namespace=namespace,
        parameters=[param_file(package, executable), params],
        ros_arguments=['--log-level', arg['log_level']],
        output='screen',
        emulate_tty=True,
    )


def source_timing(arg: dict[str, str], record: bool) -> dict[str, Any]:
    """A sensor source's pace and start: it waits until association_node (+ the recorder)
    subscribed to every detection topic and scorer_node (+ the recorder) to the ground
    truth, then ``start_delay``."""
    return {
        'seed': int(arg['seed']),
        'real_time_factor': float(arg['real_time_factor']),
        'start_delay': float(arg['start_delay']),
        'wait_for_subscribers': 1 + record,
        'wait_for_truth_subscribers': 1 + record,
    }


def recorder(arg: dict[str, str]) -> list[Any]:
    """``bag_recorder`` recording every topic but ROS housekeeping into ``bag_dir``; none with
    ``record:=false``."""
    from mlkm_ros.qos import RECORD_EXCLUDE_REGEX

    if not flag(arg['record']):
        return []
    params = {'output': arg['bag_dir'], 'exclude_regex': RECORD_EXCLUDE_REGEX}
    return [node(arg, 'rosbag_mcap', 'bag_recorder', params)]


def association_node(arg: dict[str, str], own_subscribers: int, params: dict[str, Any]) -> Any:
    """The association node holding its tracks until ``own_subscribers`` nodes of the graph
    and the user's ``track_subscribers`` matched /mlkm/tracks."""
    awaited = own_subscribers + int(arg['track_subscribers'])
    return node(
        arg, 'mlkm_assoc', 'association_node', {**params, 'wait_for_track_subscribers': awaited}
    )


def description(arguments: tuple[tuple[str, str, str], ...], nodes: Any) -> Any:
    """The launch description: ``arguments`` and the common ones declared, then the nodes
    that ``nodes(context)`` returns."""
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument, OpaqueFunction

    declared = [
        DeclareLaunchArgument(n, default_value=d, description=t)
        for n, d, t in (*arguments, *COMMON_ARGUMENTS)
    ]
    return LaunchDescription([*declared, OpaqueFunction(function=nodes)])
