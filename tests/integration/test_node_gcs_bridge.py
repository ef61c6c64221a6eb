"""``gcs_bridge`` in-process over DDS: pose → landing guidance and MAVLink; bad input dropped. And its
callbacks called directly: what it hands the core of a ``uav/pose`` and the stamp of the guidance it publishes."""

import math
import os
import signal
import socket
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np
import pytest
import yaml
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseWithCovarianceStamped
from pymavlink.dialects.v20 import common as mav2
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from scipy.spatial.transform import Rotation
from std_srvs.srv import Trigger
from test_node_common import ros  # noqa: F401 (fixture)

from uav_landing_msgs.msg import LandingGuidance, TrackerStatus
from uav_landing_vision.config import ConfigError
from uav_landing_vision.gcs.mavlink import open_link
from uav_landing_vision.nodes.gcs_bridge import GcsBridgeNode
from uav_landing_vision.nodes.qos import RELIABLE_QOS

PARAMS = Path(__file__).parents[2] / "config" / "gcs_bridge.yaml"
# libfaketime (Debian's libfaketime, in `make apt`): a process's system clock, set from a file
FAKETIME_LIBS = sorted(Path("/usr/lib").glob("*/faketime/libfaketimeMT.so.1"))
NS = 1_000_000_000


@pytest.fixture
def mavlink_receiver():
    conn = open_link("udpin:127.0.0.1:0", 255, 190)
    yield conn
    conn.close()


class Rig:
    def __init__(self, ros, port: int | str, *overrides):
        """``port``: the UDP port of a receiver, or a whole connection string."""
        self.ros = ros
        connection = port if isinstance(port, str) else f"udpout:127.0.0.1:{port}"
        self.node = ros.add(GcsBridgeNode(
            context=ros.context, cli_args=["--ros-args", "--params-file", str(PARAMS)],
            parameter_overrides=[Parameter("mavlink.connection", value=connection), *overrides],
        ))
        self.pose_pub = ros.probe.create_publisher(PoseWithCovarianceStamped, "uav/pose", RELIABLE_QOS)
        self.status_pub = ros.probe.create_publisher(TrackerStatus, "uav/tracker_status", RELIABLE_QOS)
        self.guidance = ros.collect(LandingGuidance, "uav/landing_guidance", RELIABLE_QOS)
        assert ros.spin_until(
            lambda: self.pose_pub.get_subscription_count() and self.status_pub.get_subscription_count() and self.guidance
        ), "discovery"

    def send_status(self, state: int):
        before = self.node.counters["status_received"]
        self.status_pub.publish(TrackerStatus(state=state))
        assert self.ros.spin_until(lambda: self.node.counters["status_received"] > before)

    def send_tracked(self) -> bool:
        """Publish a fresh pose and its frame's TRACKING status; whether guidance has a range yet."""
        msg = self.pose()
        self.pose_pub.publish(msg)
        self.status_pub.publish(TrackerStatus(header=msg.header, state=TrackerStatus.TRACKING))
        return any(math.isfinite(g.range) for g in self.guidance)

    def pose(self, x=0.5, y=-2.0, z=30.0, quat=(0.0, 0.0, 0.0, 1.0), frame_id="camera_optical_frame"):
        """A pose stamped now, covariance 0.01 I."""
        return pose_msg(self.ros.probe.get_clock().now().nanoseconds, [x, y, z], quat, np.eye(6) * 0.01, frame_id)


def pose_msg(stamp_ns: int, position, quat, covariance, frame_id="camera_optical_frame") -> PoseWithCovarianceStamped:
    msg = PoseWithCovarianceStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, NS)
    msg.header.frame_id = frame_id
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    p.x, p.y, p.z = (float(v) for v in position)
    q.x, q.y, q.z, q.w = (float(v) for v in quat)
    msg.pose.covariance = [float(v) for v in np.ravel(covariance)]
    return msg


def shipped_params() -> dict:
    return yaml.safe_load(PARAMS.read_text())["gcs_bridge"]["ros__parameters"]


def landing_position(p_cam) -> np.ndarray:
    """Oracle (scipy, the parameter file's numbers): the landing-frame position of a camera-frame point.

    Optical axes in the mount frame: z forward → x, x right → y, y down → z; the mount turned by
    its Z-Y-X roll, pitch, yaw in the ship frame; the landing frame is the ship frame moved to the net.
    """
    params = shipped_params()
    roll, pitch, yaw = np.radians(params["camera"]["rpy_deg"])
    mount = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
    optical_in_mount = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    return (mount @ optical_in_mount @ np.asarray(p_cam, float) + np.asarray(params["camera"]["position_m"])
            - np.asarray(params["net_position_m"]))


def test_a_tracked_pose_gives_guidance_and_mavlink(ros, mavlink_receiver):
    rig = Rig(ros, mavlink_receiver.port.getsockname()[1])
    rig.send_status(TrackerStatus.TRACKING)
    sent_stamps = []

    def tracked():  # a fresh pose per step: the bridge ignores poses older than stale_timeout_s
        msg = rig.pose()
        sent_stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
        rig.pose_pub.publish(msg)
        rig.status_pub.publish(TrackerStatus(header=msg.header, state=TrackerStatus.TRACKING))  # as the tracker does
        return any(math.isfinite(g.range) for g in rig.guidance)

    assert ros.spin_until(tracked)
    g = next(g for g in rig.guidance if math.isfinite(g.range))
    assert g.header.frame_id == "landing" and g.stage == LandingGuidance.APPROACH
    stamp = g.header.stamp.sec * 1_000_000_000 + g.header.stamp.nanosec
    assert stamp in sent_stamps, (stamp, sent_stamps)  # the image time of a pose sent, to the ns, not the tick's
    cone = shipped_params()["cone"]
    assert cone["approach_course_deg"] == 0.0  # from astern: the landing axis is −x, starboard +y, down +z
    x, y, z = landing_position([0.5, -2.0, 30.0])  # rig.pose()'s position
    glide_slope = math.radians(cone["glide_slope_deg"])
    assert g.range == pytest.approx(math.sqrt(x * x + y * y + z * z), abs=1e-9)  # 25.17 m
    assert g.glide_slope_angle == pytest.approx(math.atan2(-z, math.hypot(x, y)), abs=1e-9)  # 8.1° above the net
    assert g.glide_slope_error == pytest.approx(math.atan2(-z, math.hypot(x, y)) - glide_slope, abs=1e-9)
    assert g.lateral_angle == pytest.approx(math.atan2(y, -x), abs=1e-9)  # 1.1° to port
    assert g.inside_cone
    odometry = None
    for _ in range(100):
        odometry = mavlink_receiver.recv_match(type="ODOMETRY", blocking=True, timeout=0.1)
        if odometry is not None:
            break
    assert odometry is not None
    assert [odometry.x, odometry.y, odometry.z] == pytest.approx([x, y, z], abs=1e-5)  # float32 on the wire
    assert rig.node.counters["dropped"] == 0


def test_a_pose_is_vouched_for_only_by_a_tracking_status_of_its_own_frame(ros, mavlink_receiver):
    """A frame's pose and status travel apart: a TRACKING status stamped with an earlier frame
    or an ACQUIRING status of the pose's frame sends nothing to the GCS, however many fresh poses
    come; a TRACKING status of the pose's frame does."""
    rig = Rig(ros, mavlink_receiver.port.getsockname()[1])

    def received():
        return rig.node.counters["received"], rig.node.counters["status_received"]

    def poses_with(state: int, lag_ns: int, count: int = 10) -> None:
        for _ in range(count):
            msg = rig.pose()
            status = TrackerStatus(state=state)  # a header of its own: the pose's must not change
            status.header.stamp.sec, status.header.stamp.nanosec = divmod(
                msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec - lag_ns, 1_000_000_000)
            before, seen = received(), len(rig.guidance)
            rig.pose_pub.publish(msg)
            rig.status_pub.publish(status)
            assert ros.spin_until(lambda: all(n > b for n, b in zip(received(), before)) and len(rig.guidance) > seen)
        assert rig.node.counters["stale_poses"] == 0  # every pose was fresh and taken, to wait for its status

    poses_with(TrackerStatus.TRACKING, lag_ns=5_000_000_000)  # before every pose sent, whatever the order of arrival
    poses_with(TrackerStatus.ACQUIRING, lag_ns=0)
    assert all(math.isnan(g.range) for g in rig.guidance) and rig.guidance[-1].stage == LandingGuidance.LOITER
    assert mavlink_receiver.recv_match(type="ODOMETRY", blocking=True, timeout=0.3) is None
    assert rig.node.counters["dropped"] == 0

    def tracked():
        poses_with(TrackerStatus.TRACKING, lag_ns=0, count=1)
        return any(math.isfinite(g.range) for g in rig.guidance)

    assert ros.spin_until(tracked)


def test_the_reset_service_returns_the_stage_machine_to_loiter(ros, mavlink_receiver):
    rig = Rig(ros, mavlink_receiver.port.getsockname()[1])
    client = ros.probe.create_client(Trigger, "/gcs_bridge/reset")
    assert ros.spin_until(client.service_is_ready), "service discovery"

    def tracked():
        msg = rig.pose()
        rig.pose_pub.publish(msg)
        rig.status_pub.publish(TrackerStatus(header=msg.header, state=TrackerStatus.TRACKING))
        return any(g.stage == LandingGuidance.APPROACH for g in rig.guidance)

    assert ros.spin_until(tracked)
    future = client.call_async(Trigger.Request())
    assert ros.spin_until(future.done)
    assert future.result().success and future.result().message == "stage APPROACH -> LOITER"
    texts = []
    for _ in range(100):
        text = mavlink_receiver.recv_match(type="STATUSTEXT", blocking=True, timeout=0.1)
        if text is not None:
            texts.append(text.text)
        if texts and "reset" in texts[-1]:
            break
    assert texts[-1] == "VISION LOITER (operator reset from APPROACH)", texts
    future = client.call_async(Trigger.Request())  # already in LOITER once the poses stop: nothing to announce
    assert ros.spin_until(future.done) and future.result().success


def test_without_inputs_guidance_says_loiter_with_no_track(ros, mavlink_receiver):
    rig = Rig(ros, mavlink_receiver.port.getsockname()[1])
    g = rig.guidance[-1]
    assert g.stage == LandingGuidance.LOITER and math.isnan(g.range) and not g.inside_cone


def test_malformed_poses_and_states_are_dropped(ros, mavlink_receiver):
    rig = Rig(ros, mavlink_receiver.port.getsockname()[1])
    rig.send_status(7)
    assert rig.node.counters["dropped"] == 1 and "unknown tracker state 7" in rig.node.last_error
    rig.send_status(TrackerStatus.TRACKING)
    for bad, reason in [
        (rig.pose(x=float("nan")), "pose position must be 3 finite numbers"),
        (rig.pose(quat=(0.0, 0.0, 0.0, 0.0)), "pose quaternion must be a finite unit"),
        (rig.pose(quat=(float("nan"), 0.0, 0.0, 1.0)), "pose quaternion must be a finite unit"),
        (rig.pose(frame_id="mast_camera_optical_frame"), "in frame 'mast_camera_optical_frame', but the camera mount"),
        (rig.pose(frame_id=""), "in frame '', but the camera mount"),
    ]:
        before = rig.node.counters["dropped"]
        rig.pose_pub.publish(bad)
        assert ros.spin_until(lambda: rig.node.counters["dropped"] > before)
        assert reason in rig.node.last_error
    seen = len(rig.guidance)
    assert ros.spin_until(lambda: len(rig.guidance) > seen + 2)  # still ticking
    assert all(math.isnan(g.range) for g in rig.guidance) and rig.guidance[-1].stage == LandingGuidance.LOITER


def test_a_pose_mavlink_cannot_carry_is_dropped_and_the_node_goes_on(ros, mavlink_receiver):
    """Every landing-frame coordinate within float32 but the distance beyond it (3.4e38 m on each
    axis): the pose was taken, and the next tick raised OverflowError packing LANDING_TARGET's
    distance out of the timer, which ended the node."""
    rig = Rig(ros, mavlink_receiver.port.getsockname()[1], Parameter("mavlink.messages", value=["LANDING_TARGET"]))
    origin = landing_position(np.zeros(3))
    to_landing = np.column_stack([landing_position(e) - origin for e in np.eye(3)])  # a rotation
    x, y, z = to_landing.T @ (np.full(3, 3.4e38) - origin)
    huge = rig.pose(x=x, y=y, z=z)
    rig.pose_pub.publish(huge)
    rig.status_pub.publish(TrackerStatus(header=huge.header, state=TrackerStatus.TRACKING))
    assert ros.spin_until(lambda: rig.node.counters["dropped"] == 1)
    assert "exceeds MAVLink's float32 range" in rig.node.last_error

    assert ros.spin_until(rig.send_tracked)
    target = mavlink_receiver.recv_match(type="LANDING_TARGET", blocking=True, timeout=5.0)
    assert target is not None and target.distance == pytest.approx(math.dist(landing_position([0.5, -2.0, 30.0]), (0, 0, 0)), rel=1e-6)


def test_poses_are_refused_while_a_second_tracker_publishes(ros, mavlink_receiver):
    """Two trackers on the graph (a second graph on the domain, a bag replayed with its recorded
    uav/pose): the bridge cannot tell whose status vouches for which pose, and would guide on
    both estimates in turn. It sends nothing until one publisher of each is left."""
    rig = Rig(ros, mavlink_receiver.port.getsockname()[1])
    other = ros.probe.create_publisher(PoseWithCovarianceStamped, "uav/pose", RELIABLE_QOS)
    assert ros.spin_until(lambda: rig.node.count_publishers("uav/pose") == 2), "discovery"

    def both_publish():
        for pub, x in ((rig.pose_pub, 0.5), (other, 3.0)):
            msg = rig.pose(x=x)
            pub.publish(msg)
            rig.status_pub.publish(TrackerStatus(header=msg.header, state=TrackerStatus.TRACKING))
        return rig.node.counters["dropped"] >= 20

    assert ros.spin_until(both_publish)
    assert "2 publishers of uav/pose" in rig.node.last_error
    assert all(math.isnan(g.range) for g in rig.guidance) and rig.guidance[-1].stage == LandingGuidance.LOITER
    assert mavlink_receiver.recv_match(type="ODOMETRY", blocking=True, timeout=0.3) is None
    ros.probe.destroy_publisher(other)  # one tracker left: its tracked poses are taken again

    assert ros.spin_until(rig.send_tracked)


def test_the_node_rides_out_a_gcs_link_that_is_down(ros):
    """A TCP GCS not up yet (or gone): the node starts, keeps ticking, reports the link on
    /diagnostics (WARN, the error, the frames not sent) and sends as soon as the GCS listens.
    It refused to start before."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    reports = ros.collect(DiagnosticArray, "/diagnostics", RELIABLE_QOS)
    rig = Rig(ros, f"tcp:127.0.0.1:{port}")

    def own():
        return [s for r in reports for s in r.status if s.name == "/gcs_bridge"]

    def values(status):
        return {v.key: v.value for v in status.values}

    assert ros.spin_until(lambda: any(s.level == DiagnosticStatus.WARN for s in own()))
    warn = next(s for s in own() if s.level == DiagnosticStatus.WARN)
    assert "not sent to 'tcp:127.0.0.1:" in warn.message and "refused" in warn.message
    assert int(values(warn)["mavlink_dropped"]) > 0 and values(warn)["mavlink_up"] == "0"
    seen = len(rig.guidance)
    assert ros.spin_until(lambda: len(rig.guidance) > seen + 5)  # still ticking

    with socket.create_server(("127.0.0.1", port)) as listener:
        listener.setblocking(False)
        conn, data = None, b""

        def heartbeat_heard():
            nonlocal conn, data
            try:
                if conn is None:
                    conn, _ = listener.accept()
                    conn.setblocking(False)
                data += conn.recv(1 << 16)
            except BlockingIOError:
                pass
            return any(m.get_type() == "HEARTBEAT" for m in mav_parse(data))

        assert ros.spin_until(heartbeat_heard)
        reports.clear()
        assert ros.spin_until(lambda: own() and values(own()[-1])["mavlink_up"] == "1")
        assert int(values(own()[-1])["mavlink_restored"]) == 1
        conn.close()


def test_with_use_sim_time_the_ticks_follow_the_clock_topic(ros, mavlink_receiver):
    """A replay (``use_sim_time``): no tick while /clock stands still, and the ticks' guidance is
    stamped with sim time, 0.1 s apart at 10 Hz, as the clock is stepped."""
    node = ros.add(GcsBridgeNode(
        context=ros.context, cli_args=["--ros-args", "--params-file", str(PARAMS)],
        parameter_overrides=[Parameter("mavlink.connection", value=f"udpout:127.0.0.1:{mavlink_receiver.port.getsockname()[1]}"),
                             Parameter("use_sim_time", value=True)],
    ))
    guidance = ros.collect(LandingGuidance, "uav/landing_guidance", RELIABLE_QOS)
    clock = ros.probe.create_publisher(Clock, "/clock", RELIABLE_QOS)
    assert ros.spin_until(lambda: clock.get_subscription_count() and node.count_subscribers("uav/landing_guidance") >= 1)
    ros.spin_until(lambda: False, timeout=0.5)
    assert guidance == []  # sim time has not started
    for k in range(1, 31):
        clock.publish(Clock(clock=Time(sec=100 + k // 10, nanosec=(k % 10) * 100_000_000)))  # 100.1 ... 103.0 s
        ros.spin_until(lambda: False, timeout=0.02)
    assert ros.spin_until(lambda: any(g.header.stamp.sec == 103 for g in guidance))
    stamps = [g.header.stamp.sec + g.header.stamp.nanosec * 1e-9 for g in guidance]
    assert 100.0 <= min(stamps) and max(stamps) <= 103.0 + 1e-9
    assert len(stamps) >= 20 and np.diff(stamps) == pytest.approx(0.1, abs=1e-6)


def test_the_ticks_go_on_when_the_system_clock_steps_back(ros_domain_id, ros, mavlink_receiver, tmp_path):
    """NTP or GPS time stepping the ship PC's clock back an hour, with the node running (its
    process on a clock set by libfaketime; the monotonic clock untouched): guidance goes on at
    the tick rate, stamped on the new time-line, and the GCS hears the heartbeat again at once.
    With its ticks timed by the system clock, the node fell silent for the hour. The clock is set
    right again before the node is stopped: stopped an hour back, it crashed in the teardown of
    Fast DDS's shared-memory transport (SIGSEGV) in 8 of 16 stops under load, set right in none
    of 16 (docs/gcs.md)."""
    assert FAKETIME_LIBS, "libfaketime is not installed (make apt)"
    offset = tmp_path / "clock_offset"
    offset.write_text("+0\n")
    port = mavlink_receiver.port.getsockname()[1]
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain_id), LD_PRELOAD=str(FAKETIME_LIBS[0]),
               FAKETIME_TIMESTAMP_FILE=str(offset), FAKETIME_NO_CACHE="1", FAKETIME_DONT_FAKE_MONOTONIC="1")
    guidance = ros.collect(LandingGuidance, "uav/landing_guidance", RELIABLE_QOS)
    node = subprocess.Popen(
        [sys.executable, "-m", "uav_landing_vision.nodes.gcs_bridge", "--ros-args", "--params-file", str(PARAMS),
         "-p", f"mavlink.connection:=udpout:127.0.0.1:{port}"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert ros.spin_until(lambda: len(guidance) >= 3), "no guidance before the step"
        while mavlink_receiver.recv_match(blocking=False) is not None:  # the heartbeats so far
            pass
        last_before = max(g.header.stamp.sec for g in guidance)
        offset.write_text("-3600\n")

        def after():
            return [g for g in guidance if g.header.stamp.sec < last_before - 3000]

        assert ros.spin_until(lambda: len(after()) >= 10), "the ticks stopped when the clock stepped back"
        heard = []
        while (msg := mavlink_receiver.recv_match(blocking=False)) is not None:
            heard.append(msg.get_type())
        assert "HEARTBEAT" in heard
        assert all(g.stage == LandingGuidance.LOITER for g in after())
        offset.write_text("+0\n")  # set right before the stop (see the docstring)
        seen = len(guidance)
        assert ros.spin_until(lambda: any(g.header.stamp.sec >= last_before for g in guidance[seen:]))
    finally:
        node.send_signal(signal.SIGINT)
        output, _ = node.communicate(timeout=30)
    assert node.returncode == 0, output


def mav_parse(data: bytes) -> list:
    parser = mav2.MAVLink(None)
    parser.robust_parsing = True
    return parser.parse_buffer(data) or []


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({}, "missing 6 required positional arguments: 'camera'"),
        ({"cli_args": ["--ros-args", "--params-file", str(PARAMS)], "parameter_overrides": [Parameter("mavlink.rate_hz", value="fast")]}, "mavlink.rate_hz: expected a number"),
        ({"cli_args": ["--ros-args", "--params-file", str(PARAMS)], "parameter_overrides": [Parameter("cone.colour", value=1)]}, r"cone: unknown key\(s\) \['colour'\]"),
        ({"cli_args": ["--ros-args", "--params-file", str(PARAMS)], "parameter_overrides": [Parameter("mavlink.connection", value="tcp:127.0.0.1")]}, "mavlink.connection: cannot open 'tcp:127.0.0.1'"),
        # Reported as the link's failure before.
        ({"cli_args": ["--ros-args", "--params-file", str(PARAMS)], "parameter_overrides": [Parameter("mavlink.signing_key_file", value="/nonexistent/key")]}, "mavlink.signing_key_file: .*No such file"),
    ],
)
def test_bad_parameters_fail_start_up(ros, kwargs, message):
    with pytest.raises(ConfigError, match=message):
        GcsBridgeNode(context=ros.context, **kwargs)


def test_a_signing_timestamp_file_out_of_reach_fails_start_up(ros, tmp_path):
    key = tmp_path / "signing.key"
    key.write_text("ab" * 32)
    overrides = [Parameter("mavlink.signing_key_file", value=str(key)),
                 Parameter("mavlink.signing_timestamp_file", value=str(tmp_path / "missing" / "t"))]
    with pytest.raises(ConfigError, match=r"mavlink.signing_timestamp_file: .*signing timestamp file .*/missing/t: cannot write it"):
        GcsBridgeNode(context=ros.context, cli_args=["--ros-args", "--params-file", str(PARAMS)],
                      parameter_overrides=overrides)


# Callbacks called directly (no DDS traffic).


@pytest.fixture
def node(ros):
    """The bridge, its guidance collected in ``node.published`` instead of published."""
    made = ros.add(GcsBridgeNode(context=ros.context, cli_args=["--ros-args", "--params-file", str(PARAMS)],
                                 parameter_overrides=[Parameter("mavlink.connection", value="udpout:127.0.0.1:9")]))
    made.published = []
    made._guidance = types.SimpleNamespace(publish=made.published.append)
    return made


def _awkward_stamp(node) -> int:
    """A stamp near the node's clock whose float seconds differ between sec + nanosec·1e-9 and
    ns·1e-9 (about half of all stamps do): a key computed one way is not found the other way."""
    ns = node.get_clock().now().nanoseconds
    while True:
        sec, nanosec = divmod(ns, NS)
        if ns * 1e-9 != sec + nanosec * 1e-9:
            return ns
        ns += 7919


def _spd(rng) -> np.ndarray:
    a = rng.normal(size=(6, 6))
    return a @ a.T * 1e-3 + np.diag([0.01, 0.02, 0.03, 0.004, 0.005, 0.006])


def test_the_core_gets_position_xyz_quaternion_xyzw_and_the_covariance_as_sent(node, monkeypatch):
    rng = np.random.default_rng(11)
    calls = []
    real = node._bridge.on_pose

    def recording(*args):
        calls.append(args)
        return real(*args)

    monkeypatch.setattr(node._bridge, "on_pose", recording)
    rotation = Rotation.from_euler("ZYX", [35.0, -12.0, 7.0], degrees=True)
    cov = _spd(rng)
    stamp = _awkward_stamp(node)
    node._on_pose(pose_msg(stamp, [0.5, -2.0, 30.0], rotation.as_quat(), cov))  # scipy: scalar last
    assert node.counters["dropped"] == 0, node.last_error
    (stamp_s, position, quat, covariance, _now), = calls
    assert stamp_s == stamp * 1e-9
    assert tuple(position) == (0.5, -2.0, 30.0)
    np.testing.assert_allclose(Rotation.from_quat(quat).as_matrix(), rotation.as_matrix(), atol=1e-12)
    np.testing.assert_array_equal(np.asarray(covariance, float).reshape(6, 6), cov)  # row-major, as sent


def test_guidance_of_a_tracked_pose_carries_that_poses_header_stamp_to_the_nanosecond(node):
    cov = np.diag([0.01, 0.01, 0.01, 0.001, 0.001, 0.001])
    for _ in range(20):  # more poses than the node keeps stamps of (16), each stamp of the awkward kind
        stamp = _awkward_stamp(node)
        msg = pose_msg(stamp, [0.5, -2.0, 30.0], [0.0, 0.0, 0.0, 1.0], cov)
        node._on_pose(msg)
        node._on_status(TrackerStatus(header=msg.header, state=TrackerStatus.TRACKING))
        node._tick()
        g = node.published[-1]
        assert np.isfinite(g.range), node.last_error
        assert (g.header.stamp.sec, g.header.stamp.nanosec) == divmod(stamp, NS)
        assert g.header.frame_id == "landing"
    assert node.counters["dropped"] == 0


def test_a_status_stamped_a_fraction_of_a_second_after_the_pose_vouches_for_it_and_one_before_does_not(node):
    cov = np.diag([0.01, 0.01, 0.01, 0.001, 0.001, 0.001])
    stamp = node.get_clock().now().nanoseconds - 50_000_000  # fresh: 50 ms ago
    if stamp % NS < 20_000_000:
        stamp -= 30_000_000  # the status below, 10 ms before, is then in the same second
    msg = pose_msg(stamp, [0.5, -2.0, 30.0], [0.0, 0.0, 0.0, 1.0], cov)
    node._on_pose(msg)
    before = TrackerStatus(state=TrackerStatus.TRACKING)
    before.header.stamp.sec, before.header.stamp.nanosec = divmod(stamp - 10_000_000, NS)  # 10 ms earlier, same second
    node._on_status(before)
    node._tick()
    assert np.isnan(node.published[-1].range)  # not vouched for: the status is of an earlier frame
    node._on_status(TrackerStatus(header=msg.header, state=TrackerStatus.TRACKING))
    node._tick()
    assert np.isfinite(node.published[-1].range)


def test_a_pose_in_another_frame_than_the_camera_mounts_is_dropped_before_the_core(node, monkeypatch):
    monkeypatch.setattr(node._bridge, "on_pose", lambda *a: pytest.fail("handed to the core"))
    stamp = node.get_clock().now().nanoseconds
    node._on_pose(pose_msg(stamp, [0.5, -2.0, 30.0], [0.0, 0.0, 0.0, 1.0], np.eye(6) * 0.01, frame_id="map"))
    assert node.counters["dropped"] == 1 and "in frame 'map'" in node.last_error


def test_a_stale_pose_is_counted_as_stale_not_dropped(node):
    stamp = node.get_clock().now().nanoseconds - 2 * NS  # older than stale_timeout_s (0.3 s)
    node._on_pose(pose_msg(stamp, [0.5, -2.0, 30.0], [0.0, 0.0, 0.0, 1.0], np.eye(6) * 0.01))
    assert node.counters["stale_poses"] == 1 and node.counters["dropped"] == 0
    assert node._pose_stamps == {}


def test_frames_the_link_could_not_send_are_counted_once_each(node):
    node._bridge.close()
    stats = types.SimpleNamespace(dropped=3, written=10, failures=1, restored=0, up=False, last_error="refused")
    node._bridge = types.SimpleNamespace(link_stats=stats, signing_store_error="", close=lambda: None)
    node._report_link()
    assert node.counters["dropped"] == 3 and node.counters["mavlink_dropped"] == 3
    node._report_link()  # nothing more lost
    assert node.counters["dropped"] == 3
    stats.dropped = 5
    node._report_link()
    assert node.counters["dropped"] == 5 and "2 MAVLink frame(s) not sent" in node.last_error


def test_a_status_is_refused_while_a_second_tracker_publishes_statuses(ros, node):
    """A status of another tracker could vouch for this tracker's pose of the same stamp."""
    for _ in range(2):
        ros.probe.create_publisher(TrackerStatus, "uav/tracker_status", 10)
    deadline = time.monotonic() + 30.0
    while node.count_publishers("uav/tracker_status") < 2 and time.monotonic() < deadline:
        time.sleep(0.05)  # not spinning: the node's ticks must not count drops of their own
    assert node.count_publishers("uav/tracker_status") == 2, "graph discovery"
    calls = []
    node._bridge.on_tracker_state = lambda *args: calls.append(args)
    node._on_status(TrackerStatus(state=TrackerStatus.TRACKING))
    assert calls == [] and node.counters["dropped"] == 1
    assert "2 publishers of uav/tracker_status" in node.last_error
