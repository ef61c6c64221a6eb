"""The landing-vision node graph on a ship PC: ``ros2 launch uav_landing_vision landing_vision.launch.py``.

One process per node, parameters from the installed ``share/uav_landing_vision/config/<node>.yaml``
(the same files ``uav-landing graph`` uses). Arguments:

- ``bag:=/path/to/bag`` replays a recorded landing with ``bag_player`` (paced on the tracker's
  status: every frame tracked) once every link of the
  graph is up (those of the recorded inputs the bag has: ``replay_ready_topics``; matched by DDS
  as every node sees it: ``ready_nodes``), every node on
  the bag's time (``use_sim_time``, the player publishing ``/clock``), and shuts the graph down
  ``DRAIN_S`` after the bag ends (for the last frames' poses); without it the graph runs on the
  live camera.
- ``config_dir:=/path`` reads the parameter files from another folder.
- ``remap:=FROM:=TO[,FROM:=TO...]`` remaps topics (absolute names) in every node, as
  ``uav-landing graph --remap``: e.g. ``remap:=/deck_cam/image_raw:=/camera/image_raw,/deck_cam/camera_info:=/camera/camera_info``
  for a camera driver, or a recording, of other topic names (the player's pace and ready topics follow).
  A bag whose frames are only compressed ones (``/camera/image_raw/compressed``) is played with
  ``undistort`` decoding them, as ``uav-landing graph`` does (``frame_overrides``).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, OpaqueFunction, RegisterEventHandler, TimerAction
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

# Every link of the graph that the bag can bring up: a replay waits for all of them, or its first
# frames are lost to the nodes still loading their models.
from uav_landing_vision.graph import TRACKER_ACK, frame_overrides, parse_remaps, replay_ready_topics

PACKAGE = "uav_landing_vision"
# The graph without the player, in start order (as uav_landing_vision.graph.GRAPH_NODES).
NODES = ("undistort", "detector", "pose_boosting", "tracker", "gcs_bridge", "evaluator")
PLAYER = "bag_player"
DRAIN_S = 2.0  # from the end of the bag to the shutdown (as uav-landing graph --drain)


def _nodes(context):
    config_dir = LaunchConfiguration("config_dir").perform(context)
    bag = LaunchConfiguration("bag").perform(context)
    remaps = parse_remaps([r for r in LaunchConfiguration("remap").perform(context).split(",") if r.strip()])

    def node(name, extra=()):
        params = [os.path.join(config_dir, f"{name}.yaml"), *extra]
        return Node(package=PACKAGE, executable=name, name=name, parameters=params, remappings=list(remaps.items()),
                    output="screen", emulate_tty=True)

    sim_time = [{"use_sim_time": True}] if bag else []  # a replay runs on the bag's /clock
    frames = {name: dict(items) for name, items in frame_overrides(bag, remaps).items()} if bag else {}
    actions = [node(name, sim_time + ([frames[name]] if name in frames else [])) for name in NODES]
    if bag:
        player = node(PLAYER, [{"bag": bag, "clock": True, "ready_topics": list(replay_ready_topics(bag, remaps)),
                                "ready_nodes": list(NODES),
                                **dict(TRACKER_ACK), **frames.get(PLAYER, {})}])
        actions += [
            player,
            RegisterEventHandler(OnProcessExit(
                target_action=player,
                on_exit=[TimerAction(period=DRAIN_S, actions=[EmitEvent(event=Shutdown(reason="bag played"))])],
            )),
        ]
    return actions


def generate_launch_description():
    default_config = os.path.join(get_package_share_directory(PACKAGE), "config")
    return LaunchDescription([
        DeclareLaunchArgument("bag", default_value="", description="rosbag2 bag to replay (empty: live camera)"),
        DeclareLaunchArgument("remap", default_value="", description="topic remappings of every node: FROM:=TO[,FROM:=TO...] (absolute names)"),
        DeclareLaunchArgument("config_dir", default_value=default_config, description="folder of the <node>.yaml parameter files"),
        OpaqueFunction(function=_nodes),
    ])
