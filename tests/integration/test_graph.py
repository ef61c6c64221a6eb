"""``uav-landing graph``: bag_player + undistort as separate processes over DDS, and their shutdown."""

import os
import signal
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import Image
from test_node_common import SMALL_CAMERA, frame_entries, rgb_frame, ros, write_bag  # noqa: F401 (fixture)

from uav_landing_vision.graph import GRAPH_NODES, node_command
from uav_landing_vision.nodes.base import stamp_ns
from uav_landing_vision.nodes.image import image_to_numpy
from uav_landing_vision.nodes.qos import RELIABLE_QOS, IMAGE_QOS

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


def test_bag_replayed_through_undistort_in_separate_processes(ros, ros_domain_id, tmp_path):
    """Paced on the probe's acknowledgement: every frame reaches the probe, rectified, then the graph stops."""
    frames = 8
    bag = write_bag(tmp_path / "bag", frame_entries(SMALL_CAMERA, frames))
    rect = []
    sub = ros.probe.create_subscription(Image, "/camera/image_rect", rect.append, IMAGE_QOS)
    acked = []
    log = tmp_path / "graph.log"
    graph = _graph(
        ros_domain_id, "--bag", str(bag), "--nodes", "undistort,bag_player",
        "--param", "bag_player:ack_topic=/test/ack", "--param", "bag_player:ack_type=geometry_msgs/msg/PoseStamped",
        log=log,
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
        np.testing.assert_array_equal(image_to_numpy(msg), cv2.remap(rgb_frame(SMALL_CAMERA, i), *maps, cv2.INTER_LINEAR))
    assert "[bag_player]" in output and "[undistort]" in output and "bag played; stopping the graph" in output
    assert f"acknowledged {frames}, ack timeouts 0, dropped 0" in output
    assert "all nodes stopped cleanly" in output


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
    for args, message in [
        (["--nodes", "localiser"], "unknown node(s) ['localiser']"),
        (["--bag", str(tmp_path / "missing")], "does not exist"),
        (["--param", "undistort=linear"], "expected NODE:KEY=VALUE"),
    ]:
        log = tmp_path / "graph.log"
        assert _finish(_graph(ros_domain_id, *args, log=log)) == 2
        assert message in log.read_text()


def test_every_graph_node_has_a_module_and_a_parameter_file():
    for name in GRAPH_NODES:
        cmd = node_command(name, REPO / "config")
        assert cmd[1:3] == ["-m", f"uav_landing_vision.nodes.{name}"]
        assert Path(cmd[-1]).is_file(), cmd[-1]
        assert (REPO / "src" / "uav_landing_vision" / "uav_landing_vision" / "nodes" / f"{name}.py").is_file()
