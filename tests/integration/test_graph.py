"""``uav-landing graph``: bag_player + undistort as separate processes over DDS, and their shutdown; its
plan (node commands, remaps, frame transport, ready topics) and the launcher's drain, signals and exit."""

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import rclpy
import yaml
import rclpy.node
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import CompressionMode, Writer
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import CompressedImage, Image
from test_node_common import SMALL_CAMERA, frame_entries, rgb_frame, ros, write_bag  # noqa: F401 (fixture)

from uav_landing_msgs.msg import TrackerStatus
from uav_landing_vision.gcs.mavlink import open_link
from uav_landing_vision import graph as graph_module
from uav_landing_vision.graph import (COMPRESSED_FRAMES, GRAPH_NODES, PIPELINE_TOPICS, PLAYER, TRACKER_ACK, Graph,
                                      _plan, domain_id, frame_overrides, node_command, node_environment, parse_remaps,
                                      replay_overrides, replay_ready_topics)
from uav_landing_vision.nodes.image import image_to_numpy
from uav_landing_vision.nodes.qos import RELIABLE_QOS, IMAGE_QOS
from uav_landing_vision.resources import config_path
from uav_landing_vision.stamps import stamp_ns

REPO = Path(__file__).parents[2]
PROCESS_TIMEOUT_S = 120.0


def _graph(ros_domain_id, *args, log: Path) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO / "src" / "uav_landing_vision"), os.environ.get("PYTHONPATH", "")]))
    cmd = [sys.executable, "-m", "uav_landing_vision.cli", "graph", "--config", str(REPO / "config"), "--domain-id", str(ros_domain_id), *args]
    return subprocess.Popen(cmd, env=env, cwd=REPO, stdout=log.open("w"), stderr=subprocess.STDOUT)


def _finish(proc: subprocess.Popen) -> int:
    try:
        return proc.wait(timeout=PROCESS_TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()


DECK_CAM = {"/camera/image_raw": "/deck_cam/image_raw", "/camera/camera_info": "/deck_cam/camera_info"}


def _compressed(entries):
    """The entries with each frame as image_transport's compressed plugin records it: PNG of its
    BGR pixels on /camera/image_raw/compressed."""
    out = []
    for topic, type_name, t, msg in entries:
        if type_name == "sensor_msgs/msg/Image":
            ok, png = cv2.imencode(".png", image_to_numpy(msg)[..., ::-1])
            assert ok
            topic, type_name, msg = f"{topic}/compressed", "sensor_msgs/msg/CompressedImage", CompressedImage(
                header=msg.header, format="rgb8; png compressed bgr8", data=png.tobytes())
        out.append((topic, type_name, t, msg))
    return out


@pytest.mark.parametrize("recording", ["camera", "deck_cam-remapped", "compressed"])
def test_bag_replayed_through_undistort_in_separate_processes(ros, ros_domain_id, tmp_path, recording):
    """Paced on the probe's acknowledgement: every frame reaches the probe, rectified, then the
    graph stops. Also a recording of other topic names, remapped onto the graph's, and one of
    compressed frames, which the graph has undistort decode and the player pace on."""
    frames = 8
    remap, compressed = recording == "deck_cam-remapped", recording == "compressed"
    entries = frame_entries(SMALL_CAMERA, frames)
    if remap:
        entries = [(DECK_CAM[topic], *rest) for topic, *rest in entries]
    if compressed:
        entries = _compressed(entries)
    bag = write_bag(tmp_path / "bag", entries)
    remaps = [a for ours, recorded in DECK_CAM.items() for a in ("--remap", f"{recorded}:={ours}")] if remap else []
    rect = []
    sub = ros.probe.create_subscription(Image, "/camera/image_rect", rect.append, IMAGE_QOS)
    acked = []
    log = tmp_path / "graph.log"
    graph = _graph(
        ros_domain_id, "--bag", str(bag), "--nodes", "undistort,bag_player",
        "--param", "bag_player:ack_topic=/test/ack", "--param", "bag_player:ack_type=geometry_msgs/msg/PoseStamped",
        *remaps, log=log,
    )
    try:
        # The ack publisher appears only once undistort's output reaches the probe: the player,
        # which waits for a publisher of its ack topic, cannot start before that link is up.
        assert ros.spin_until(lambda: sub.get_publisher_count() >= 1 or graph.poll() is not None, PROCESS_TIMEOUT_S)
        ack_pub = ros.probe.create_publisher(PoseStamped, "/test/ack", RELIABLE_QOS)

        def step():
            for msg in rect[len(acked):]:
                ack_pub.publish(PoseStamped(header=msg.header))
                acked.append(msg)
            return graph.poll() is not None

        assert ros.spin_until(step, PROCESS_TIMEOUT_S)
    finally:
        code = _finish(graph)
    output = log.read_text()
    assert code == 0, output
    assert [stamp_ns(m.header.stamp) for m in rect] == [1_000_000_000 + i * 33_000_000 for i in range(frames)], output
    maps = SMALL_CAMERA.undistortion_maps()
    for i, msg in enumerate(rect):
        pixels = rgb_frame(SMALL_CAMERA, i)[..., ::-1] if compressed else rgb_frame(SMALL_CAMERA, i)
        assert msg.encoding == ("bgr8" if compressed else "rgb8")
        np.testing.assert_array_equal(image_to_numpy(msg), cv2.remap(pixels, *maps, cv2.INTER_LINEAR))
    assert ("the bag's frames are compressed" in output) == compressed
    assert "[bag_player]" in output and "[undistort]" in output and "bag played; stopping the graph" in output
    assert f"acknowledged {frames}, ack timeouts 0, dropped 0" in output
    assert "all nodes stopped cleanly" in output


def _tracked_poses_bag(path: Path, frames: int) -> Path:
    """A recording of the tracker's output: a TRACKING status and a pose 30 -> 12 m out per frame,
    stamped (and recorded) at the bag's time, 34 ms apart."""
    typestore = get_typestore(Stores.ROS2_JAZZY)
    with Writer(path, version=9) as writer:
        status_conn = writer.add_connection("/uav/tracker_status", "uav_landing_msgs/msg/TrackerStatus",
                                            msgdef="uint8 state\n", rihs01="RIHS01_" + "0" * 64)  # played by the installed type
        pose_conn = writer.add_connection("/uav/pose", "geometry_msgs/msg/PoseWithCovarianceStamped", typestore=typestore)
        for i in range(frames):
            t = 1_700_000_000_000_000_000 + i * 34_000_000
            status = TrackerStatus(state=TrackerStatus.TRACKING)
            pose = PoseWithCovarianceStamped()
            for header in (status.header, pose.header):
                header.stamp.sec, header.stamp.nanosec = divmod(t, 1_000_000_000)
            pose.header.frame_id = "camera_optical_frame"
            pose.pose.pose.position.x, pose.pose.pose.position.y, pose.pose.pose.position.z = 0.5, -2.0, 30.0 - 0.2 * i
            pose.pose.pose.orientation.w = 1.0
            pose.pose.covariance = [0.01 if k % 7 == 0 else 0.0 for k in range(36)]
            writer.write(status_conn, t, serialize_message(status))
            writer.write(pose_conn, t, serialize_message(pose))
    return path


def test_a_replay_runs_the_nodes_on_the_bags_clock(ros_domain_id, tmp_path):
    """Replayed poses carry the bag's stamps (here 2023): on the wall clock the GCS bridge found
    every one stale and sent none. With --bag every node takes the player's /clock."""
    frames = 90
    receiver = open_link("udpin:127.0.0.1:0", 255, 190)
    log = tmp_path / "graph.log"
    try:
        graph = _graph(
            ros_domain_id, "--bag", str(_tracked_poses_bag(tmp_path / "bag", frames)), "--nodes", "gcs_bridge,bag_player",
            "--param", "bag_player:mode=timed", "--param", "bag_player:ready_topics=[/uav/pose,/uav/tracker_status]",
            "--param", f"gcs_bridge:mavlink.connection=udpout:127.0.0.1:{receiver.port.getsockname()[1]}", log=log,
        )
        sent = []
        deadline = time.monotonic() + PROCESS_TIMEOUT_S
        while graph.poll() is None and time.monotonic() < deadline:
            msg = receiver.recv_match(blocking=True, timeout=0.1)
            if msg is not None:
                sent.append(msg.get_type())
        code = _finish(graph)
    finally:
        receiver.close()
    output = log.read_text()
    assert code == 0, output
    # One ODOMETRY per pose taken, at most 10 a second of bag time (3 s of poses): ~30.
    assert sent.count("ODOMETRY") >= 20, (sent, output)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGHUP], ids=["ctrl_c", "hangup"])
def test_ctrl_c_or_a_hangup_stops_every_node_cleanly(ros, ros_domain_id, tmp_path, sig):
    log = tmp_path / "graph.log"
    graph = _graph(ros_domain_id, "--nodes", "undistort", log=log)
    try:
        assert ros.spin_until(lambda: ros.probe.count_publishers("/camera/image_rect") >= 1 or graph.poll() is not None, PROCESS_TIMEOUT_S)
        assert graph.poll() is None, log.read_text()
        graph.send_signal(sig)
    finally:
        code = _finish(graph)
    output = log.read_text()
    assert code == 0, output
    assert "stop requested" in output and "all nodes stopped cleanly" in output
    assert ros.spin_until(lambda: ros.probe.count_publishers("/camera/image_rect") == 0)


def test_a_node_that_fails_stops_the_graph_with_an_error(ros_domain_id, tmp_path):
    log = tmp_path / "graph.log"
    code = _finish(_graph(ros_domain_id, "--nodes", "undistort,gcs_bridge", "--param", "undistort:interpolation=bogus", log=log))
    output = log.read_text()
    assert code == 1, output
    assert "[undistort] [FATAL] cannot start" in output and "interpolation: 'bogus' is not one of" in output
    assert "undistort exited with code 2" in output and "failed: undistort" in output


def test_bad_requests_are_refused_before_anything_starts(ros_domain_id, tmp_path):
    cut_off = write_bag(tmp_path / "cut_off", frame_entries(SMALL_CAMERA, 2), compression=CompressionMode.FILE)
    packed = next(cut_off.glob("*.zstd"))
    packed.write_bytes(packed.read_bytes()[: packed.stat().st_size // 2])
    for args, message in [
        (["--bag", str(cut_off)], f"bag {cut_off} is not a readable rosbag2 bag: "),
        (["--nodes", "localiser"], "unknown node(s) ['localiser']"),
        (["--bag", str(tmp_path / "missing")], "does not exist"),
        (["--param", "undistort=linear"], "expected NODE:KEY=VALUE"),
        (["--remap", "/deck_cam/image_raw"], "expected FROM:=TO"),
        (["--remap", "deck_cam/image_raw:=/camera/image_raw"], "absolute topic names"),
    ]:
        log = tmp_path / "graph.log"
        assert _finish(_graph(ros_domain_id, *args, log=log)) == 2
        assert message in log.read_text()


def test_a_replay_waits_for_the_links_its_bag_can_bring_up(tmp_path):
    """Every pipeline link of a bag with ground truth; less it without; all of them (for the
    player to report) for a bag that cannot be read, e.g. a compressed one cut off."""
    truth = PoseStamped()
    truth.header.stamp.sec = 1
    full = write_bag(tmp_path / "full", frame_entries(SMALL_CAMERA, 1) + [("/uav/ground_truth", "geometry_msgs/msg/PoseStamped", 10**9, truth)])
    assert graph_module.replay_ready_topics(full) == graph_module.PIPELINE_TOPICS
    packed_frames = write_bag(tmp_path / "packed_frames", _compressed(frame_entries(SMALL_CAMERA, 1)))
    assert graph_module.replay_ready_topics(packed_frames) == ("/camera/image_raw/compressed", *(
        t for t in graph_module.PIPELINE_TOPICS if t not in ("/camera/image_raw", "/uav/ground_truth")))
    assert graph_module.frame_overrides(packed_frames) == {
        "undistort": [("image_transport", "compressed")], "bag_player": [("pace_topic", "/camera/image_raw/compressed")]}
    assert graph_module.frame_overrides(full) == {}
    untrue = write_bag(tmp_path / "untrue", frame_entries(SMALL_CAMERA, 1), compression=CompressionMode.FILE)
    untrue_links = tuple(t for t in graph_module.PIPELINE_TOPICS if t != "/uav/ground_truth")
    assert graph_module.replay_ready_topics(untrue) == untrue_links
    packed = next(untrue.glob("*.zstd"))
    packed.write_bytes(packed.read_bytes()[: packed.stat().st_size // 2])
    assert graph_module.replay_ready_topics(untrue) == graph_module.PIPELINE_TOPICS
    deck_cam = write_bag(tmp_path / "deck_cam", [(DECK_CAM[topic], *rest) for topic, *rest in frame_entries(SMALL_CAMERA, 1)])
    links = tuple(t for t in graph_module.PIPELINE_TOPICS if t not in DECK_CAM and t != "/uav/ground_truth")
    assert graph_module.replay_ready_topics(deck_cam) == links
    for remaps in ({v: k for k, v in DECK_CAM.items()}, DECK_CAM):  # played onto the graph's topics, or the graph onto the bag's
        assert graph_module.replay_ready_topics(deck_cam, remaps) == untrue_links


def test_the_launch_files_python_without_rosbags_still_reads_a_bag_folders_topics(tmp_path, monkeypatch, capsys):
    """`ros2 launch` runs in the system's Python; with the package's requirements in a virtual
    environment, reading the bag raised ModuleNotFoundError and the replay launch died."""
    packed_frames = write_bag(tmp_path / "packed_frames", _compressed(frame_entries(SMALL_CAMERA, 1)))
    expected = (graph_module.replay_ready_topics(packed_frames), graph_module.frame_overrides(packed_frames))
    for name in [m for m in sys.modules if m == "rosbags" or m.startswith(("rosbags.", "uav_landing_vision.sim"))]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "rosbags", None)  # import rosbags now raises ImportError
    assert (graph_module.replay_ready_topics(packed_frames), graph_module.frame_overrides(packed_frames)) == expected
    single = next(packed_frames.glob("*.mcap"))  # a bare file has no metadata.yaml: the raw-frame defaults, said
    assert graph_module.replay_ready_topics(single) == graph_module.PIPELINE_TOPICS
    assert "cannot read the topics of" in capsys.readouterr().err


def test_a_string_parameter_outside_the_basic_plane_reaches_rcl_as_written(tmp_path, ros_domain_id):
    """json.dumps's ASCII escapes (a surrogate pair for an emoji) made rcl refuse the override and
    every node fail to start."""
    value = str(tmp_path / "landing 😀 #1: deck \x85\x7f\u2028")  # NEL, DEL and U+2028: YAML line breaks or refused
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=ros_domain_id, args=["--ros-args", "-p", f"path:={graph_module.string_parameter(value)}"])
    try:
        node = rclpy.node.Node("quoted", context=context, automatically_declare_parameters_from_overrides=True)
        assert node.get_parameter("path").value == value
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_every_graph_node_has_a_module_and_a_parameter_file():
    for name in GRAPH_NODES:
        cmd = node_command(name, REPO / "config")
        assert cmd[1:3] == ["-m", f"uav_landing_vision.nodes.{name}"]
        assert Path(cmd[-1]).is_file(), cmd[-1]
        assert (REPO / "src" / "uav_landing_vision" / "uav_landing_vision" / "nodes" / f"{name}.py").is_file()


def _fake_nodes(monkeypatch, scripts: dict) -> None:
    """Each graph node replaced by ``python -c <its script>`` (no ROS)."""
    monkeypatch.setattr(graph_module, "node_command", lambda name, *args: [sys.executable, "-c", scripts[name]])


@pytest.mark.parametrize("code, expected", [(0, 0), (3, 1)], ids=["clean", "error"])
def test_a_node_that_exits_on_its_own_stops_the_graph_failing_only_on_an_error(monkeypatch, capsys, tmp_path, code, expected):
    """E.g. an evaluator done after ``frames``: the others get SIGINT; exit code 0 is no failure."""
    _fake_nodes(monkeypatch, {"undistort": "import time; time.sleep(60)", "evaluator": f"import time; time.sleep(0.5); raise SystemExit({code})"})
    graph = graph_module.Graph(["undistort", "evaluator"], tmp_path, {"undistort": [], "evaluator": []}, dict(os.environ), stop_timeout=5.0)
    assert graph.run() == expected
    output = capsys.readouterr().out
    assert f"evaluator exited with code {code}; stopping the graph" in output
    assert graph.procs["undistort"].returncode == -signal.SIGINT and graph.procs["evaluator"].returncode == code
    assert ("all nodes stopped cleanly" in output) == (code == 0)
    assert (f"failed: evaluator (exit code {code})" in output) == (code != 0)


def test_the_nodes_are_stopped_one_at_a_time_the_last_started_first(monkeypatch, capsys, tmp_path):
    """All at once, a node's DDS teardown ran into the others': Fast DDS hung in one (loaded e2e runs)."""
    def slow_to_stop(name):
        return ("import signal, sys, time\n"
                "def stop(*_):\n"
                f"    print('stopping {name}', flush=True); time.sleep(0.3); print('stopped {name}', flush=True); sys.exit(0)\n"
                "signal.signal(signal.SIGINT, stop)\n"
                f"open({str(tmp_path / name)!r}, 'w').close()\n"
                "time.sleep(60)")
    names = ["undistort", "pose_boosting", "evaluator"]
    ready = " and ".join(f"os.path.exists({str(tmp_path / n)!r})" for n in names)
    # the node that ends the graph exits once the others can be stopped
    ends = f"import os, time\nwhile not ({ready}):\n    time.sleep(0.05)"
    _fake_nodes(monkeypatch, {**{n: slow_to_stop(n) for n in names}, "detector": ends})
    graph = graph_module.Graph([*names, "detector"], tmp_path, {n: [] for n in [*names, "detector"]}, dict(os.environ), stop_timeout=5.0)
    assert graph.run() == 0
    lines = [line.split("] ", 1)[1] for line in capsys.readouterr().out.splitlines() if " stop" in line and line.startswith("[") and not line.startswith("[graph]")]
    assert lines == ["stopping evaluator", "stopped evaluator", "stopping pose_boosting", "stopped pose_boosting",
                     "stopping undistort", "stopped undistort"]


def test_a_node_that_ignores_sigint_and_sigterm_prints_where_it_hangs_before_sigkill(monkeypatch, capsys, tmp_path):
    """A node stuck in its shutdown (seen once: the GCS bridge of an e2e run) was killed without a
    trace of where it was."""
    hung = ("import faulthandler, signal, time\n"
            "faulthandler.register(signal.SIGUSR1, all_threads=True)\n"
            "signal.signal(signal.SIGINT, signal.SIG_IGN); signal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
            "def stuck_in_shutdown():\n    time.sleep(60)\n"
            "print('ready', flush=True); stuck_in_shutdown()")
    _fake_nodes(monkeypatch, {"gcs_bridge": hung, "evaluator": "import time; time.sleep(0.5)"})
    graph = graph_module.Graph(["gcs_bridge", "evaluator"], tmp_path, {"gcs_bridge": [], "evaluator": []}, dict(os.environ), stop_timeout=0.5)
    assert graph.run() == 1
    output = capsys.readouterr().out
    assert "gcs_bridge still running 0.5 s after the last signal; sending SIGKILL after SIGUSR1 (its threads' stacks)" in output
    assert "[gcs_bridge]" in output and "in stuck_in_shutdown" in output
    assert graph.procs["gcs_bridge"].returncode == -signal.SIGKILL


def test_a_node_prints_its_threads_stacks_on_sigusr1_and_runs_on(ros_domain_id, tmp_path):
    cmd = node_command("evaluator", REPO / "config", [("out_dir", str(tmp_path / "report"))])
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain_id))
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 30.0
        while not _catches(proc.pid, signal.SIGUSR1) and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.05)
        assert _catches(proc.pid, signal.SIGUSR1), "the node never set up its SIGUSR1 handler"
        proc.send_signal(signal.SIGUSR1)  # without the handler its default action ends the process
        with pytest.raises(subprocess.TimeoutExpired):
            proc.communicate(timeout=2.0)  # it runs on
    finally:
        proc.kill()
    output, _ = proc.communicate(timeout=30)
    # The main thread's stack, whichever thread took the signal: one of the middleware's threads
    # may (faulthandler then names none "Current thread", as in one loaded run).
    assert "(most recent call first)" in output and "uav_landing_vision/nodes/base.py" in output, output


def _catches(pid: int, sig: int) -> bool:
    """Whether process ``pid`` has a handler for ``sig`` (/proc/PID/status, SigCgt)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return False
    caught = int(next(line.split()[1] for line in status.splitlines() if line.startswith("SigCgt:")), 16)
    return bool(caught >> (sig - 1) & 1)


@pytest.mark.parametrize("path", ["/data/landings/run #3/bag", "/data/landing: day 2/bag", "/data/ünïcode 'quoted' \"bag\""])
def test_a_bag_path_reaches_the_player_whole(path):
    """rcl reads a ``-p key:=value`` override as YAML: a bare path was cut at " #" (the player then
    played another bag, if one was there) or refused at ": "."""
    (key, value), = [kv for kv in graph_module.replay_overrides(["bag_player"], path)["bag_player"] if kv[0] == "bag"]
    context = rclpy.Context()
    rclpy.init(args=["node", "--ros-args", "-p", f"{key}:={value}"], context=context)
    try:
        node = rclpy.node.Node("player", context=context, automatically_declare_parameters_from_overrides=True)
        assert node.get_parameter("bag").value == str(Path(path).resolve())
        node.destroy_node()
    finally:
        context.try_shutdown()


# --- the plan (what each node is started with, which start, the replay's links) and the launcher's end

CONFIG = config_path("tracker.yaml").parent
TYPES = {"/camera/image_raw": "sensor_msgs/msg/Image", "/camera/camera_info": "sensor_msgs/msg/CameraInfo",
         "/uav/ground_truth": "geometry_msgs/msg/PoseStamped", COMPRESSED_FRAMES: "sensor_msgs/msg/CompressedImage",
         "/deck_cam/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
         "/deck_cam/camera_info": "sensor_msgs/msg/CameraInfo"}


def bag_of(path: Path, topics) -> Path:
    """A bag recording ``topics`` (one message each; only the names matter to the plan)."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    with Writer(path, version=9) as writer:
        for topic in topics:
            writer.write(writer.add_connection(topic, TYPES[topic], typestore=typestore), 1, b"\x00\x01\x00\x00")
    return path


def plan(nodes=None, bag=None, params=(), drain=2.0, stop_timeout=10.0, config=CONFIG, remaps=None):
    args = argparse.Namespace(nodes=nodes, bag=bag, param=list(params), drain=drain, stop_timeout=stop_timeout, config=config)
    return _plan(args, remaps)


# --- command lines, environment, requests ---------------------------------------------------------


def test_a_node_command_passes_each_override_as_a_ros_parameter_and_each_remap_from_source_to_target():
    cmd = node_command("undistort", Path("/cfg"), [("interpolation", "linear"), ("use_sim_time", "true")],
                       {"/deck_cam/image_raw": "/camera/image_raw"})
    assert cmd[:3] == [sys.executable, "-m", "uav_landing_vision.nodes.undistort"]
    assert cmd[3:] == ["--ros-args", "--params-file", "/cfg/undistort.yaml", "-p", "interpolation:=linear",
                       "-p", "use_sim_time:=true", "-r", "/deck_cam/image_raw:=/camera/image_raw"]


def test_remap_rules_need_absolute_names_on_both_sides():
    assert parse_remaps(["/a:=/b", "/c:=/d"]) == {"/a": "/b", "/c": "/d"}
    for rule in ["/deck_cam/image_raw:=camera/image_raw", "deck_cam/image_raw:=/camera/image_raw"]:
        with pytest.raises(ValueError, match="absolute topic names"):
            parse_remaps([rule])


@pytest.mark.parametrize("text, value", [("0", 0), ("232", 232), ("95", 95)])
def test_every_domain_id_rcl_accepts_is_taken(text, value):
    assert domain_id(text) == value


def test_the_node_environment_sets_domain_zero_and_puts_this_package_first_on_the_path(monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    monkeypatch.setenv("PYTHONPATH", "/elsewhere")
    env = node_environment(0)
    assert env["ROS_DOMAIN_ID"] == "0"  # a domain asked for, even the default one, is set
    first = env["PYTHONPATH"].split(os.pathsep)[0]
    assert (Path(first) / "uav_landing_vision" / "graph.py").resolve() == Path(graph_module.__file__).resolve()
    assert env["PYTHONPATH"].split(os.pathsep)[1:] == ["/elsewhere"]
    assert node_environment()["ROS_DOMAIN_ID"] == "42" and node_environment()["PYTHONUNBUFFERED"] == "1"


def test_without_a_bag_the_player_is_not_started():
    names, overrides = plan()
    assert names == [n for n in GRAPH_NODES if n != PLAYER] and set(overrides) == set(names)
    assert all(items == [] for items in overrides.values())  # the live graph: wall clock, the files' parameters


def test_a_drain_of_zero_is_taken_and_a_stop_timeout_of_zero_refused():
    assert plan(nodes="undistort", drain=0.0)[0] == ["undistort"]
    with pytest.raises(ValueError, match="--stop-timeout > 0"):
        plan(nodes="undistort", stop_timeout=0.0)


def test_a_parameter_override_without_a_key_is_refused():
    with pytest.raises(ValueError, match="expected NODE:KEY=VALUE"):
        plan(nodes="undistort", params=["undistort:=linear"])
    with pytest.raises(ValueError, match="node 'tracker' is not in the graph"):
        plan(nodes="undistort", params=["tracker:particles=10"])


def test_a_missing_parameter_file_is_refused_before_anything_starts(tmp_path):
    (tmp_path / "undistort.yaml").write_text("undistort:\n  ros__parameters: {}\n")
    with pytest.raises(ValueError, match=r"missing parameter file\(s\): .*detector.yaml"):
        plan(nodes="undistort,detector", config=tmp_path)
    assert plan(nodes="undistort", config=tmp_path)[0] == ["undistort"]


# --- replay overrides -------------------------------------------------------------------------------


def test_a_replay_runs_every_node_but_the_player_on_the_bags_clock_and_paces_on_the_tracker_only_with_one():
    with_tracker = replay_overrides(["undistort", "tracker", PLAYER], "/bags/landing")
    assert with_tracker["undistort"] == [("use_sim_time", "true")] == with_tracker["tracker"]
    player = dict(with_tracker[PLAYER])
    assert player["clock"] == "true" and "use_sim_time" not in player
    assert yaml.safe_load(player["bag"]) == "/bags/landing"
    assert all(player[k] == v for k, v in TRACKER_ACK)
    without = dict(replay_overrides(["undistort", PLAYER], "/bags/landing")[PLAYER])
    assert "ack_topic" not in without and "ack_type" not in without and "ready_topics" not in without


def test_a_compressed_recording_of_other_names_remapped_onto_the_graphs_is_decoded_by_undistort(tmp_path):
    bag = bag_of(tmp_path / "deck", ["/deck_cam/image_raw/compressed", "/deck_cam/camera_info"])
    remaps = {"/deck_cam/image_raw/compressed": COMPRESSED_FRAMES, "/deck_cam/camera_info": "/camera/camera_info"}
    assert frame_overrides(bag, remaps) == {"undistort": [("image_transport", "compressed")],
                                            PLAYER: [("pace_topic", COMPRESSED_FRAMES)]}
    assert frame_overrides(bag) == {}  # not remapped: no frames the graph takes
    assert replay_ready_topics(bag, remaps)[0] == COMPRESSED_FRAMES
    names, overrides = plan(bag=bag, remaps=remaps)
    assert dict(overrides["undistort"])["image_transport"] == "compressed"
    assert dict(overrides[PLAYER])["pace_topic"] == COMPRESSED_FRAMES
    assert yaml.safe_load(dict(overrides[PLAYER])["ready_topics"]) == [
        COMPRESSED_FRAMES, *(t for t in PIPELINE_TOPICS if t not in ("/camera/image_raw", "/uav/ground_truth"))]


def test_a_compressed_replay_of_part_of_the_graph_waits_for_the_frames_and_camera_info_links(tmp_path):
    bag = bag_of(tmp_path / "packed", [COMPRESSED_FRAMES, "/camera/camera_info"])
    player = dict(plan(nodes="undistort,bag_player", bag=bag)[1][PLAYER])
    assert yaml.safe_load(player["ready_topics"]) == [COMPRESSED_FRAMES, "/camera/camera_info"]
    assert player["pace_topic"] == COMPRESSED_FRAMES
    # The user's own ready topics are the only ones the player is given.
    told = plan(nodes="undistort,bag_player", bag=bag, params=["bag_player:ready_topics=[/camera/camera_info]"])[1][PLAYER]
    assert [v for k, v in told if k == "ready_topics"] == ["[/camera/camera_info]"]


def test_a_replay_waits_for_every_other_nodes_own_links_on_the_ready_topics(tmp_path):
    """The player sees only its own links; each other node started reports its own (``ready_nodes``)."""
    bag = bag_of(tmp_path / "full", list(graph_module.RECORDED_TOPICS))
    others = [n for n in GRAPH_NODES if n != PLAYER]
    assert yaml.safe_load(dict(replay_overrides(GRAPH_NODES, bag, PIPELINE_TOPICS)[PLAYER])["ready_nodes"]) == others
    assert yaml.safe_load(dict(plan(bag=bag)[1][PLAYER])["ready_nodes"]) == others
    told = dict(plan(bag=bag, params=["bag_player:ready_topics=[/uav/pose]"])[1][PLAYER])
    assert yaml.safe_load(told["ready_nodes"]) == others and told["ready_topics"] == "[/uav/pose]"
    part = dict(plan(nodes="undistort,detector,bag_player", bag=bag)[1][PLAYER])
    assert yaml.safe_load(part["ready_nodes"]) == ["undistort", "detector"]
    own = plan(bag=bag, params=["bag_player:ready_topics=[/uav/pose]", "bag_player:ready_nodes=[tracker]"])[1][PLAYER]
    assert [v for k, v in own if k == "ready_nodes"] == ["[tracker]"]


def test_a_compressed_replay_without_undistort_still_starts_the_others(tmp_path):
    """The frame overrides of a node not started are not given (there is no such node to give them to)."""
    bag = bag_of(tmp_path / "packed", [COMPRESSED_FRAMES, "/camera/camera_info"])
    names, overrides = plan(nodes="tracker,bag_player", bag=bag)
    assert names == ["tracker", PLAYER] and set(overrides) == {"tracker", PLAYER}
    assert dict(overrides[PLAYER])["pace_topic"] == COMPRESSED_FRAMES


# --- the launcher ------------------------------------------------------------------------------------


def _running(flag: Path) -> str:
    """A node that runs until it is stopped, ``flag`` made once it runs (its SIGINT handling set up)."""
    return f"import pathlib, time\npathlib.Path({str(flag)!r}).touch()\ntime.sleep(60)"


def _once_running(flag: Path, then: str) -> str:
    """A node that does ``then`` once the :func:`_running` node of ``flag`` runs."""
    return f"import os, time\nwhile not os.path.exists({str(flag)!r}):\n    time.sleep(0.02)\n{then}"


class RecordingEvent:
    """A stop-request event that records the seconds of every wait on it (and waits none)."""

    def __init__(self):
        self.waits, self._set = [], False

    def is_set(self):
        return self._set

    def set(self):
        self._set = True

    def wait(self, timeout=None):
        self.waits.append(timeout)
        return self._set


def _replay_drained_after(monkeypatch, tmp_path, player_then: str) -> Graph:
    """undistort and a player that does ``player_then`` once undistort runs, with a 3.25 s drain
    and a stop event that records its waits."""
    flag = tmp_path / "running"
    _fake_nodes(monkeypatch, {"undistort": _running(flag), PLAYER: _once_running(flag, player_then)})
    graph = Graph(["undistort", PLAYER], tmp_path, {"undistort": [], PLAYER: []}, dict(os.environ), stop_timeout=5.0,
                  drain_s=3.25)
    graph._stop_requested = RecordingEvent()
    return graph


def test_the_graph_waits_the_drain_time_after_the_bag_is_played(monkeypatch, capsys, tmp_path):
    graph = _replay_drained_after(monkeypatch, tmp_path, "pass")
    assert graph.run() == 0
    assert 3.25 in graph._stop_requested.waits
    assert "bag played; stopping the graph in 3.25 s" in capsys.readouterr().out


def test_a_player_that_fails_fails_the_graph_without_a_drain(monkeypatch, capsys, tmp_path):
    graph = _replay_drained_after(monkeypatch, tmp_path, "raise SystemExit(1)")
    assert graph.run() == 1
    output = capsys.readouterr().out
    assert "bag_player exited with code 1; stopping the graph" in output and "bag played" not in output
    assert 3.25 not in graph._stop_requested.waits


def test_the_graph_command_gives_the_launcher_its_drain_and_remaps(monkeypatch):
    from uav_landing_vision.cli import main

    made = {}

    class Recorder:
        def __init__(self, names, config_dir, overrides, env, stop_timeout, drain_s=2.0, remaps=None):
            made.update(names=names, stop_timeout=stop_timeout, drain_s=drain_s, remaps=remaps, env=env)

        def run(self):
            return 0

    monkeypatch.setattr(graph_module, "Graph", Recorder)
    assert main(["graph", "--nodes", "undistort", "--drain", "0.75", "--stop-timeout", "4", "--domain-id", "95",
                 "--remap", "/deck_cam/image_raw:=/camera/image_raw"]) == 0
    assert made["names"] == ["undistort"] and made["drain_s"] == 0.75 and made["stop_timeout"] == 4.0
    assert made["remaps"] == {"/deck_cam/image_raw": "/camera/image_raw"}
    assert made["env"]["ROS_DOMAIN_ID"] == "95"


def test_a_node_ending_with_the_shells_ctrl_c_status_ended_cleanly(monkeypatch, capsys, tmp_path):
    """128 + SIGINT: how a node run through a shell reports its Ctrl-C."""
    flag = tmp_path / "running"
    _fake_nodes(monkeypatch, {"undistort": _running(flag), "evaluator": _once_running(flag, "raise SystemExit(130)")})
    graph = Graph(["undistort", "evaluator"], tmp_path, {"undistort": [], "evaluator": []}, dict(os.environ), stop_timeout=5.0)
    assert graph.run() == 0
    assert "all nodes stopped cleanly" in capsys.readouterr().out


def test_a_sigterm_to_the_launcher_stops_the_graph_says_which_signal_and_restores_the_handlers(monkeypatch, capsys, tmp_path):
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    # The node asks its launcher to stop, then waits for its own SIGINT.
    script = "import os, signal, time; os.kill(os.getppid(), signal.SIGTERM); time.sleep(60)"
    _fake_nodes(monkeypatch, {"undistort": script})
    graph = Graph(["undistort"], tmp_path, {"undistort": []}, dict(os.environ), stop_timeout=5.0)
    assert graph.run() == 0
    assert graph.stopped_by_signal == signal.SIGTERM
    assert "stop requested; stopping the graph" in capsys.readouterr().out
    assert graph.procs["undistort"].returncode == -signal.SIGINT
    assert {s: signal.getsignal(s) for s in before} == before


def test_a_bag_with_raw_frames_is_played_raw_even_if_it_also_has_compressed_ones(tmp_path):
    bag = bag_of(tmp_path / "both", ["/camera/image_raw", COMPRESSED_FRAMES, "/camera/camera_info"])
    assert frame_overrides(bag) == {}
    assert COMPRESSED_FRAMES not in replay_ready_topics(bag) and "/camera/image_raw" in replay_ready_topics(bag)


def test_the_graph_remapped_onto_a_recordings_compressed_frames_decodes_them(tmp_path):
    """The other direction of remapping: the graph's names onto the recording's (-r /camera/...:=/deck_cam/...)."""
    bag = bag_of(tmp_path / "deck", ["/deck_cam/image_raw/compressed", "/deck_cam/camera_info"])
    remaps = {COMPRESSED_FRAMES: "/deck_cam/image_raw/compressed", "/camera/camera_info": "/deck_cam/camera_info"}
    assert frame_overrides(bag, remaps) == {"undistort": [("image_transport", "compressed")],
                                            PLAYER: [("pace_topic", COMPRESSED_FRAMES)]}
    assert replay_ready_topics(bag, remaps)[:2] == (COMPRESSED_FRAMES, "/camera/camera_info")
