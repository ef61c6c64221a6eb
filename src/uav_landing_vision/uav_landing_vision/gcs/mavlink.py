"""MAVLink 2 encoding and transport (pymavlink, ``common`` dialect).

Every position message carries the landing-frame pose of ``frames.LandingPose``: x toward
the bow, y starboard, z down, origin at the net; attitude of the UAV's FRD body;
quaternions on the wire are w-first. ``time_usec`` is the image time.
"""

import math
import string
from pathlib import Path

import numpy as np
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mav2

from ..geometry import quat_conjugate, quat_to_euler_zyx
from .config import MavlinkConfig
from .frames import LandingPose, euler_covariance, target_in_body

ODOMETRY_FRAME_IDS = {
    "LOCAL_FRD": mav2.MAV_FRAME_LOCAL_FRD,
    "LOCAL_NED": mav2.MAV_FRAME_LOCAL_NED,
    "MOCAP_NED": 14,  # MAV_FRAME_MOCAP_NED, now MAV_FRAME_RESERVED_14 in common.xml
}
_NAN_21 = [math.nan] + [0.0] * 20  # "unknown" covariance: NaN in the first element


def load_signing_key(path: str | Path) -> bytes:
    """The 32-byte MAVLink 2 signing key from a file of 64 hexadecimal digits."""
    text = Path(path).read_text(encoding="ascii").strip()
    if len(text) != 64 or any(c not in string.hexdigits for c in text):
        raise ValueError(f"{path}: a signing key file holds exactly 64 hexadecimal digits")
    return bytes.fromhex(text)


def open_link(connection: str, system_id: int, component_id: int, key: bytes | None = None, link_id: int = 0):
    """A pymavlink connection speaking MAVLink 2 with ``common``, signing outgoing frames if ``key``.

    The dialect object is set on the connection, so the process-wide pymavlink dialect and
    the ``MAVLINK20`` environment variable are left alone.
    """
    conn = mavutil.mavlink_connection(connection, source_system=system_id, source_component=component_id)
    conn.mav = mav2.MAVLink(conn, srcSystem=system_id, srcComponent=component_id)
    conn.mav.robust_parsing = True
    conn.WIRE_PROTOCOL_VERSION = "2.0"
    conn.first_byte = False  # no auto-switch of the global dialect on the first byte received
    if key is not None:
        conn.setup_signing(key, sign_outgoing=True, link_id=link_id)
    return conn


def covariance_upper_triangle(cov: np.ndarray) -> list[float]:
    """The 21 entries of MAVLink's row-major upper-right triangle of a 6×6 covariance."""
    return [float(v) for v in np.asarray(cov)[np.triu_indices(6)]]


def encode_pose(mav, names: tuple[str, ...], pose: LandingPose, stamp_s: float, odometry_frame: str) -> list:
    """The configured position messages for one landing-frame pose (never an unconfigured one)."""
    usec = int(round(stamp_s * 1e6))
    x, y, z = (float(v) for v in pose.position)
    q_wxyz = [float(pose.quat[3]), *(float(v) for v in pose.quat[:3])]
    roll, pitch, yaw = (float(a) for a in quat_to_euler_zyx(pose.quat))
    cov21 = covariance_upper_triangle(euler_covariance(pose))
    out = []
    for name in names:
        if name == "ODOMETRY":
            out.append(
                mav.odometry_encode(
                    usec, ODOMETRY_FRAME_IDS[odometry_frame], mav2.MAV_FRAME_BODY_FRD,
                    x, y, z, q_wxyz, math.nan, math.nan, math.nan, math.nan, math.nan, math.nan,
                    cov21, _NAN_21, reset_counter=0, estimator_type=mav2.MAV_ESTIMATOR_TYPE_VISION, quality=0,
                )
            )
        elif name == "ATT_POS_MOCAP":
            out.append(mav.att_pos_mocap_encode(usec, q_wxyz, x, y, z, cov21))
        elif name == "VISION_POSITION_ESTIMATE":
            out.append(mav.vision_position_estimate_encode(usec, x, y, z, roll, pitch, yaw, cov21, 0))
        elif name == "LANDING_TARGET":
            out.append(_landing_target(mav, usec, pose))
        else:
            raise ValueError(f"unknown MAVLink message {name!r}")
    return out


def _landing_target(mav, usec: int, pose: LandingPose):
    """LANDING_TARGET in MAV_FRAME_BODY_FRD, position_valid=1: the net relative to the UAV.

    There is no image, so angle_x/angle_y carry the azimuth (+ right) and depression (+ down)
    of the net in the body frame; q is the landing frame's orientation in the body frame.
    """
    tx, ty, tz = (float(v) for v in target_in_body(pose))
    q_body_l = quat_conjugate(pose.quat)
    return mav.landing_target_encode(
        usec, 0, mav2.MAV_FRAME_BODY_FRD,
        math.atan2(ty, tx), math.atan2(tz, math.hypot(tx, ty)), math.sqrt(tx * tx + ty * ty + tz * tz),
        0.0, 0.0, tx, ty, tz,
        [float(q_body_l[3]), *(float(v) for v in q_body_l[:3])],
        mav2.LANDING_TARGET_TYPE_VISION_OTHER, 1,
    )


class MavlinkSender:
    """The station's MAVLink output: heartbeat, position messages, status texts."""

    def __init__(self, cfg: MavlinkConfig):
        key = load_signing_key(cfg.signing_key_file) if cfg.signing_key_file else None
        self._cfg = cfg
        self.conn = open_link(cfg.connection, cfg.system_id, cfg.component_id, key, cfg.signing_link_id)

    def send_pose(self, pose: LandingPose, stamp_s: float) -> list[str]:
        msgs = encode_pose(self.conn.mav, self._cfg.messages, pose, stamp_s, self._cfg.odometry_frame)
        for m in msgs:
            self.conn.mav.send(m)
        return [m.get_type() for m in msgs]

    def send_heartbeat(self) -> None:
        self.conn.mav.heartbeat_send(
            mav2.MAV_TYPE_ONBOARD_CONTROLLER, mav2.MAV_AUTOPILOT_INVALID, 0, 0, mav2.MAV_STATE_ACTIVE
        )

    def send_statustext(self, text: str, severity: int) -> None:
        """One STATUSTEXT (at most 50 ASCII characters; longer text is cut)."""
        self.conn.mav.statustext_send(severity, text.encode("ascii", "replace")[:50])

    def close(self) -> None:
        self.conn.close()
