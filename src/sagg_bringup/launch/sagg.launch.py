"""Launch the sagg graph on a full ROS 2 install: ``ros2 launch sagg_bringup sagg.launch.py config:=FILE``.

Mirrors ``sagg run`` without its extras (recording, evaluation, report): the three nodes with one
parameter file. Unlike ``sagg run``, nothing is filled in for you: for the learner, the file must set
``joints``, ``joint_limits.lower/upper``, ``rest_posture`` (and ``max_micro_actions`` if wanted) to
match the bridge's arm or your real arm's controller; ``sagg run`` writes such a file
(``DIR/params.yaml``) that can be passed here as is. For a real arm, set ``use_sim:=false`` and
run your ros2_control driver instead of the MuJoCo bridge.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    config = LaunchConfiguration("config")
    use_sim = LaunchConfiguration("use_sim")
    return LaunchDescription([
        DeclareLaunchArgument(
            "config", description="ROS 2 parameter file with sections sagg_goal_generator, "
                                  "sagg_learner and sagg_sim_bridge (e.g. a `sagg run` params.yaml)"),
        DeclareLaunchArgument("use_sim", default_value="true",
                              description="start the MuJoCo bridge (false: a real driver is running)"),
        Node(package="sagg_sim_bridge", executable="mujoco_bridge", name="sagg_sim_bridge",
             parameters=[config], output="screen", condition=IfCondition(use_sim)),
        Node(package="sagg_goal_generator", executable="goal_generator", name="sagg_goal_generator",
             parameters=[config], output="screen"),
        Node(package="sagg_low_level", executable="learner", name="sagg_learner",
             parameters=[config], output="screen"),
    ])
