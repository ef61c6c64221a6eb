"""MAVLink 2 output decoded by a pymavlink receiver on loopback UDP; signing with right and wrong keys.

MAVLink carries positions as float32: at 100 m one float32 step is 7.6e-6 m, so decoded values
are compared with the float64 truth within 1e-6 plus one float32 step of the value.
"""

import dataclasses
import math
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_gcs_landing import CONFIG, COV, on_axis
from test_gcs_frames import camera_pose_from_truth

from uav_landing_vision.gcs import GcsBridge
from uav_landing_vision.gcs.bridge import TRACKER_TRACKING
from uav_landing_vision.gcs.frames import DeckGeometry, camera_to_landing, euler_covariance
from uav_landing_vision.gcs.mavlink import covariance_upper_triangle, load_signing_key, open_link

KEY = bytes(range(32))
ALL_MESSAGES = ("ODOMETRY", "ATT_POS_MOCAP", "VISION_POSITION_ESTIMATE", "LANDING_TARGET")


def tol(value):
    return 1e-6 + float(np.spacing(np.float32(abs(value))))


def assert_f32(actual, expected):
    for a, e in zip(np.atleast_1d(actual), np.atleast_1d(expected)):
        assert abs(a - e) <= tol(e), (actual, expected)


@pytest.fixture
def receiver():
    conns = []

    def make(key=None):
        conn = open_link("udpin:127.0.0.1:0", 255, 190, key)
        conns.append(conn)
        return conn, conn.port.getsockname()[1]

    yield make
    for c in conns:
        c.close()


def collect(conn, until, timeout=3.0):
    """Messages by type until ``until(messages)`` holds or ``timeout`` s pass."""
    got: dict[str, list] = {}
    deadline = time.monotonic() + timeout
    while not until(got) and time.monotonic() < deadline:
        m = conn.recv_match(blocking=True, timeout=min(0.1, max(0.0, deadline - time.monotonic())))
        if m is not None:
            got.setdefault(m.get_type(), []).append(m)
    return got


def make_bridge(port, messages=ALL_MESSAGES, key_file="", frame="LOCAL_FRD"):
    mav = dataclasses.replace(
        CONFIG.mavlink, connection=f"udpout:127.0.0.1:{port}", messages=messages,
        signing_key_file=str(key_file), odometry_frame=frame, system_id=42, component_id=197,
    )
    return GcsBridge(dataclasses.replace(CONFIG, mavlink=mav))


def feed(bridge, t, p_land, rpy):
    cam = CONFIG.camera
    p_cam, q_cam = camera_pose_from_truth(cam.position_m, cam.rpy, CONFIG.net_position_m, p_land, rpy)
    bridge.on_tracker_state(TRACKER_TRACKING, t)
    assert bridge.on_pose(t, p_cam, q_cam, COV, now_s=t + 0.01)
    return p_cam, q_cam


# A scripted approach: (stamp, landing-frame position, FRD roll/pitch/yaw).
SCRIPT = [
    (100.0, on_axis(80.0, lateral_m=-3.0), (0.05, -0.10, 0.03)),
    (100.5, on_axis(45.0, lateral_m=1.5), (-0.08, -0.12, -0.02)),
    (101.0, on_axis(20.0), (0.02, -0.09, 0.01)),
    (101.5, on_axis(6.0), (0.0, -0.05, 0.0)),
]


def test_scripted_approach_decodes_to_the_truth(receiver):
    conn, port = receiver()
    bridge = make_bridge(port)
    cam_poses = {}
    for stamp, p, rpy in SCRIPT:
        cam_poses[stamp] = feed(bridge, stamp, p, rpy)
        bridge.tick(stamp + 0.02)
    n = len(SCRIPT)
    got = collect(conn, lambda g: all(len(g.get(name, [])) == n for name in ALL_MESSAGES) and "STATUSTEXT" in g)
    bridge.close()
    for name in ALL_MESSAGES:
        assert len(got.get(name, [])) == n, name

    for k, (stamp, p, rpy) in enumerate(SCRIPT):
        usec = int(round(stamp * 1e6))
        truth_q = Rotation.from_euler("ZYX", rpy[::-1]).as_quat()  # FRD body → landing frame, xyzw
        q_wxyz = np.array([truth_q[3], *truth_q[:3]])

        odo = got["ODOMETRY"][k]
        assert odo.time_usec == usec and odo.frame_id == 20 and odo.child_frame_id == 12  # LOCAL_FRD, BODY_FRD
        assert odo.estimator_type == 2  # MAV_ESTIMATOR_TYPE_VISION
        assert_f32([odo.x, odo.y, odo.z], p)
        assert_f32(np.array(odo.q) * np.sign(odo.q[0]), q_wxyz * np.sign(q_wxyz[0]))
        assert math.isnan(odo.vx) and math.isnan(odo.velocity_covariance[0])
        pose = camera_to_landing(*cam_poses[stamp], COV, DeckGeometry.from_mount(
            CONFIG.camera.position_m, CONFIG.camera.rpy, CONFIG.net_position_m))
        cov = euler_covariance(pose)
        assert_f32([odo.pose_covariance[i] for i in (0, 6, 11, 15, 18, 20)], np.diag(cov))
        assert_f32(odo.pose_covariance[1], cov[0, 1])

        mocap = got["ATT_POS_MOCAP"][k]
        assert mocap.time_usec == usec
        assert_f32([mocap.x, mocap.y, mocap.z], p)
        assert_f32(np.array(mocap.q) * np.sign(mocap.q[0]), q_wxyz * np.sign(q_wxyz[0]))

        vpe = got["VISION_POSITION_ESTIMATE"][k]
        assert vpe.usec == usec
        assert_f32([vpe.x, vpe.y, vpe.z, vpe.roll, vpe.pitch, vpe.yaw], [*p, *rpy])

        lt = got["LANDING_TARGET"][k]
        target = Rotation.from_quat(truth_q).as_matrix().T @ -p  # net in the UAV's FRD body frame
        assert lt.time_usec == usec and lt.frame == 12 and lt.position_valid == 1  # MAV_FRAME_BODY_FRD
        assert_f32([lt.x, lt.y, lt.z, lt.distance], [*target, np.linalg.norm(p)])
        assert lt.x > 0  # the net is ahead
        azimuth, depression = np.arctan2(target[1], target[0]), np.arctan2(target[2], np.hypot(*target[:2]))
        assert_f32([lt.angle_x, lt.angle_y], [azimuth, depression])
        q_body_l = np.array([truth_q[3], *-truth_q[:3]])  # the landing frame in the body frame
        assert_f32(np.array(lt.q) * np.sign(lt.q[0]), q_body_l * np.sign(q_body_l[0]))

    texts = [m.text for m in got["STATUSTEXT"]]
    assert texts[0].startswith("VISION APPROACH")
    hb = got["HEARTBEAT"][0]
    assert hb.get_srcSystem() == 42 and hb.get_srcComponent() == 197 and hb.type == 18  # ONBOARD_CONTROLLER
    assert hb.get_msgbuf()[0] == 0xFD  # MAVLink 2 framing
    assert not hb.get_signed()


def test_only_configured_messages_are_sent(receiver):
    conn, port = receiver()
    bridge = make_bridge(port, messages=("VISION_POSITION_ESTIMATE",), frame="LOCAL_NED")
    stamp, p, rpy = SCRIPT[1]
    feed(bridge, stamp, p, rpy)
    bridge.tick(stamp + 0.02)
    bridge.tick(stamp + 1.1)  # stale now: a second heartbeat, no second position
    got = collect(conn, lambda g: len(g.get("HEARTBEAT", [])) == 2)
    bridge.close()
    assert set(got) == {"HEARTBEAT", "STATUSTEXT", "VISION_POSITION_ESTIMATE"}
    assert len(got["VISION_POSITION_ESTIMATE"]) == 1


def test_covariance_triangle_layout():
    cov = np.arange(36, dtype=float).reshape(6, 6)
    tri = covariance_upper_triangle(cov)
    assert len(tri) == 21 and tri[:6] == list(cov[0]) and tri[6:11] == list(cov[1, 1:]) and tri[20] == cov[5, 5]


@pytest.fixture
def key_file(tmp_path):
    path = tmp_path / "signing.key"
    path.write_text(KEY.hex() + "\n")
    return path


def test_signed_stream_accepted_with_the_right_key(receiver, key_file):
    conn, port = receiver(KEY)
    bridge = make_bridge(port, messages=("ODOMETRY",), key_file=key_file)
    feed(bridge, *SCRIPT[0])
    bridge.tick(SCRIPT[0][0] + 0.02)
    got = collect(conn, lambda g: "ODOMETRY" in g)
    bridge.close()
    assert got["ODOMETRY"][0].get_signed()
    assert conn.mav.signing.goodsig_count >= 2 and conn.mav.signing.badsig_count == 0


def test_signed_stream_rejected_with_a_wrong_key(receiver, key_file):
    conn, port = receiver(bytes(32))
    bridge = make_bridge(port, messages=("ODOMETRY",), key_file=key_file)
    feed(bridge, *SCRIPT[0])
    bridge.tick(SCRIPT[0][0] + 0.02)  # HEARTBEAT, STATUSTEXT, ODOMETRY: three frames
    got = collect(conn, lambda g: len(g.get("BAD_DATA", [])) >= 3)
    bridge.close()
    assert "ODOMETRY" not in got and "HEARTBEAT" not in got
    assert all("signature" in m.reason for m in got["BAD_DATA"])
    assert conn.mav.signing.sig_count == conn.mav.signing.badsig_count == 3  # signed, and rejected


@pytest.mark.parametrize("text", ["00ff", "zz" * 32, KEY.hex() + "00"])
def test_bad_key_files(tmp_path, text):
    path = tmp_path / "k"
    path.write_text(text)
    with pytest.raises(ValueError, match="64 hexadecimal"):
        load_signing_key(path)


@pytest.mark.parametrize("frame, frame_id", [("LOCAL_FRD", 20), ("LOCAL_NED", 1), ("MOCAP_NED", 14)])
def test_odometry_carries_the_configured_frame_and_the_stamp_to_the_microsecond(frame, frame_id):
    """MAV_FRAME ids from MAVLink's common.xml; 1.001 s is not exact in binary (cut, not rounded, it is 1000999 µs)."""
    from pymavlink.dialects.v20 import common as mav2

    from uav_landing_vision.gcs.frames import LandingPose
    from uav_landing_vision.gcs.mavlink import encode_pose

    mav = mav2.MAVLink(None, srcSystem=1, srcComponent=197)
    pose = LandingPose(np.array([-30.0, 1.0, -3.0]), np.array([0.0, 0.0, 0.0, 1.0]), np.eye(6) * 1e-3)
    (msg,) = encode_pose(mav, ("ODOMETRY",), pose, 1.001, frame)
    assert msg.frame_id == frame_id and msg.time_usec == 1_001_000
