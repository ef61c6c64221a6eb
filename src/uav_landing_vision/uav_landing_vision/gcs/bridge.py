"""The GCS bridge core: tracker pose in, MAVLink and landing guidance out; the node only adapts.

Call ``on_pose`` / ``on_tracker_state`` from the subscriptions and ``tick`` from a timer at
``mavlink.rate_hz``; publish ``TickResult.guidance`` as ``uav/landing_guidance``.
"""

import math
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mav2

from .config import GcsBridgeConfig
from .frames import DeckGeometry, LandingPose, camera_to_landing, euler_covariance
from .landing import LandingGuidance, Stage, StageMachine, cone_geometry
from .link import LinkStats
from .mavlink import MavlinkSender

TRACKER_LOST, TRACKER_ACQUIRING, TRACKER_TRACKING = 0, 1, 2  # uav_landing_msgs/TrackerStatus.state
HEARTBEAT_PERIOD_S = 1.0
# A pose stamped further than this ahead of the bridge's clock is refused: its stamp cannot be
# checked for staleness, and as the newest stamp it would shut out every correct pose after it.
CLOCK_LEAD_TOLERANCE_S = 0.05
FLOAT32_MAX = float(np.finfo(np.float32).max)  # MAVLink's positions and covariances are float32
# Position messages are at least this fraction of 1 / mavlink.rate_hz apart, not a whole period: the
# timer ticking at rate_hz fires a varying few ms late, and a whole period would hold a fresh pose
# back at every tick that came sooner after the last send than the one before it.
MIN_SEND_SPACING = 0.75


@dataclass(frozen=True)
class TickResult:
    guidance: LandingGuidance
    sent: tuple[str, ...]  # MAVLink message types this tick handed to the link, in order (see link_stats)


class GcsBridge:
    """Decides what to send and when: a pose is sent once, only while fresh and tracked.

    A pose is fresh while ``−CLOCK_LEAD_TOLERANCE_S <= now_s − stamp_s <= stale_timeout_s``;
    the tracker must report TRACKING (its latest state wins; LOST drops the held pose). A new pose
    is held back until a status stamped no earlier than it says TRACKING (the tracker publishes a
    frame's status after its pose, and after a silent restart of its track that status says
    ACQUIRING); until then the pose before it stays the one in use. Stale or
    lost → no position message at all and, in LAND, GO_AROUND at the next tick (within 0.5 s,
    checked by the config); a LOST or ACQUIRING (a restarted or coasting track) reported between
    two ticks counts at the next one even if the tracker is back to TRACKING by then. A clock that
    jumps back behind the held pose drops it too, and restarts the heartbeat, the send rate and
    the go-around hold on the new time-line.
    Stage changes go to the GCS as STATUSTEXT. A link failure changes none of this: what the link
    cannot send is dropped (``link_stats``), and at the first tick after frames go out again the
    heartbeat and the current stage (a STATUSTEXT as for a stage change) are sent at once, since
    the GCS may have missed both.
    """

    def __init__(self, config: GcsBridgeConfig, sender: MavlinkSender | None = None):
        self._cfg = config
        self._deck = DeckGeometry.from_mount(config.camera.position_m, config.camera.rpy, config.net_position_m)
        self._sender = sender if sender is not None else MavlinkSender(config.mavlink)
        self._machine = StageMachine(config.cone, config.go_around_hold_s)
        self._tracker_state = TRACKER_LOST
        self._status_stamp = -math.inf
        self._untracked_since_tick = False  # a status other than TRACKING since the last tick
        self._pose: LandingPose | None = None  # the newest pose confirmed by a TRACKING status
        self._stamp = -math.inf
        self._pose_sent = False
        self._pending: LandingPose | None = None  # a newer pose awaiting its frame's status
        self._pending_stamp = -math.inf
        self._newest_stamp = -math.inf  # of every pose taken; a loss keeps it, so none older is sent after it
        self._last_position_send = -math.inf
        self._last_heartbeat = -math.inf

    @property
    def stage(self) -> Stage:
        return self._machine.stage

    @property
    def link_stats(self) -> LinkStats:
        return self._sender.stats

    @property
    def signing_store_error(self) -> str:
        """Why the MAVLink signing timestamp could not be stored at the last try, or ""."""
        return self._sender.signing_store_error

    def on_pose(self, stamp_s: float, position_cam, quat_cam, covariance, now_s: float) -> bool:
        """Take a tracker pose (FLU body in the camera optical frame, ROS 6×6 covariance).

        Malformed input raises ValueError and changes nothing: a stamp that is not a finite time
        ≥ 0 or lies more than ``CLOCK_LEAD_TOLERANCE_S`` ahead of ``now_s``, or a pose or
        covariance MAVLink cannot carry. Returns False, ignoring the pose, when it is not newer
        than every pose taken before (a loss of track does not change that: a pose that comes late
        must not reach the GCS after a newer one did) or already stale at ``now_s``.
        """
        if not (math.isfinite(stamp_s) and stamp_s >= 0.0):
            raise ValueError(f"pose stamp must be a finite time >= 0, got {stamp_s!r}")
        if stamp_s - now_s > CLOCK_LEAD_TOLERANCE_S:
            raise ValueError(f"pose stamp {stamp_s:.3f} s is {stamp_s - now_s:.3f} s ahead of the clock "
                             f"(more than {CLOCK_LEAD_TOLERANCE_S} s): clocks out of step?")
        pose = camera_to_landing(position_cam, quat_cam, covariance, self._deck)
        mavlink_covariance = euler_covariance(pose)  # undefined at pitch ±90°: ValueError
        # The distance bounds every coordinate sent, LANDING_TARGET's body-frame ones and distance too.
        # Not max(): a NaN (inf × 0 in the Euler Jacobian of a huge covariance near ±90° pitch) would pass it.
        if not np.all(np.abs(mavlink_covariance) <= FLOAT32_MAX) or np.linalg.norm(pose.position) > FLOAT32_MAX:
            raise ValueError("pose position or covariance exceeds MAVLink's float32 range")
        self._forget_pose_ahead_of(now_s)
        if stamp_s <= self._newest_stamp or now_s - stamp_s > self._cfg.stale_timeout_s:
            return False
        self._pending, self._pending_stamp, self._newest_stamp = pose, stamp_s, stamp_s
        self._confirm()
        return True

    def _forget_pose_ahead_of(self, now_s: float) -> None:
        """Drop held poses and the status stamp if the clock has jumped back behind them (e.g. a restarted replay)."""
        if self._stamp - now_s > CLOCK_LEAD_TOLERANCE_S:
            self._pose, self._stamp = None, -math.inf
        if self._pending_stamp - now_s > CLOCK_LEAD_TOLERANCE_S:
            self._pending, self._pending_stamp = None, -math.inf
        if self._newest_stamp - now_s > CLOCK_LEAD_TOLERANCE_S:
            self._newest_stamp = -math.inf
        if self._status_stamp - now_s > CLOCK_LEAD_TOLERANCE_S:
            self._status_stamp = -math.inf

    def _confirm(self) -> None:
        """Settle the pending pose once a status of its frame or a later one has come: it is the pose
        in use from now on if that status says TRACKING, else it is dropped."""
        if self._pending is None or self._status_stamp < self._pending_stamp:
            return
        if self._tracker_state == TRACKER_TRACKING:
            self._pose, self._stamp, self._pose_sent = self._pending, self._pending_stamp, False
        self._pending, self._pending_stamp = None, -math.inf

    def on_tracker_state(self, state: int, stamp_s: float) -> None:
        """Latest ``TrackerStatus``: its state and image stamp; LOST discards the held pose."""
        if state not in (TRACKER_LOST, TRACKER_ACQUIRING, TRACKER_TRACKING):
            raise ValueError(f"unknown tracker state {state!r}")
        if not math.isfinite(stamp_s):
            raise ValueError(f"tracker status stamp must be finite, got {stamp_s!r}")
        self._tracker_state, self._status_stamp = state, stamp_s
        self._untracked_since_tick |= state != TRACKER_TRACKING
        if state == TRACKER_LOST:
            self._pose, self._stamp = None, -math.inf
            self._pending, self._pending_stamp = None, -math.inf
        self._confirm()

    def reset(self) -> Stage:
        """Operator reset of the stage machine to LOITER (e.g. after recovery from the net).

        Announced to the GCS by STATUSTEXT when it changes the stage; returns the stage before."""
        before = self._machine.stage
        self._machine.reset()
        if before is not Stage.LOITER:
            self._sender.send_statustext(f"VISION LOITER (operator reset from {before.name})", mav2.MAV_SEVERITY_NOTICE)
        return before

    def tick(self, now_s: float) -> TickResult:
        self._forget_pose_ahead_of(now_s)
        if now_s < max(self._last_heartbeat, self._last_position_send):  # the clock jumped back
            self._last_heartbeat = self._last_position_send = -math.inf
        restored = self._sender.poll()
        if restored:
            self._last_heartbeat = -math.inf
        fresh = (
            self._pose is not None
            and self._tracker_state == TRACKER_TRACKING
            and not self._untracked_since_tick
            and now_s - self._stamp <= self._cfg.stale_timeout_s
        )
        self._untracked_since_tick = False
        geometry = cone_geometry(self._pose.position, self._cfg.cone) if fresh else None
        before = self._machine.stage
        stage = self._machine.update(now_s, geometry, self._stamp)
        sent: list[str] = []
        if now_s - self._last_heartbeat >= HEARTBEAT_PERIOD_S:
            self._sender.send_heartbeat()
            self._last_heartbeat = now_s
            sent.append("HEARTBEAT")
        if stage != before or restored:
            self._sender.send_statustext(status_text(stage, geometry), status_severity(stage))
            sent.append("STATUSTEXT")
        period = 1.0 / self._cfg.mavlink.rate_hz
        if fresh and not self._pose_sent and now_s - self._last_position_send >= MIN_SEND_SPACING * period:
            sent += self._sender.send_pose(self._pose, self._stamp)
            self._pose_sent = True
            self._last_position_send = now_s
        nan = math.nan
        guidance = LandingGuidance(
            stamp_s=self._stamp if fresh else now_s,
            stage=stage,
            range=geometry.range if geometry else nan,
            glide_slope_angle=geometry.glide_slope_angle if geometry else nan,
            glide_slope_error=geometry.glide_slope_error if geometry else nan,
            lateral_angle=geometry.lateral_angle if geometry else nan,
            inside_cone=bool(geometry and geometry.inside_cone),
        )
        return TickResult(guidance, tuple(sent))

    def close(self) -> None:
        self._sender.close()


def status_severity(stage: Stage) -> int:
    return mav2.MAV_SEVERITY_WARNING if stage is Stage.GO_AROUND else mav2.MAV_SEVERITY_NOTICE


def status_text(stage: Stage, geometry) -> str:
    """The STATUSTEXT for a stage change, e.g. ``VISION LAND r=42.0m gs=+0.3 lat=-1.2deg``."""
    if geometry is None:
        return f"VISION {stage.name} (no track)"
    return (
        f"VISION {stage.name} r={geometry.range:.1f}m gs={math.degrees(geometry.glide_slope_error):+.1f}"
        f" lat={math.degrees(geometry.lateral_angle):+.1f}deg"
    )
