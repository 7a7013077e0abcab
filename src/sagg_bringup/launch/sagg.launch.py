"""Launch the sagg graph on a full ROS 2 install.

    ros2 launch sagg_bringup sagg.launch.py [config:=arm8] [driver:=sim|external] [record:=false|true]
                                            [micro_actions:=0] [record_out:=DIR]

``config``: an installed config's name (``arm8``, ``arm15``, ``quadruped``, ...) or any parameter
file (a config, or the ``params.yaml`` a ``sagg run`` wrote). Every derived parameter is filled in
from it exactly as ``sagg run`` does (``sagg_bringup.graph.launch_params.launch_plan``): the learner's
``joints``, ``joint_limits``, ``rest_posture`` from the simulated arm (``driver:=sim``) or the
config's own (``driver:=external``: your arm's driver runs already; no bridge is started), the
synergy set-ups' nodes. The expanded parameter file is written to a temporary directory and its
path logged; the directory is removed when the launch shuts down (every process has read it at its
start). ``record:=true`` also starts ``sagg record`` (``sagg run``'s topic set, mcap, into
``record_out`` or ``runs/record-<time>``): the learner and generator wait for its subscriptions
before their first sample and goal, the learner then waits whenever it lags (its acknowledgements
on /sagg/recorded, ``recorder_max_lag``), and at Ctrl-C (SIGINT to every process at once) it
records until the nodes have exited and their last messages are in, then closes the bag; messages
lost all the same are counted and make it exit with code 3 (``sagg record``'s doc). Its
``sigterm_timeout`` (30 s) is above its drain limit (20 s), so launch does not cut that short.
``micro_actions``: the learner stops there (0 = never). The run-only values (``max_micro_actions``,
a config's ``checkpoint_dir`` / ``resume``) are given to the nodes as parameters of their own,
not in the parameter file (``sagg_bringup.graph.params_files.run_values``).
"""
import shutil
import tempfile
from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess, LogInfo, OpaqueFunction, RegisterEventHandler
from launch.event_handlers import OnShutdown
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from sagg_bringup.graph.processes import find_node_executable
from sagg_bringup.graph.launch_params import launch_plan, write_plan
from sagg_bringup.graph.params_files import run_values


def _nodes(context):
    def arg(name):
        return LaunchConfiguration(name).perform(context)

    record = arg("record").lower()
    if record not in ("true", "false"):
        raise RuntimeError(f"record:={record!r}; allowed: true or false")
    plan = launch_plan(arg("config"), arg("driver"), int(arg("micro_actions")))
    tmp = Path(tempfile.mkdtemp(prefix="sagg-launch-"))
    path = write_plan(plan, tmp / "params.yaml")
    waits = {"sagg_learner": {"min_sample_subscribers": 1}, "sagg_goal_generator": {"min_goal_subscribers": 1}}
    run = run_values(plan.params)  # (the budget, a config's checkpoint_dir / resume: not in the file)
    actions = [LogInfo(msg=f"sagg: {plan.config} (driver {plan.driver}) -> parameters in {path}"),
               RegisterEventHandler(OnShutdown(on_shutdown=lambda event, context: shutil.rmtree(tmp, True)))]
    for package, executable, name in plan.nodes:
        params = ([str(path)] + ([run[name]] if name in run else [])
                  + ([waits[name]] if record == "true" and name in waits else []))
        actions.append(Node(package=package, executable=executable, name=name, parameters=params,
                            output="screen"))
    if record == "true":
        cmd = [str(find_node_executable("sagg_bringup", "sagg")), "record", "--params", str(path)]
        if arg("record_out"):
            cmd += ["--out", arg("record_out")]
        # (sigterm_timeout: launch's SIGTERM after it would cut the recorder's drain short: 20 s at most)
        actions.append(ExecuteProcess(cmd=cmd, output="screen", sigterm_timeout="30"))
    return actions


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("config", default_value="arm8",
                              description="an installed config's name (arm8, arm15, quadruped, ...) or a "
                                          "parameter file (a config or a `sagg run` params.yaml)"),
        DeclareLaunchArgument("driver", default_value="sim", choices=["sim", "external"],
                              description="sim: start the MuJoCo bridge; external: your driver is running"),
        DeclareLaunchArgument("record", default_value="false", choices=["true", "false"],
                              description="also record sagg run's topic set with `sagg record`"),
        DeclareLaunchArgument("record_out", default_value="",
                              description="bag directory of record:=true (default runs/record-<time>)"),
        DeclareLaunchArgument("micro_actions", default_value="0",
                              description="the learner stops after this many micro-actions (0 = never)"),
        OpaqueFunction(function=_nodes),
    ])
