"""Ground-truth motion: the landing approach in the cone of Fig. 1.5, ship motion, single-frame poses.

Frames (see ``docs/simulator.md``):

* **M**, the ship's mean frame: moves with the ship's mean course and speed, level; origin at
  the centre of the net, x forward (bow), y port, z up. The UAV's path is planned here.
* **S**, the ship frame: M rotated by the ship's roll/pitch/yaw about the net centre and
  raised by heave. The camera is fixed in S (``ShipConfig.camera_*``).
* **C**, the camera optical frame (x right, y down, z forward). The ground truth is the UAV
  body (FLU) in C: ``p_C = R(q) p_body + t``.
"""

from dataclasses import dataclass

import numpy as np

from ..geometry import (
    euler_zyx_to_matrix,
    euler_zyx_to_quat,
    matrix_to_quat,
    quat_canonical,
    quat_multiply,
    quat_normalise,
)
from .config import MAX_FRAMES, ApproachConfig, ScenarioError, ShipConfig, SingleFrameConfig

GRAVITY = 9.81
# Columns: the optical axes (x right, y down, z forward) in the camera body frame (x forward, y left, z up).
BODY_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
# The UAV facing the camera, upright: body x → −z_C, body y (left wing) → +x_C, body z → −y_C.
FACING_CAMERA = matrix_to_quat(np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]]))


@dataclass(frozen=True)
class Trajectory:
    """A sequence of ground-truth poses at times ``times_s`` (N,).

    ``quat``/``trans``: the UAV body in the camera optical frame; ``cam_rot``/``cam_pos``: the
    camera optical frame in M (rotation optical→M and position); ``uav_pos``: the UAV in M.
    ``continuous`` is False for independent single-frame poses (no motion between frames).
    """

    times_s: np.ndarray
    quat: np.ndarray
    trans: np.ndarray
    cam_rot: np.ndarray
    cam_pos: np.ndarray
    uav_pos: np.ndarray
    continuous: bool

    def __len__(self) -> int:
        return len(self.times_s)

    def head(self, n: int) -> "Trajectory":
        """The first ``n`` frames."""
        if not 1 <= n <= len(self):
            raise ValueError(f"this sequence has {len(self)} frames; cannot take {n}")
        return Trajectory(self.times_s[:n], self.quat[:n], self.trans[:n], self.cam_rot[:n],
                          self.cam_pos[:n], self.uav_pos[:n], self.continuous)


class SmoothSignal:
    """Zero-mean smooth random signal: a sum of sinusoids with random frequencies in a band.

    All parameters are drawn at construction, so its value at any time does not depend on
    how long the sequence is. Its RMS is ``rms``.
    """

    def __init__(self, rng: np.random.Generator, rms: float, band_hz: tuple[float, float], terms: int = 6):
        self.freq = rng.uniform(band_hz[0], band_hz[1], terms)
        self.phase = rng.uniform(0.0, 2 * np.pi, terms)
        w = rng.uniform(0.5, 1.0, terms)
        self.amp = rms * np.sqrt(2.0) * w / np.sqrt(np.sum(w * w))

    def __call__(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)[..., None]
        return np.sum(self.amp * np.sin(2 * np.pi * self.freq * t + self.phase), axis=-1)

    @property
    def peak(self) -> float:
        """The most ``|value|`` can reach: at most ``rms·√(2·terms)``."""
        return float(np.sum(np.abs(self.amp)))


def camera_mount(ship: ShipConfig) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (optical → S) and position in S of the camera."""
    rot = euler_zyx_to_matrix(np.radians(ship.camera_rpy_deg)) @ BODY_FROM_OPTICAL
    return rot, np.asarray(ship.camera_position_m, dtype=float)


def ship_motion(rng: np.random.Generator, ship: ShipConfig, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera pose in M over time: rotations optical→M ``(N,3,3)`` and positions ``(N,3)``.

    Roll, pitch, yaw and heave of the ship are independent smooth signals in the wave band.
    """
    band = (1.0 / ship.wave_period_s[1], 1.0 / ship.wave_period_s[0])
    rms = np.radians([ship.roll_deg, ship.pitch_deg, ship.yaw_deg])
    angles = np.stack([SmoothSignal(rng, r, band, terms=4)(t) for r in rms], axis=-1)
    heave = SmoothSignal(rng, ship.heave_m, band, terms=4)(t)
    r_ms = euler_zyx_to_matrix(angles)
    p_ms = np.stack([np.zeros_like(t), np.zeros_like(t), heave], axis=-1)
    mount_rot, mount_pos = camera_mount(ship)
    return r_ms @ mount_rot, p_ms + r_ms @ mount_pos


def cone_direction(alpha: np.ndarray, beta: np.ndarray) -> np.ndarray:
    """Unit vector in M from the net towards a UAV at apparent descent angle α and horizontal angle β (Fig. 1.5).

    The UAV comes from astern: α is its elevation above the net seen from the net, β its
    bearing from the ship's aft axis, positive to port.
    """
    ca = np.cos(alpha)
    return np.stack([-ca * np.cos(beta), ca * np.sin(beta), np.sin(alpha)], axis=-1)


def _bounded(centre: float, half: np.ndarray, value: np.ndarray) -> np.ndarray:
    """Smoothly squash ``value`` into ``centre ± half`` (tanh), identity near the centre."""
    return centre + half * np.tanh((value - centre) / half)


def landing_approach(rngs: tuple[np.random.Generator, np.random.Generator], cfg: ApproachConfig,
                     ship: ShipConfig, dt: float) -> Trajectory:
    """A landing from ``start_range_m`` (camera distance) to the net, relative to the moving ship.

    The UAV flies towards the net at ``airspeed − ship speed`` (plus a smooth jitter), along a
    line of nominal angles (α0, β0) drawn inside the cone, with a smooth wander of the
    apparent angles that always stays inside ``[α2, α1]`` and ``|β| ≤ β2/2`` once within
    ``cone_start_m`` of the net (before that, the approach stage, the bounds are 50 % wider per
    ``cone_start_m`` of extra range). Its nose follows its air-relative velocity (ship speed
    added, no wind) pitched up by the angle of attack, banks into turns (coordinated turn),
    and carries smooth roll/pitch/yaw disturbances whose RMS shrinks from the far to the near
    value inside ``disturbance_range_m``. ``rngs`` = (UAV generator, ship generator).
    """
    rng, ship_rng = rngs
    a1, a2, half_b = np.radians([cfg.alpha1_deg, cfg.alpha2_deg, cfg.beta2_deg / 2])
    a_c, a_h = (a1 + a2) / 2, (a1 - a2) / 2
    alpha0 = rng.uniform(a_c - 0.5 * a_h, a_c + 0.5 * a_h)
    beta0 = rng.uniform(-0.5 * half_b, 0.5 * half_b)
    distance0 = rng.uniform(*cfg.start_range_m)
    wander = np.radians(cfg.path_wander_deg)
    d_alpha = SmoothSignal(rng, wander, (0.03, 0.2))
    d_beta = SmoothSignal(rng, wander, (0.03, 0.2))
    jitter = SmoothSignal(rng, cfg.speed_jitter_mps, (0.05, 0.3))
    dist = [SmoothSignal(rng, 1.0, cfg.disturbance_band_hz) for _ in range(3)]

    # Range from the net at the start: the camera distance along the nominal line is distance0.
    _, cam = camera_mount(ship)
    u0 = cone_direction(alpha0, beta0)
    uc = float(u0 @ cam)
    r0 = uc + np.sqrt(uc * uc - cam @ cam + distance0**2)
    closing = cfg.airspeed_mps - ship.speed_mps
    n = int(np.ceil(r0 / ((closing - jitter.peak) * dt))) + 1  # enough steps at the slowest; trimmed below
    if n > MAX_FRAMES:
        raise ScenarioError(f"this approach may take up to {n} frames (at most {MAX_FRAMES}): "
                            "raise dt_s or the closing speed (approach.airspeed_mps - ship.speed_mps)")
    t = np.arange(n) * dt
    r = r0 - np.concatenate([[0.0], np.cumsum((closing + jitter(t[:-1])) * dt)])
    keep = r >= 0.0
    t, r = t[keep], r[keep]
    if len(t) < 2:
        raise ScenarioError(f"dt_s = {dt} s leaves fewer than 2 frames of this approach: lower it")

    widen = 1.0 + 0.5 * np.clip((r - cfg.cone_start_m) / cfg.cone_start_m, 0.0, None)
    alpha = _bounded(a_c, 0.95 * a_h * widen, alpha0 + d_alpha(t))
    beta = _bounded(0.0, 0.95 * half_b * widen, beta0 + d_beta(t))
    pos = r[:, None] * cone_direction(alpha, beta)

    air_vel = np.gradient(pos, dt, axis=0) + np.array([ship.speed_mps, 0.0, 0.0])
    heading = np.unwrap(np.arctan2(air_vel[:, 1], air_vel[:, 0]))
    climb = np.arctan2(air_vel[:, 2], np.hypot(air_vel[:, 0], air_vel[:, 1]))
    # REP 103 roll is positive right wing down, a turn to the right (heading falling, z up).
    turn_roll = -np.arctan(np.linalg.norm(air_vel, axis=1) * np.gradient(heading, dt) / GRAVITY)
    near = np.clip(r / cfg.disturbance_range_m, 0.0, 1.0)

    def envelope(far_deg, near_deg):
        return np.radians(near_deg + (far_deg - near_deg) * near)

    # REP 103 pitch is positive nose-down, so the nose-up attitude is −(climb + AoA).
    roll = turn_roll + envelope(cfg.roll_far_deg, cfg.roll_near_deg) * dist[0](t)
    pitch = -(climb + np.radians(cfg.angle_of_attack_deg)) + envelope(cfg.pitch_far_deg, cfg.pitch_near_deg) * dist[1](t)
    yaw = heading + envelope(cfg.yaw_far_deg, cfg.yaw_near_deg) * dist[2](t)
    uav_rot = euler_zyx_to_matrix(np.stack([roll, pitch, yaw], axis=-1))

    cam_rot, cam_pos = ship_motion(ship_rng, ship, t)
    return _in_camera(t, uav_rot, pos, cam_rot, cam_pos, continuous=True)


def single_frame_poses(rng: np.random.Generator, cfg: SingleFrameConfig, ship: ShipConfig, dt: float) -> Trajectory:
    """The single-frame protocol (§6.4, §6.6): the UAV centred on the optical axis at each distance.

    Its orientation is the facing-the-camera pose rotated by Z-Y-X Euler angles about the
    camera axes, each uniform in ``±angle_limit_deg``. The camera does not move.
    """
    dist = np.repeat(np.asarray(cfg.distances_m, dtype=float), cfg.poses_per_distance)
    n = len(dist)
    lim = np.radians(cfg.angle_limit_deg)
    angles = rng.uniform(-lim, lim, (n, 3))
    quat = quat_multiply(euler_zyx_to_quat(angles), FACING_CAMERA)
    trans = np.stack([np.zeros(n), np.zeros(n), dist], axis=-1)
    mount_rot, mount_pos = camera_mount(ship)
    cam_rot = np.broadcast_to(mount_rot, (n, 3, 3)).copy()
    cam_pos = np.broadcast_to(mount_pos, (n, 3)).copy()
    uav_pos = cam_pos + np.einsum("nij,nj->ni", cam_rot, trans)
    return Trajectory(np.arange(n) * dt, quat_canonical(quat_normalise(quat)), trans, cam_rot, cam_pos, uav_pos, False)


def _in_camera(t, uav_rot, uav_pos, cam_rot, cam_pos, continuous) -> Trajectory:
    """Express the UAV pose (in M) in the camera optical frame."""
    cam_t = np.swapaxes(cam_rot, -1, -2)
    rot = cam_t @ uav_rot
    trans = np.einsum("nij,nj->ni", cam_t, uav_pos - cam_pos)
    return Trajectory(t, matrix_to_quat(rot), trans, cam_rot, cam_pos, uav_pos, continuous)
