"""Start ``driveline_node`` the way a vehicle stack starts nodes.

    ros2 launch dmf_sim driveline.launch.py
    ros2 launch dmf_sim driveline.launch.py namespace:=truck1 record:=true bag_path:=/data/run1
    ros2 launch dmf_sim driveline.launch.py params_file:=/path/to/my_truck_node.yaml

Arguments: ``namespace`` (topics, services and the node move under it; '' = none),
``params_file`` (default: the installed config/driveline_node.yaml, whose key ``/**/
driveline_node`` matches the node in any namespace), ``record`` (true/false) and ``bag_path``
('' = dmf_bag_<YYYYmmdd_HHMMSS> in the working directory). ``record`` and ``bag_path`` override
the params file. Installed to share/dmf_sim/launch by setup.py.
"""
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

from launch import LaunchDescription


def generate_launch_description() -> LaunchDescription:
    default_params = PathJoinSubstitution(
        [FindPackageShare('dmf_sim'), 'config', 'driveline_node.yaml'])
    arguments = [
        DeclareLaunchArgument('namespace', default_value='',
                              description="Namespace of the node and its topics, e.g. 'truck1'"),
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='Parameters YAML of driveline_node'),
        DeclareLaunchArgument('record', default_value='false', choices=['true', 'false'],
                              description='Record the published streams to an MCAP bag'),
        DeclareLaunchArgument('bag_path', default_value='',
                              description="Bag directory ('' = dmf_bag_<time>); never "
                                          'overwritten'),
    ]
    node = Node(
        package='dmf_sim', executable='driveline_node', name='driveline_node',
        namespace=LaunchConfiguration('namespace'), output='screen', emulate_tty=True,
        parameters=[LaunchConfiguration('params_file'),
                    {'record': ParameterValue(LaunchConfiguration('record'), value_type=bool),
                     'bag_path': ParameterValue(LaunchConfiguration('bag_path'),
                                                value_type=str)}])
    return LaunchDescription(arguments + [node])
