"""Ground-truth motion against independent oracles: the cone geometry of Fig. 1.5, the ship's
motion about the net, the air-relative attitude and the single-frame protocol's poses."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision.geometry import quat_to_matrix
from uav_landing_vision.sim import generators, load_scenario, make_trajectory
from uav_landing_vision.sim.config import ShipConfig, SingleFrameConfig
from uav_landing_vision.sim.trajectory import (
    SmoothSignal,
    _bounded,
    camera_mount,
    cone_direction,
    landing_approach,
    ship_motion,
    single_frame_poses,
)

# The UAV facing the camera, upright, as the columns say: body x (nose) → −z_C, body y (left
# wing) → +x_C, body z (up) → −y_C.
FACING = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])
CALM = dict.fromkeys(("roll_far_deg", "roll_near_deg", "pitch_far_deg", "pitch_near_deg",
                      "yaw_far_deg", "yaw_near_deg"), 0.0)


def test_cone_direction_has_elevation_alpha_and_bearing_beta_to_port_from_astern():
    alpha = np.radians([3.0, 7.0, 10.0, 5.0])
    beta = np.radians([-10.0, 0.0, 4.0, 9.0])
    u = cone_direction(alpha, beta)
    np.testing.assert_allclose(np.linalg.norm(u, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.arcsin(u[:, 2]), alpha, atol=1e-12)
    np.testing.assert_allclose(np.arctan2(u[:, 1], -u[:, 0]), beta, atol=1e-12)
    assert np.all(u[:, 0] < 0)  # astern
    assert u[3, 1] > 0 and u[0, 1] < 0  # positive β: to port (+y)


def test_bounded_is_the_identity_near_the_centre_and_saturates_at_the_bounds():
    centre, half = 0.12, 0.05
    np.testing.assert_allclose(_bounded(centre, half, np.array([centre + 1e-4])), [centre + 1e-4], rtol=0, atol=1e-9)
    np.testing.assert_allclose(_bounded(centre, half, np.array([centre - 1e-4])), [centre - 1e-4], rtol=0, atol=1e-9)
    far = _bounded(centre, half, np.array([centre + 10.0, centre - 10.0]))
    np.testing.assert_allclose(far, [centre + half, centre - half], atol=1e-9)


def test_ship_heave_moves_the_camera_straight_up_and_down_only():
    ship = replace(ShipConfig(), roll_deg=0.0, pitch_deg=0.0, yaw_deg=0.0, heave_m=0.4)
    t = np.arange(0.0, 600.0, 0.05)
    rot, pos = ship_motion(np.random.default_rng(1), ship, t)
    mount_rot, mount_pos = camera_mount(ship)
    np.testing.assert_allclose(rot, np.broadcast_to(mount_rot, rot.shape), atol=1e-12)
    np.testing.assert_allclose(pos[:, :2], np.broadcast_to(mount_pos[:2], (len(t), 2)), atol=1e-12)
    heave = pos[:, 2] - mount_pos[2]
    assert np.sqrt(np.mean(heave**2)) == pytest.approx(0.4, rel=0.15)


def test_ship_rotation_turns_the_camera_about_the_net_centre():
    """Without heave the camera is the mount carried by the ship's rotation about the net: its
    position is R_MS p_mount with R_MS = cam_rot · mount_rot^T."""
    ship = replace(ShipConfig(), roll_deg=5.0, pitch_deg=3.0, yaw_deg=2.0, heave_m=0.0)
    t = np.arange(0.0, 60.0, 0.1)
    rot, pos = ship_motion(np.random.default_rng(2), ship, t)
    mount_rot, mount_pos = camera_mount(ship)
    r_ms = rot @ mount_rot.T
    np.testing.assert_allclose(pos, r_ms @ mount_pos, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(pos, axis=1), np.linalg.norm(mount_pos), atol=1e-9)
    assert np.max(np.linalg.norm(pos - mount_pos, axis=1)) > 0.05  # it does move


def test_approach_starts_at_the_drawn_camera_distance():
    s = load_scenario("normal")
    calm_ship = replace(s.ship, roll_deg=0.0, pitch_deg=0.0, yaw_deg=0.0, heave_m=0.0)
    s = replace(s, ship=calm_ship, approach=replace(s.approach, start_range_m=(90.0, 90.001), path_wander_deg=0.0))
    for seed in range(3):
        tr = make_trajectory(s, generators(seed))
        # (the nominal angles are squashed a little towards the cone's centre: a few cm)
        assert np.linalg.norm(tr.trans[0]) == pytest.approx(90.0, abs=0.1)


@pytest.mark.parametrize("seed", range(4))
def test_a_wandering_approach_stays_in_the_cone_and_in_the_wider_approach_bounds(seed):
    """With a wander far wider than the cone, the apparent angles are squashed into [α2, α1] and
    |β| ≤ β2/2 within cone_start_m of the net, and 50 % wider per cone_start_m beyond; the
    wander does use the room (β comes near its bound)."""
    s = load_scenario("normal")
    a = replace(s.approach, path_wander_deg=25.0)
    s = replace(s, approach=a)
    tr = make_trajectory(s, generators(seed))
    r = np.linalg.norm(tr.uav_pos, axis=1)
    ok = r > 0.5
    p, r = tr.uav_pos[ok], r[ok]
    alpha = np.degrees(np.arcsin(p[:, 2] / r))
    beta = np.degrees(np.arctan2(p[:, 1], -p[:, 0]))
    widen = 1.0 + 0.5 * np.clip((r - a.cone_start_m) / a.cone_start_m, 0.0, None)
    centre, half = (a.alpha1_deg + a.alpha2_deg) / 2, (a.alpha1_deg - a.alpha2_deg) / 2
    assert np.all(np.abs(alpha - centre) <= half * widen + 1e-6)
    assert np.all(np.abs(beta) <= a.beta2_deg / 2 * widen + 1e-6)
    inside = r <= a.cone_start_m
    assert np.all(np.abs(beta[inside]) <= a.beta2_deg / 2 + 1e-6)
    assert np.all((alpha[inside] >= a.alpha2_deg - 1e-6) & (alpha[inside] <= a.alpha1_deg + 1e-6))


def test_a_wandering_approach_uses_the_whole_width_of_the_cone():
    s = load_scenario("normal")
    a = replace(s.approach, path_wander_deg=25.0)
    s = replace(s, approach=a)
    reach = []
    for seed in range(4):
        tr = make_trajectory(s, generators(seed))
        r = np.linalg.norm(tr.uav_pos, axis=1)
        inside = (r <= a.cone_start_m) & (r > 0.5)
        p = tr.uav_pos[inside]
        reach.append(np.abs(np.degrees(np.arctan2(p[:, 1], -p[:, 0]))).max())
    assert max(reach) > 0.8 * a.beta2_deg / 2


@pytest.mark.parametrize("seed", range(3))
def test_nose_follows_the_air_relative_velocity_pitched_up_by_the_angle_of_attack(seed):
    """Without disturbances the nose points along the velocity relative to the air (the velocity
    relative to the ship plus the ship's speed, no wind), raised by the angle of attack."""
    s = load_scenario("normal")
    s = replace(s, approach=replace(s.approach, **CALM))
    tr = make_trajectory(s, generators(seed))
    nose = (tr.cam_rot @ quat_to_matrix(tr.quat))[:, :, 0]  # body x in M
    vel = np.gradient(tr.uav_pos, s.dt_s, axis=0) + np.array([s.ship.speed_mps, 0.0, 0.0])
    climb = np.degrees(np.arctan2(vel[:, 2], np.hypot(vel[:, 0], vel[:, 1])))
    nose_up = np.degrees(np.arcsin(np.clip(nose[:, 2], -1, 1)))
    inner = slice(3, -3)
    np.testing.assert_allclose(nose_up[inner], climb[inner] + s.approach.angle_of_attack_deg, atol=0.05)
    heading = np.degrees(np.arctan2(vel[:, 1], vel[:, 0]))
    nose_heading = np.degrees(np.arctan2(nose[:, 1], nose[:, 0]))
    np.testing.assert_allclose(nose_heading[inner], heading[inner], atol=0.05)


def test_single_frame_pose_without_turns_faces_the_camera_upright():
    cfg = SingleFrameConfig(distances_m=(5.0, 20.0), poses_per_distance=3, angle_limit_deg=0.0)
    tr = single_frame_poses(np.random.default_rng(0), cfg, ShipConfig(), 0.1)
    rot = quat_to_matrix(tr.quat)
    np.testing.assert_allclose(rot @ [1.0, 0.0, 0.0], np.broadcast_to([0.0, 0.0, -1.0], (6, 3)), atol=1e-9)
    np.testing.assert_allclose(rot @ [0.0, 1.0, 0.0], np.broadcast_to([1.0, 0.0, 0.0], (6, 3)), atol=1e-9)
    np.testing.assert_allclose(rot @ [0.0, 0.0, 1.0], np.broadcast_to([0.0, -1.0, 0.0], (6, 3)), atol=1e-9)


def test_single_frame_turns_are_about_the_camera_axes():
    """The pose is R_ZYX(γ, β, α) · R_facing with α, β, γ uniform in ±limit: the turn acts in
    the camera frame (rotation applied after the facing pose), checked with scipy."""
    cfg = SingleFrameConfig(distances_m=(5.0, 15.0), poses_per_distance=10, angle_limit_deg=40.0)
    tr = single_frame_poses(np.random.default_rng(7), cfg, ShipConfig(), 0.1)
    turn = Rotation.from_quat(tr.quat).as_matrix() @ FACING.T  # the turn in the camera frame
    angles = Rotation.from_matrix(turn).as_euler("ZYX")  # intrinsic Z-Y-X: [γ, β, α]
    assert np.all(np.abs(angles) <= np.radians(40.0) + 1e-9)
    # the same draws, reproduced: α, β, γ are the generator's first 3n uniforms, row by row
    drawn = np.random.default_rng(7).uniform(-np.radians(40.0), np.radians(40.0), (len(tr), 3))
    expected = Rotation.from_euler("ZYX", drawn[:, ::-1]).as_matrix() @ FACING
    np.testing.assert_allclose(quat_to_matrix(tr.quat), expected, atol=1e-9)


def test_single_frame_uav_position_is_the_camera_pose_applied_to_the_translation():
    s = load_scenario("single_frame")
    tr = make_trajectory(s, generators(0))
    np.testing.assert_allclose(np.einsum("nji,nj->ni", tr.cam_rot, tr.uav_pos - tr.cam_pos), tr.trans, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(tr.uav_pos - tr.cam_pos, axis=1), tr.trans[:, 2], atol=1e-9)


def _optical_in(body_rot):
    """Optical axes (x right, y down, z forward) as columns, from a camera body frame (x forward, y left, z up)."""
    return np.stack([-body_rot[:, 1], -body_rot[:, 2], body_rot[:, 0]], axis=1)


@pytest.mark.parametrize("rpy", [(0.0, -2.0, 180.0), (4.0, 10.0, -30.0), (-20.0, 35.0, 95.0)])
def test_camera_mount_is_the_optical_frame_of_its_zyx_body_angles(rpy):
    """The optical axis is the body x axis of the Z-Y-X (yaw, pitch, roll) angles, image x its
    right (−y) and image y its down (−z), checked with scipy."""
    ship = replace(ShipConfig(), camera_rpy_deg=rpy, camera_position_m=(4.0, -1.0, 0.7))
    rot, pos = camera_mount(ship)
    body = Rotation.from_euler("ZYX", rpy[::-1], degrees=True).as_matrix()
    np.testing.assert_allclose(rot, _optical_in(body), atol=1e-12)
    np.testing.assert_allclose(pos, [4.0, -1.0, 0.7])


def test_the_shipped_camera_looks_aft_upright_tilted_up():
    """Looking aft from the bow side of the net: image right is port (+y), image down is down."""
    rot, _ = camera_mount(ShipConfig())
    np.testing.assert_allclose(rot[:, 0], [0.0, 1.0, 0.0], atol=1e-12)
    assert rot[2, 1] < -0.99 and rot[0, 2] < -0.99 and rot[2, 2] > 0  # y down; z aft, a little up


def _band_power(signal, dt, band):
    """Fraction of the signal's power (periodogram) in ``band`` Hz."""
    power = np.abs(np.fft.rfft(signal - signal.mean())) ** 2
    freq = np.fft.rfftfreq(len(signal), dt)
    return power[(freq >= band[0]) & (freq <= band[1])].sum() / power.sum()


def test_smooth_signal_stays_in_its_band_and_within_its_peak():
    band = (0.1, 0.5)
    sig = SmoothSignal(np.random.default_rng(4), 2.0, band)
    t = np.arange(0.0, 4000.0, 0.05)
    v = sig(t)
    assert _band_power(v, 0.05, (band[0] - 0.005, band[1] + 0.005)) > 0.98
    assert np.abs(v).max() <= sig.peak <= 2.0 * np.sqrt(2 * 6) + 1e-12
    assert np.abs(v).max() > 0.8 * sig.peak  # the bound is tight: the terms do line up


def test_ship_roll_pitch_yaw_have_their_own_rms_in_the_wave_band():
    """Ship attitude R_MS = cam_rot · mount_rot^T, read as Z-Y-X angles with scipy: each of
    roll, pitch and yaw has its configured RMS, all of it between 1/10 and 1/5 Hz."""
    ship = replace(ShipConfig(), roll_deg=5.0, pitch_deg=2.0, yaw_deg=0.8, heave_m=0.0, wave_period_s=(5.0, 10.0))
    dt = 0.25
    t = np.arange(0.0, 6000.0, dt)
    rot, _ = ship_motion(np.random.default_rng(8), ship, t)
    yaw, pitch, roll = np.degrees(Rotation.from_matrix(rot @ camera_mount(ship)[0].T).as_euler("ZYX")).T
    for angle, rms in ((roll, 5.0), (pitch, 2.0), (yaw, 0.8)):
        assert np.sqrt(np.mean(angle**2)) == pytest.approx(rms, rel=0.15)
        assert _band_power(angle, dt, (0.099, 0.201)) > 0.95


def test_head_takes_the_first_frames_of_every_field():
    s = load_scenario("single_frame")
    tr = make_trajectory(s, generators(0))
    head = tr.head(7)
    for name in ("times_s", "quat", "trans", "cam_rot", "cam_pos", "uav_pos"):
        np.testing.assert_array_equal(getattr(head, name), getattr(tr, name)[:7])
    assert head.continuous is False and len(tr.head(len(tr))) == len(tr)
    for n in (0, len(tr) + 1):
        with pytest.raises(ValueError, match=f"this sequence has {len(tr)} frames; cannot take {n}"):
            tr.head(n)


def test_single_frame_times_start_at_zero_one_dt_apart():
    cfg = SingleFrameConfig(distances_m=(5.0, 20.0), poses_per_distance=3, angle_limit_deg=30.0)
    tr = single_frame_poses(np.random.default_rng(0), cfg, ShipConfig(), 0.25)
    np.testing.assert_array_equal(tr.times_s, [0.0, 0.25, 0.5, 0.75, 1.0, 1.25])


def _attitude_in_m(tr):
    """The UAV's yaw, pitch, roll in M (scipy Z-Y-X), radians."""
    return Rotation.from_matrix(tr.cam_rot @ quat_to_matrix(tr.quat)).as_euler("ZYX").T


def _air_velocity(s, tr):
    return np.gradient(tr.uav_pos, s.dt_s, axis=0) + np.array([s.ship.speed_mps, 0.0, 0.0])


@pytest.mark.parametrize("seed", range(2))
def test_roll_is_the_coordinated_turns_bank(seed):
    """Without disturbances tan(roll) = −a_left / g where the flight is about level, a_left the
    horizontal acceleration to the left of the flight path (M moves at a constant velocity:
    accelerations are inertial)."""
    s = load_scenario("normal")
    s = replace(s, approach=replace(s.approach, path_wander_deg=5.0, **CALM))
    tr = make_trajectory(s, generators(seed))
    _, _, roll = _attitude_in_m(tr)
    vel = _air_velocity(s, tr)
    acc = np.gradient(vel, s.dt_s, axis=0)
    left = np.stack([-vel[:, 1], vel[:, 0]], axis=-1) / np.hypot(vel[:, 0], vel[:, 1])[:, None]
    a_left = np.einsum("ni,ni->n", acc[:, :2], left)
    level = np.abs(vel[:, 2]) < 0.1 * np.hypot(vel[:, 0], vel[:, 1])  # the level turn's formula, within 0.5 %
    level[:5] = level[-5:] = False
    assert level.sum() > 50 and np.abs(a_left[level]).max() > 0.5
    np.testing.assert_allclose(np.tan(roll[level]), -a_left[level] / 9.81, rtol=0.01, atol=0.002)


def test_disturbances_have_the_far_and_near_rms_of_each_axis_independently():
    """Along a straight 1 km approach, the roll/pitch/yaw disturbances about the turn's bank, the
    air-relative climb plus angle of attack and the heading have the far RMS everywhere when
    disturbance_range_m is tiny, the near RMS when it is huge, and are not one signal."""
    s = load_scenario("normal")
    rms = dict(roll_far_deg=12.0, roll_near_deg=2.0, pitch_far_deg=5.0, pitch_near_deg=1.5,
               yaw_far_deg=4.0, yaw_near_deg=1.0)
    base = replace(s.approach, start_range_m=(1000.0, 1000.001), path_wander_deg=0.0, speed_jitter_mps=0.0, **rms)
    for reach, which in ((1.0, "far"), (1e7, "near")):
        s = replace(s, approach=replace(base, disturbance_range_m=reach))
        tr = make_trajectory(s, generators(1))
        yaw, pitch, roll = _attitude_in_m(tr)
        vel = _air_velocity(s, tr)
        climb = np.arctan2(vel[:, 2], np.hypot(vel[:, 0], vel[:, 1]))
        inner = slice(5, -5)
        d = {"roll": roll, "pitch": pitch + climb + np.radians(s.approach.angle_of_attack_deg),
             "yaw": yaw - np.arctan2(vel[:, 1], vel[:, 0])}
        d = {axis: np.degrees(v[inner]) for axis, v in d.items()}
        for axis, v in d.items():
            assert np.sqrt(np.mean(v**2)) == pytest.approx(rms[f"{axis}_{which}_deg"], rel=0.1), (axis, which)
        corr = np.corrcoef(np.stack(list(d.values())))
        assert np.abs(corr[np.triu_indices(3, 1)]).max() < 0.3


def test_single_frame_camera_is_the_mount_at_every_frame():
    ship = replace(ShipConfig(), camera_rpy_deg=(3.0, -10.0, 170.0), camera_position_m=(4.0, 1.0, 0.5))
    cfg = SingleFrameConfig(distances_m=(5.0, 20.0), poses_per_distance=2, angle_limit_deg=30.0)
    tr = single_frame_poses(np.random.default_rng(0), cfg, ship, 0.1)
    rot, pos = camera_mount(ship)
    np.testing.assert_array_equal(tr.cam_rot, np.broadcast_to(rot, (4, 3, 3)))
    np.testing.assert_array_equal(tr.cam_pos, np.broadcast_to(pos, (4, 3)))


def _apparent_angles(tr):
    """Elevation α and bearing β (from astern, to port) of the UAV seen from the net, degrees, and its range."""
    r = np.linalg.norm(tr.uav_pos, axis=1)
    p = tr.uav_pos
    return np.degrees(np.arcsin(p[:, 2] / r)), np.degrees(np.arctan2(p[:, 1], -p[:, 0])), r


def test_start_distances_cover_the_start_range():
    s = load_scenario("normal")
    s = replace(s, approach=replace(s.approach, start_range_m=(30.0, 100.0)))
    start = np.array([np.linalg.norm(make_trajectory(s, generators(seed)).trans[0]) for seed in range(12)])
    assert np.all((start > 29.9) & (start < 100.1))
    assert start.min() < 45.0 and start.max() > 85.0


def test_each_approach_flies_its_own_line_inside_the_cone():
    """Without wander the apparent angles near the net are the nominal line's: inside the cone,
    and not the same line for every seed."""
    s = load_scenario("normal")
    a = replace(s.approach, path_wander_deg=0.0)
    s = replace(s, approach=a)
    ends = []
    for seed in range(8):
        alpha, beta, r = _apparent_angles(make_trajectory(s, generators(seed)))
        near = (r > 2.0) & (r < 20.0)
        assert np.ptp(alpha[near]) < 1e-6 and np.ptp(beta[near]) < 1e-6  # a straight line
        ends.append((alpha[near][0], beta[near][0]))
    alpha, beta = np.array(ends).T
    assert np.all((alpha > a.alpha2_deg) & (alpha < a.alpha1_deg)) and np.all(np.abs(beta) < a.beta2_deg / 2)
    assert np.std(alpha) > 0.5 and np.std(beta) > 1.0


def test_elevation_and_bearing_wander_independently():
    s = load_scenario("normal")
    s = replace(s, approach=replace(s.approach, start_range_m=(300.0, 300.001), path_wander_deg=0.5))
    corr = []
    for seed in range(4):
        alpha, beta, _ = _apparent_angles(make_trajectory(s, generators(seed)))
        corr.append(np.corrcoef(alpha[:-5], beta[:-5])[0, 1])
    assert np.mean(np.abs(corr)) < 0.7


def test_closing_speed_carries_the_smooth_jitter():
    """Along a straight line (no wander) the speed relative to the ship is the closing speed
    plus a jitter of about ``speed_jitter_mps`` RMS, never beyond its peak (3.5×)."""
    s = load_scenario("normal")  # closing speed 7 m/s
    steady = replace(s.approach, start_range_m=(300.0, 300.001), path_wander_deg=0.0, speed_jitter_mps=0.0)
    for jitter, low, high in ((0.0, 0.0, 1e-3), (1.0, 0.5, 1.6)):
        s = replace(s, approach=replace(steady, speed_jitter_mps=jitter))
        tr = make_trajectory(s, generators(2))
        speed = np.linalg.norm(np.diff(tr.uav_pos, axis=0), axis=1)[:-1] / s.dt_s  # the last step: to the net
        assert low <= np.sqrt(np.mean((speed - 7.0) ** 2)) <= high
        assert np.abs(speed - 7.0).max() <= 3.5 * jitter + 1e-3


def test_squashed_angles_reach_the_cone_near_the_net_and_the_wider_bound_far_out():
    """With a wander far wider than the cone, |β| comes near β2/2 within half of cone_start_m of
    the net, and beyond 1.5 of it near β2/2 · (1 + 0.5 (r − d)/d) for r ≥ 3d."""
    s = load_scenario("normal")
    a = replace(s.approach, path_wander_deg=25.0, start_range_m=(200.0, 200.001))
    s = replace(s, approach=a)
    near, far = [], []
    for seed in range(4):
        _, beta, r = _apparent_angles(make_trajectory(s, generators(seed)))
        near.append(np.abs(beta[(r > 1.0) & (r < a.cone_start_m / 2)]).max())
        wide = r > 3 * a.cone_start_m
        far.append((np.abs(beta[wide]) / (1 + 0.5 * (r[wide] - a.cone_start_m) / a.cone_start_m)).max())
    assert max(near) > 0.8 * a.beta2_deg / 2
    assert 0.8 * a.beta2_deg / 2 < max(far) <= a.beta2_deg / 2
