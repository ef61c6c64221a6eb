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
