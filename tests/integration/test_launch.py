"""The ship-PC launch file (not executable here: no launch/launch_ros wheels) and what it relies on:
console scripts, parameter files installed to share/, the same node list as ``uav-landing graph``, and the
shutdown a drain time after the bag."""

import argparse
import ast
import importlib.util
import py_compile
import subprocess
import sys
import types
from pathlib import Path

import yaml

from uav_landing_vision import graph as graph_module
from uav_landing_vision.graph import COMPRESSED_FRAMES, GRAPH_NODES, PIPELINE_TOPICS, PLAYER, TRACKER_ACK, _plan

PACKAGE_DIR = Path(__file__).parents[2] / "src" / "uav_landing_vision"
LAUNCH = PACKAGE_DIR / "launch" / "landing_vision.launch.py"
CONFIG = str(Path(__file__).parents[2] / "config")


def _assignments(path: Path) -> dict:
    tree = ast.parse(path.read_text())
    return {
        node.targets[0].id: ast.literal_eval(node.value)
        for node in tree.body
        if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Name) and isinstance(node.value, (ast.Tuple, ast.Constant))
    }


def _console_scripts() -> dict:
    tree = ast.parse((PACKAGE_DIR / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Dict) and any(isinstance(k, ast.Constant) and k.value == "console_scripts" for k in node.keys):
            entries = ast.literal_eval(node.values[0])
            return dict(e.replace(" ", "").split("=") for e in entries)
    raise AssertionError("no console_scripts in setup.py")


def test_launch_file_compiles(tmp_path):
    py_compile.compile(str(LAUNCH), cfile=str(tmp_path / "launch.pyc"), doraise=True)


def test_launch_and_graph_start_the_same_nodes_each_with_script_module_and_parameters():
    launch = _assignments(LAUNCH)
    assert set(launch["NODES"]) | {launch["PLAYER"]} == set(GRAPH_NODES) and launch["PLAYER"] == PLAYER
    # the graph's links, remaps and frame transport
    assert "from uav_landing_vision.graph import TRACKER_ACK, frame_overrides, parse_remaps, replay_ready_topics" in LAUNCH.read_text()
    scripts = _console_scripts()
    for name in GRAPH_NODES:
        assert scripts[name] == f"uav_landing_vision.nodes.{name}:main"
        assert (PACKAGE_DIR / "uav_landing_vision" / "nodes" / f"{name}.py").is_file()


class _Recorded:
    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


def _launch_actions(monkeypatch, bag: str, config_dir: str, remap: str = "") -> list:
    """The actions the launch file returns, with launch / launch_ros stood in for by recorders
    (they are not installable here), one recorder class per launch class."""

    class LaunchConfiguration(_Recorded):
        def perform(self, context):
            return context[self.args[0]]

    def recorder(name):
        return type(name, (_Recorded,), {})

    stubs = {
        "launch": {"LaunchDescription": _Recorded},
        "launch.actions": {n: recorder(n) for n in
                           ("DeclareLaunchArgument", "EmitEvent", "OpaqueFunction", "RegisterEventHandler", "TimerAction")},
        "launch.event_handlers": {"OnProcessExit": recorder("OnProcessExit")},
        "launch.events": {"Shutdown": recorder("Shutdown")},
        "launch.substitutions": {"LaunchConfiguration": LaunchConfiguration},
        "launch_ros": {},
        "launch_ros.actions": {"Node": recorder("Node")},
        "ament_index_python": {},
        "ament_index_python.packages": {"get_package_share_directory": lambda package: config_dir},
    }
    for name, attributes in stubs.items():
        monkeypatch.setitem(sys.modules, name, types.SimpleNamespace(**attributes))
    spec = importlib.util.spec_from_file_location("landing_vision_launch", LAUNCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module._nodes({"bag": bag, "config_dir": config_dir, "remap": remap})


def _launch_nodes(monkeypatch, bag: str, config_dir: str, remap: str = "", remappings: bool = False) -> dict:
    """The parameters (or the remappings) of each node the launch file starts."""
    nodes = [a.kwargs for a in _launch_actions(monkeypatch, bag, config_dir, remap) if type(a).__name__ == "Node"]
    if remappings:
        return {n["name"]: n["remappings"] for n in nodes}
    return {n["name"]: {k: v for p in n["parameters"] if isinstance(p, dict) for k, v in p.items()} for n in nodes}


def _bag_of(path: Path, topics: dict) -> Path:
    """A bag recording ``topics`` ({name: type}, one message each; only the names matter to the plan)."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    with Writer(path, version=9) as writer:
        for topic, type_name in topics.items():
            writer.write(writer.add_connection(topic, type_name, typestore=typestore), 1, b"\x00\x01\x00\x00")
    return path


def test_launch_replay_runs_on_the_bags_clock_and_waits_for_the_links_the_graph_waits_for(monkeypatch, tmp_path):
    """As ``uav-landing graph --bag``: every node but the player with use_sim_time (the player
    publishing /clock), and the same ready topics (a bag without ground truth: not that link)."""
    bag = _bag_of(tmp_path / "recorded", {"/camera/image_raw": "sensor_msgs/msg/Image", "/camera/camera_info": "sensor_msgs/msg/CameraInfo"})
    config = Path(__file__).parents[2] / "config"
    params = _launch_nodes(monkeypatch, str(bag), str(config))
    assert set(params) == set(GRAPH_NODES)
    assert params[PLAYER]["clock"] is True and "use_sim_time" not in params[PLAYER]
    assert all(params[name]["use_sim_time"] is True for name in GRAPH_NODES if name != PLAYER)
    args = types.SimpleNamespace(nodes=None, bag=bag, param=[], drain=2.0, stop_timeout=10.0, config=config)
    graph_topics = yaml.safe_load(dict(_plan(args)[1][PLAYER])["ready_topics"])
    assert params[PLAYER]["ready_topics"] == graph_topics == [t for t in PIPELINE_TOPICS if t != "/uav/ground_truth"]
    graph_player = dict(_plan(args)[1][PLAYER])  # both pace on the tracker's status
    assert params[PLAYER]["ack_topic"] == graph_player["ack_topic"] == "uav/tracker_status"
    assert params[PLAYER]["ack_type"] == graph_player["ack_type"] == "uav_landing_msgs/msg/TrackerStatus"
    live = _launch_nodes(monkeypatch, "", str(config))  # the live camera: wall time, no player
    assert set(live) == set(GRAPH_NODES) - {PLAYER} and not any(live.values())


def test_launch_replays_compressed_frames_as_the_graph_does(monkeypatch, tmp_path):
    """A recording of image_transport's compressed frames: undistort decodes them and the player
    paces on them and waits for their link, with the same parameters ``uav-landing graph`` gives."""
    bag = _bag_of(tmp_path / "compressed", {"/camera/image_raw/compressed": "sensor_msgs/msg/CompressedImage", "/camera/camera_info": "sensor_msgs/msg/CameraInfo"})
    config = Path(__file__).parents[2] / "config"
    params = _launch_nodes(monkeypatch, str(bag), str(config))
    assert params["undistort"]["image_transport"] == "compressed" and "image_transport" not in params["detector"]
    assert params[PLAYER]["pace_topic"] == "/camera/image_raw/compressed"
    plan = _plan(types.SimpleNamespace(nodes=None, bag=bag, param=[], drain=2.0, stop_timeout=10.0, config=config))[1]
    assert dict(plan["undistort"])["image_transport"] == "compressed"
    assert dict(plan[PLAYER])["pace_topic"] == params[PLAYER]["pace_topic"]
    assert params[PLAYER]["ready_topics"] == yaml.safe_load(dict(plan[PLAYER])["ready_topics"])
    assert params[PLAYER]["ready_topics"][0] == "/camera/image_raw/compressed"
    assert "/camera/image_raw" not in params[PLAYER]["ready_topics"]


def test_launch_remaps_topics_in_every_node_as_the_graph_does(monkeypatch, tmp_path):
    """A camera driver, or a recording, of other topic names: ``remap:=`` reaches every node, and a
    replay's player waits for the remapped recorded links as ``uav-landing graph --remap`` does."""
    import pytest
    bag = _bag_of(tmp_path / "deck_cam", {"/deck_cam/image_raw": "sensor_msgs/msg/Image", "/deck_cam/camera_info": "sensor_msgs/msg/CameraInfo"})
    config = str(Path(__file__).parents[2] / "config")
    rule = "/deck_cam/image_raw:=/camera/image_raw,/deck_cam/camera_info:=/camera/camera_info"
    remappings = _launch_nodes(monkeypatch, str(bag), config, rule, remappings=True)
    expected = [("/deck_cam/image_raw", "/camera/image_raw"), ("/deck_cam/camera_info", "/camera/camera_info")]
    assert set(remappings) == set(GRAPH_NODES) and all(r == expected for r in remappings.values())
    ready = _launch_nodes(monkeypatch, str(bag), config, rule)[PLAYER]["ready_topics"]
    assert ready == [t for t in PIPELINE_TOPICS if t != "/uav/ground_truth"]  # without the remap, the camera links are left out
    assert "/camera/image_raw" not in _launch_nodes(monkeypatch, str(bag), config)[PLAYER]["ready_topics"]
    assert all(r == [] for r in _launch_nodes(monkeypatch, "", config, remappings=True).values())
    with pytest.raises(ValueError, match="expected FROM:=TO"):
        _launch_nodes(monkeypatch, "", config, "/deck_cam/image_raw")


def test_setup_installs_the_launch_file_parameter_files_models_and_shaders(tmp_path):
    """What a plain (non-symlink) ``colcon build`` installs: setup.py's build_py and install_data,
    run from the package folder as colcon does."""
    subprocess.run([sys.executable, "setup.py", "-q", "build_py", "-d", str(tmp_path / "lib"),
                    "install_data", "-d", str(tmp_path / "data")],
                   cwd=PACKAGE_DIR, check=True, capture_output=True)
    share = tmp_path / "data" / "share" / "uav_landing_vision"
    assert (share / "launch" / "landing_vision.launch.py").is_file()
    installed = {p.name for p in (share / "config").glob("*.yaml")}
    assert {f"{name}.yaml" for name in GRAPH_NODES} | {"camera.yaml"} <= installed
    assert {p.name for p in (PACKAGE_DIR / "models").iterdir()} <= {p.name for p in (share / "models").iterdir()}
    shaders = {p.name for p in (PACKAGE_DIR / "uav_landing_vision" / "render" / "shaders").iterdir()}
    assert shaders and shaders == {p.name for p in (tmp_path / "lib" / "uav_landing_vision" / "render" / "shaders").iterdir()}


def test_compose_replay_runs_every_node_but_the_player_on_the_bags_clock():
    """As the launch file's ``bag:=``: the documented replay sets ``USE_SIM_TIME=true``, which every
    node service but the player passes as ``use_sim_time`` (on the wall clock the GCS bridge
    finds every replayed pose stale); the live graph keeps the wall clock."""
    docker = PACKAGE_DIR.parents[1] / "docker"
    services = yaml.safe_load((docker / "compose.yaml").read_text())["services"]
    assert set(services) == set(GRAPH_NODES)
    option = "-p use_sim_time:=${USE_SIM_TIME:-false}"
    assert [n for n, s in services.items() if (option in s["command"]) != (n != PLAYER)] == []
    assert "clock" not in services[PLAYER]["command"]  # the player publishes /clock (bag_player.yaml)
    # Paced as the graph and the launch file pace it: on the tracker's status (it paced on undistort's output).
    assert all(f"-p {key}:={value}" in services[PLAYER]["command"] for key, value in TRACKER_ACK)
    replay = [line for line in (docker / "README.md").read_text().splitlines() if "--profile replay up" in line]
    assert replay and all("USE_SIM_TIME=true " in line for line in replay)


def test_the_replay_shuts_the_graph_down_the_graphs_drain_time_after_the_player_exits(monkeypatch, tmp_path):
    bag = _bag_of(tmp_path / "bag", {"/camera/image_raw": "sensor_msgs/msg/Image", "/camera/camera_info": "sensor_msgs/msg/CameraInfo"})
    actions = _launch_actions(monkeypatch, str(bag), CONFIG)
    (player,) = [a for a in actions if type(a).__name__ == "Node" and a.kwargs["name"] == PLAYER]
    (handler,) = [a for a in actions if type(a).__name__ == "RegisterEventHandler"]
    on_exit = handler.args[0]
    assert on_exit.kwargs["target_action"] is player
    (timer,) = on_exit.kwargs["on_exit"]
    parser = argparse.ArgumentParser()
    graph_module.register(parser.add_subparsers())
    assert timer.kwargs["period"] == parser.parse_args(["graph"]).drain == 2.0
    (emit,) = timer.kwargs["actions"]
    assert type(emit.kwargs["event"]).__name__ == "Shutdown"
    live = _launch_actions(monkeypatch, "", CONFIG)
    assert not [a for a in live if type(a).__name__ == "RegisterEventHandler"]
    assert {a.kwargs["name"] for a in live} == set(GRAPH_NODES) - {PLAYER}


def test_a_remapped_recording_of_compressed_frames_is_decoded_by_undistort(monkeypatch, tmp_path):
    bag = _bag_of(tmp_path / "deck", {"/deck_cam/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
                                     "/deck_cam/camera_info": "sensor_msgs/msg/CameraInfo"})
    rule = f"/deck_cam/image_raw/compressed:={COMPRESSED_FRAMES},/deck_cam/camera_info:=/camera/camera_info"
    params = _launch_nodes(monkeypatch, str(bag), CONFIG, rule)
    assert params["undistort"]["image_transport"] == "compressed"
    assert all("image_transport" not in params[n] for n in GRAPH_NODES if n != "undistort")
    assert params[PLAYER]["pace_topic"] == COMPRESSED_FRAMES and params[PLAYER]["ready_topics"][0] == COMPRESSED_FRAMES
