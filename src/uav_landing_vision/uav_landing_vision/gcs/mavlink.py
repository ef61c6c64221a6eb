"""MAVLink 2 encoding (pymavlink, ``common`` dialect); the link it goes out on is ``gcs.link``.

Every position message carries the landing-frame pose of ``frames.LandingPose``: x toward
the bow, y starboard, z down, origin at the net; attitude of the UAV's FRD body;
quaternions on the wire are w-first. ``time_usec`` is the image time.
"""

import math
import string
import time
from pathlib import Path
from typing import Callable

import numpy as np
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mav2

from ..geometry import quat_conjugate, quat_to_euler_zyx
from .config import MavlinkConfig
from .frames import LandingPose, euler_covariance, target_in_body
from .link import LinkStats, open_transport
from .signing import LAST_TIMESTAMP, SigningTimestamps, clock_timestamp

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


def encoder(file, system_id: int, component_id: int, key: bytes | None = None, link_id: int = 0,
            timestamp: int | None = None):
    """A MAVLink 2 ``common`` encoder that writes each frame with ``file.write``, signing it if ``key``
    from ``timestamp`` (``gcs.signing``; the clock's now if None, as pymavlink's ``setup_signing``)."""
    mav = mav2.MAVLink(file, srcSystem=system_id, srcComponent=component_id)
    mav.robust_parsing = True
    if key is not None:
        mav.signing.secret_key, mav.signing.sign_outgoing, mav.signing.link_id = key, True, link_id
        mav.signing.timestamp = clock_timestamp(time.time()) if timestamp is None else timestamp
    return mav


def open_link(connection: str, system_id: int, component_id: int, key: bytes | None = None, link_id: int = 0):
    """A pymavlink connection speaking MAVLink 2 with ``common``, signing outgoing frames if ``key``
    (the GCS's end in tests and tools; the station sends through ``MavlinkSender``).

    The dialect object is set on the connection, so the process-wide pymavlink dialect and
    the ``MAVLINK20`` environment variable are left alone.
    """
    conn = mavutil.mavlink_connection(connection, source_system=system_id, source_component=component_id)
    conn.mav = encoder(conn, system_id, component_id, key, link_id)
    conn.WIRE_PROTOCOL_VERSION = "2.0"
    conn.first_byte = False  # no auto-switch of the global dialect on the first byte received
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
    """The station's MAVLink output: heartbeat, position messages, status texts, over a link
    that never blocks or raises (``gcs.link``): what it cannot send is dropped and counted.
    Signed, its timestamps follow ``clock`` (Unix seconds) and survive restarts (``gcs.signing``),
    and rise to those of the GCS's signed frames, as pymavlink's parser takes them: a station whose
    clock is behind the GCS's is then accepted once it has heard the GCS."""

    def __init__(self, cfg: MavlinkConfig, clock: Callable[[], float] = time.time):
        # Each failure is a ValueError naming the parameter behind it.
        try:
            key = load_signing_key(cfg.signing_key_file) if cfg.signing_key_file else None
        except (OSError, ValueError) as exc:
            raise ValueError(f"mavlink.signing_key_file: {exc}") from exc
        self._cfg = cfg
        try:
            self._stamps = SigningTimestamps(cfg.signing_timestamp_path, clock) if key is not None else None
        except (OSError, ValueError) as exc:
            raise ValueError(f"mavlink.signing_timestamp_file: {exc}") from exc
        try:
            self.link = open_transport(cfg.connection)
        except (OSError, ValueError) as exc:
            raise ValueError(f"mavlink.connection: cannot open '{cfg.connection}': {exc}") from exc
        start = self._stamps.start if self._stamps is not None else None
        self.mav = encoder(self.link, cfg.system_id, cfg.component_id, key, cfg.signing_link_id, start)
        self._inbound = None  # parses what the GCS sends, for the stamps of its signed frames
        if key is not None:
            self._inbound = mav2.MAVLink(None)
            self._inbound.robust_parsing = True
            self._inbound.signing.secret_key = key

    @property
    def stats(self) -> LinkStats:
        return self.link.stats

    @property
    def signing_store_error(self) -> str:
        """Why the signing timestamp could not be stored at the last try, or ""."""
        return self._stamps.store_error if self._stamps is not None else ""

    def _send(self, msg) -> None:
        if self._stamps is not None:
            self.mav.signing.timestamp = self._stamps.advance(self.mav.signing.timestamp)
        self.mav.send(msg)

    def poll(self) -> bool:
        """Service the link (see ``Link.poll``): True once when it sends again after an outage.
        Signed, what came in is parsed: the stamp of a frame with a good signature raises the
        station's timestamp (up to ``LAST_TIMESTAMP``).

        The parser has signing state of its own, emptied before each parse: pymavlink records a
        stream's stamp before it checks the signature, so a forged frame could otherwise block
        the GCS's later frames, and one stream per forged (link, system, component) would pile up."""
        back = self.link.poll()
        data = self.link.received()
        if data and self._inbound is not None:
            signing = self._inbound.signing
            signing.timestamp = 0
            signing.stream_timestamps.clear()
            self._inbound.parse_buffer(data)
            if signing.timestamp <= LAST_TIMESTAMP:
                self.mav.signing.timestamp = max(self.mav.signing.timestamp, signing.timestamp)
        return back

    def send_pose(self, pose: LandingPose, stamp_s: float) -> list[str]:
        msgs = encode_pose(self.mav, self._cfg.messages, pose, stamp_s, self._cfg.odometry_frame)
        for m in msgs:
            self._send(m)
        return [m.get_type() for m in msgs]

    def send_heartbeat(self) -> None:
        self._send(self.mav.heartbeat_encode(
            mav2.MAV_TYPE_ONBOARD_CONTROLLER, mav2.MAV_AUTOPILOT_INVALID, 0, 0, mav2.MAV_STATE_ACTIVE
        ))

    def send_statustext(self, text: str, severity: int) -> None:
        """One STATUSTEXT (at most 50 ASCII characters; longer text is cut)."""
        self._send(self.mav.statustext_encode(severity, text.encode("ascii", "replace")[:50]))

    def close(self) -> None:
        self.link.close()
        if self._stamps is not None:
            self._stamps.close()
