"""MAVLink 2 output decoded by a pymavlink receiver on loopback UDP; signing with right and wrong keys.

MAVLink carries positions as float32: at 100 m one float32 step is 7.6e-6 m, so decoded values
are compared with the float64 truth within 1e-6 plus one float32 step of the value.
"""

import dataclasses
import errno
import hashlib
import math
import socket
import struct
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mav2
from scipy.spatial.transform import Rotation
from test_gcs_landing import CONFIG, COV, on_axis
from test_gcs_frames import camera_pose_from_truth
from test_gcs_link import free_port, parse
from test_gcs_signing import UNIX_2015

from uav_landing_vision.gcs import GcsBridge
from uav_landing_vision.gcs.bridge import TRACKER_TRACKING
from uav_landing_vision.gcs.frames import DeckGeometry, LandingPose, camera_to_landing, euler_covariance
from uav_landing_vision.gcs.mavlink import (
    MavlinkSender, covariance_upper_triangle, encode_pose, encoder, load_signing_key, open_link,
)

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


def mavlink_config(port, **changes):
    """The station's MAVLink settings, sending to a receiver on ``port``."""
    return dataclasses.replace(
        CONFIG.mavlink, connection=f"udpout:127.0.0.1:{port}", system_id=42, component_id=197, **changes
    )


def make_bridge(port, messages=ALL_MESSAGES, key_file="", frame="LOCAL_FRD"):
    mav = mavlink_config(port, messages=messages, signing_key_file=str(key_file), odometry_frame=frame)
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
    assert hb.get_srcSystem() == 42 and hb.get_srcComponent() == 197
    assert (hb.type, hb.autopilot) == (18, 8)  # ONBOARD_CONTROLLER, AUTOPILOT_INVALID: not a vehicle to a GCS
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


def rpy_covariance_by_finite_differences(quat_xyzw, cov6):
    """Oracle (scipy's Z-Y-X angles): Σ of (x, y, z, roll, pitch, yaw) for a rotation error about the parent's axes."""
    base = Rotation.from_quat(quat_xyzw)
    h = 1e-6
    jac = np.eye(6)
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        plus = (Rotation.from_rotvec(d) * base).as_euler("ZYX")[::-1]
        minus = (Rotation.from_rotvec(-d) * base).as_euler("ZYX")[::-1]
        jac[3:, 3 + k] = (plus - minus) / (2 * h)
    return jac @ cov6 @ jac.T


def test_every_position_message_carries_all_21_covariance_entries():
    """ODOMETRY.pose_covariance, ATT_POS_MOCAP.covariance and VISION_POSITION_ESTIMATE.covariance:
    (x, y, z, roll, pitch, yaw), the first row, then the second from its diagonal, and so on."""
    rng = np.random.default_rng(20240611)
    for _ in range(5):
        a = rng.normal(size=(6, 6)) * np.array([0.3, 0.3, 1.0, 0.02, 0.02, 0.02])
        cov = a @ a.T + np.diag([0.01, 0.02, 0.03, 1e-4, 2e-4, 3e-4])
        rpy = rng.uniform([-0.6, -0.8, -np.pi], [0.6, 0.8, np.pi])
        quat = Rotation.from_euler("ZYX", rpy[::-1]).as_quat()
        mav = mav2.MAVLink(None, srcSystem=1, srcComponent=197)
        msgs = encode_pose(mav, ALL_MESSAGES, LandingPose(rng.normal(0.0, 30.0, 3), quat, cov), 12.5, "LOCAL_FRD")
        by_type = {m.get_type(): m for m in parse(b"".join(msg.pack(mav) for msg in msgs))}
        sigma = rpy_covariance_by_finite_differences(quat, cov)
        expected = [sigma[i, j] for i in range(6) for j in range(i, 6)]
        for name, field in (("ODOMETRY", "pose_covariance"), ("ATT_POS_MOCAP", "covariance"),
                            ("VISION_POSITION_ESTIMATE", "covariance")):
            got = np.array(getattr(by_type[name], field), dtype=float)
            np.testing.assert_allclose(got, expected, rtol=2e-5, atol=1e-9, err_msg=name)


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


def signature_block(frame: bytes):
    """(link id, timestamp) of a signed MAVLink 2 frame, and whether its 6-byte signature is
    SHA-256(key + everything before the signature) for ``KEY``."""
    assert frame[0] == 0xFD and frame[2] & 0x01  # MAVLink 2, MAVLINK_IFLAG_SIGNED
    low, high = struct.unpack("<IH", frame[-12:-6])  # 48-bit little-endian
    return frame[-13], low + (high << 32), hashlib.sha256(KEY + frame[:-6]).digest()[:6] == frame[-6:]


def test_signed_frames_carry_the_configured_link_id_and_the_clock_stamp(receiver, key_file):
    """The signature block checked by hand: 10 µs units since 2015-01-01 UTC, one more per frame."""
    conn, port = receiver(KEY)
    now = float(int(time.time()))  # a whole second: its stamp is exact
    sender = MavlinkSender(mavlink_config(port, signing_key_file=str(key_file), signing_link_id=7), clock=lambda: now)
    sender.send_heartbeat()
    sender.send_heartbeat()
    got = collect(conn, lambda g: len(g.get("HEARTBEAT", [])) == 2)
    sender.close()
    stamp = round((now - UNIX_2015) * 100_000)
    assert [signature_block(m.get_msgbuf()) for m in got["HEARTBEAT"]] == [(7, stamp, True), (7, stamp + 1, True)]
    assert conn.mav.signing.goodsig_count == 2 and conn.mav.signing.badsig_count == 0


@pytest.mark.parametrize("text", ["00ff", "zz" * 32, KEY.hex() + "00"])
def test_bad_key_files(tmp_path, text):
    path = tmp_path / "k"
    path.write_text(text)
    with pytest.raises(ValueError, match="64 hexadecimal"):
        load_signing_key(path)


@pytest.mark.parametrize("frame, frame_id", [("LOCAL_FRD", 20), ("LOCAL_NED", 1), ("MOCAP_NED", 14)])
def test_odometry_carries_the_configured_frame_and_the_stamp_to_the_microsecond(frame, frame_id):
    """MAV_FRAME ids from MAVLink's common.xml; 1.001 s is not exact in binary (cut, not rounded, it is 1000999 µs)."""
    mav = mav2.MAVLink(None, srcSystem=1, srcComponent=197)
    pose = LandingPose(np.array([-30.0, 1.0, -3.0]), np.array([0.0, 0.0, 0.0, 1.0]), np.eye(6) * 1e-3)
    (msg,) = encode_pose(mav, ("ODOMETRY",), pose, 1.001, frame)
    assert msg.frame_id == frame_id and msg.time_usec == 1_001_000


@pytest.mark.parametrize("length", [49, 50, 70])
def test_status_text_keeps_up_to_the_50_characters_statustext_holds(receiver, length):
    conn, port = receiver()
    text = "".join(chr(ord("A") + k % 26) for k in range(length))
    sender = MavlinkSender(mavlink_config(port))
    sender.send_statustext(text, mav2.MAV_SEVERITY_WARNING)
    got = collect(conn, lambda g: "STATUSTEXT" in g)
    sender.close()
    (msg,) = got["STATUSTEXT"]
    assert msg.text == text[:50] and msg.severity == mav2.MAV_SEVERITY_WARNING


def decoded(names, pose=None, stamp_s=12.5):
    """The position messages of one pose, packed and decoded by pymavlink's own parser, by type."""
    if pose is None:
        quat = Rotation.from_euler("ZYX", [0.3, -0.1, 0.05]).as_quat()
        pose = LandingPose(np.array([-30.0, 2.0, -3.0]), quat, np.eye(6) * 1e-3)
    mav = mav2.MAVLink(None, srcSystem=1, srcComponent=197)
    msgs = encode_pose(mav, names, pose, stamp_s, "LOCAL_FRD")
    return {m.get_type(): m for m in parse(b"".join(msg.pack(mav) for msg in msgs))}


def test_odometry_says_velocities_and_rates_are_unknown_and_the_quality_unset():
    """No velocity is measured: all six velocities and rates are NaN (not a measured zero an EKF
    would fuse), the velocity covariance is flagged unknown (NaN first), and the quality is
    0, "unknown" (−1 would say the odometry failed)."""
    odo = decoded(("ODOMETRY",))["ODOMETRY"]
    for field in ("vx", "vy", "vz", "rollspeed", "pitchspeed", "yawspeed"):
        assert math.isnan(getattr(odo, field)), field
    assert math.isnan(odo.velocity_covariance[0])
    assert odo.quality == 0 and odo.reset_counter == 0


def test_landing_target_names_one_vision_target_of_unknown_size():
    """The one target (number 0), seen by vision (LANDING_TARGET_TYPE_VISION_OTHER), no image so no
    angular size (0)."""
    lt = decoded(("LANDING_TARGET",))["LANDING_TARGET"]
    assert lt.target_num == 0 and lt.type == mav2.LANDING_TARGET_TYPE_VISION_OTHER
    assert lt.size_x == 0.0 and lt.size_y == 0.0


def test_heartbeat_says_an_active_disarmed_onboard_controller(receiver):
    conn, port = receiver()
    sender = MavlinkSender(mavlink_config(port))
    sender.send_heartbeat()
    got = collect(conn, lambda g: "HEARTBEAT" in g)
    sender.close()
    (hb,) = got["HEARTBEAT"]
    assert hb.system_status == mav2.MAV_STATE_ACTIVE
    assert hb.base_mode == 0 and hb.custom_mode == 0  # in particular not MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.mavlink_version == 3


def test_an_encoder_given_no_timestamp_signs_from_the_clock():
    """As pymavlink's setup_signing: the first frame's stamp is now, in 10 µs units since 2015."""
    class Frames(list):
        def write(self, data):
            self.append(bytes(data))

    frames = Frames()
    before = time.time()
    mav = encoder(frames, 255, 190, KEY)
    mav.heartbeat_send(6, 8, 0, 0, 4)
    after = time.time()
    link_id, stamp, good = signature_block(frames[0])
    assert good and link_id == 0
    assert int((before - UNIX_2015) * 100_000) <= stamp <= int((after - UNIX_2015) * 100_000) + 1


def test_closing_the_bridge_frees_its_mavlink_port():
    """A udpin station's port is free again once the bridge is closed (a restarted node can bind it)."""
    port = free_port(socket.SOCK_DGRAM)
    mav = dataclasses.replace(CONFIG.mavlink, connection=f"udpin:127.0.0.1:{port}")
    bridge = GcsBridge(dataclasses.replace(CONFIG, mavlink=mav))

    def bind():
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", port))

    with pytest.raises(OSError) as exc:
        bind()
    assert exc.value.errno == errno.EADDRINUSE
    bridge.close()
    bind()
