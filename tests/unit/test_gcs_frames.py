"""GCS frames: camera optical → ship (FRD) → landing frame, FLU → FRD body, covariance.

Expected values are built by hand (axis by axis) or with scipy as the oracle. The traps users
report against MAVROS are checked explicitly: z up vs. down, yaw sign, FLU vs. FRD body axes
and scalar-first vs. scalar-last quaternions.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision.gcs.frames import (
    DeckGeometry,
    camera_mount_rotation,
    camera_to_landing,
    euler_covariance,
    target_in_body,
    validate_pose,
)
from uav_landing_vision.geometry import quat_to_euler_zyx

# Camera 3 m above the ship origin looking aft (yaw 180°); net 4 m aft of the origin, 1.5 m up.
AFT_CAMERA = DeckGeometry.from_mount([0.0, 0.0, -3.0], [0.0, 0.0, np.pi], [-4.0, 0.0, -1.5])
ZERO_COV = np.zeros((6, 6))


def camera_pose_from_truth(deck_position, deck_rpy, net, p_land, rpy_frd):
    """Oracle (scipy): the tracker's FLU-in-optical pose of a UAV at ``p_land`` with FRD attitude ``rpy_frd``."""
    mount = Rotation.from_euler("ZYX", [deck_rpy[2], deck_rpy[1], deck_rpy[0]]).as_matrix()
    optical_in_mount = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    r_sc = mount @ optical_in_mount
    r_l_frd = Rotation.from_euler("ZYX", [rpy_frd[2], rpy_frd[1], rpy_frd[0]]).as_matrix()
    r_c_flu = r_sc.T @ r_l_frd @ np.diag([1.0, -1.0, -1.0])
    p_cam = r_sc.T @ (np.asarray(p_land) + np.asarray(net) - np.asarray(deck_position))
    return p_cam, Rotation.from_matrix(r_c_flu).as_quat()


def quat_from_columns(x_axis, y_axis, z_axis):
    """[x, y, z, w] of the rotation whose columns are the body axes written in the parent frame."""
    return Rotation.from_matrix(np.column_stack([x_axis, y_axis, z_axis])).as_quat()


def test_mount_zero_angles_looks_at_the_bow():
    r = camera_mount_rotation([0.0, 0.0, 0.0])
    np.testing.assert_allclose(r @ [0, 0, 1], [1, 0, 0], atol=1e-15)  # optical axis → bow
    np.testing.assert_allclose(r @ [1, 0, 0], [0, 1, 0], atol=1e-15)  # image right → starboard
    np.testing.assert_allclose(r @ [0, 1, 0], [0, 0, 1], atol=1e-15)  # image down → down


def test_mount_yaw_and_pitch():
    aft = camera_mount_rotation([0.0, 0.0, np.pi])
    np.testing.assert_allclose(aft @ [0, 0, 1], [-1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(aft @ [1, 0, 0], [0, -1, 0], atol=1e-15)  # image right → port
    up = camera_mount_rotation([0.0, np.radians(10.0), 0.0])
    np.testing.assert_allclose(up @ [0, 0, 1], [np.cos(np.radians(10)), 0, -np.sin(np.radians(10))], atol=1e-15)


# UAV 46 m astern of the net, 5 m above it: 50 m aft of and 3.5 m above the camera, i.e.
# straight ahead of the aft-looking camera, 3.5 m up in the image (optical y is down).
UAV_CAM = np.array([0.0, -3.5, 50.0])
UAV_LAND = np.array([-46.0, 0.0, -5.0])


def test_level_uav_flying_to_the_bow_is_identity_attitude_and_negative_z():
    # Flying toward the bow: nose = ship +x = optical −z; left wing = port = optical +x; up = optical −y.
    q_cam = quat_from_columns([0, 0, -1], [1, 0, 0], [0, -1, 0])
    pose = camera_to_landing(UAV_CAM, q_cam, ZERO_COV, AFT_CAMERA)
    np.testing.assert_allclose(pose.position, UAV_LAND, atol=1e-12)  # z < 0: above the net (NED, not ENU)
    np.testing.assert_allclose(pose.quat, [0, 0, 0, 1], atol=1e-12)  # FRD body aligned with the landing frame
    np.testing.assert_allclose(quat_to_euler_zyx(pose.quat), [0, 0, 0], atol=1e-12)


def test_heading_to_starboard_is_plus_90_yaw():
    # Nose to starboard (optical −x), left wing toward the bow (optical −z), up = optical −y.
    q_cam = quat_from_columns([-1, 0, 0], [0, 0, -1], [0, -1, 0])
    pose = camera_to_landing(UAV_CAM, q_cam, ZERO_COV, AFT_CAMERA)
    np.testing.assert_allclose(quat_to_euler_zyx(pose.quat), [0, 0, np.pi / 2], atol=1e-12)  # ENU would say −90°


@pytest.mark.parametrize("angle", [np.radians(30.0), np.radians(-20.0)])
def test_right_wing_down_is_positive_roll(angle):
    c, s = np.cos(angle), np.sin(angle)
    # In the ship frame: nose (1,0,0), left wing (0,−c,−s), up (0,s,−c); optical = (−y, z, −x) of ship.
    q_cam = quat_from_columns([0, 0, -1], [c, -s, 0], [-s, -c, 0])
    pose = camera_to_landing(UAV_CAM, q_cam, ZERO_COV, AFT_CAMERA)
    np.testing.assert_allclose(quat_to_euler_zyx(pose.quat), [angle, 0, 0], atol=1e-12)


def test_nose_up_is_positive_pitch():
    t = np.radians(8.0)
    c, s = np.cos(t), np.sin(t)
    # Nose (c,0,−s), left wing (0,−1,0), up (−s,0,−c) in the ship frame.
    q_cam = quat_from_columns([0, -s, -c], [1, 0, 0], [0, -c, s])
    pose = camera_to_landing(UAV_CAM, q_cam, ZERO_COV, AFT_CAMERA)
    np.testing.assert_allclose(quat_to_euler_zyx(pose.quat), [0, t, 0], atol=1e-12)


def test_target_in_body_is_ahead_and_below():
    q_cam = quat_from_columns([0, 0, -1], [1, 0, 0], [0, -1, 0])
    pose = camera_to_landing(UAV_CAM, q_cam, ZERO_COV, AFT_CAMERA)
    np.testing.assert_allclose(target_in_body(pose), [46.0, 0.0, 5.0], atol=1e-12)  # FRD: +z is down


def test_random_chain_matches_scipy_oracle():
    rng = np.random.default_rng(7)
    for _ in range(50):
        deck_pos, net = rng.normal(0, 5, 3), rng.normal(0, 5, 3)
        deck_rpy = rng.uniform([-0.3, -0.5, -np.pi], [0.3, 0.5, np.pi])
        p_land = rng.normal(0, 40, 3)
        rpy = rng.uniform([-1.0, -1.2, -np.pi], [1.0, 1.2, np.pi])
        p_cam, q_cam = camera_pose_from_truth(deck_pos, deck_rpy, net, p_land, rpy)
        pose = camera_to_landing(p_cam, q_cam, ZERO_COV, DeckGeometry.from_mount(deck_pos, deck_rpy, net))
        np.testing.assert_allclose(pose.position, p_land, atol=1e-9)
        np.testing.assert_allclose(quat_to_euler_zyx(pose.quat), rpy, atol=1e-9)


def test_position_covariance_follows_the_axes():
    # Aft camera: depth (optical z) is ship −x, image x is ship −y, image y is ship +z.
    cov = np.diag([0.01, 0.04, 9.0, 0.001, 0.002, 0.003])
    cov[0, 2] = cov[2, 0] = 0.05  # image-x/depth correlation: both signs flip, so it stays +
    q_cam = quat_from_columns([0, 0, -1], [1, 0, 0], [0, -1, 0])
    pose = camera_to_landing(UAV_CAM, q_cam, cov, AFT_CAMERA)
    expected = np.diag([9.0, 0.01, 0.04, 0.003, 0.001, 0.002])
    expected[0, 1] = expected[1, 0] = 0.05
    np.testing.assert_allclose(pose.covariance, expected, atol=1e-15)


def test_euler_covariance_level_heading_starboard():
    # Heading +90°: a rotation about the landing frame's y axis (starboard) is a roll of the UAV.
    q_cam = quat_from_columns([-1, 0, 0], [0, 0, -1], [0, -1, 0])
    cov = np.diag([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
    cov[3:, 3:] = np.diag([0.001, 0.002, 0.003])  # optical axes: ship −y, +z, −x
    pose = camera_to_landing(UAV_CAM, q_cam, cov, AFT_CAMERA)
    rpy_cov = euler_covariance(pose)
    np.testing.assert_allclose(np.diag(rpy_cov)[3:], [0.001, 0.003, 0.002], atol=1e-15)


def test_euler_covariance_matches_finite_differences():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(6, 6))
    cov = a @ a.T * 1e-3
    p_cam, q_cam = camera_pose_from_truth([1, 2, -3], [0.1, 0.2, 2.5], [-4, 0, -1], [-30, 4, -3], [0.4, -0.6, 1.1])
    pose = camera_to_landing(p_cam, q_cam, ZERO_COV, AFT_CAMERA)
    pose = type(pose)(pose.position, pose.quat, cov)
    base = quat_to_euler_zyx(pose.quat)
    h = 1e-7
    jac = np.eye(6)
    for k in range(3):
        delta = np.zeros(3)
        delta[k] = h
        perturbed = (Rotation.from_rotvec(delta) * Rotation.from_quat(pose.quat)).as_quat()
        jac[3:, 3 + k] = (quat_to_euler_zyx(perturbed) - base) / h
    np.testing.assert_allclose(euler_covariance(pose), jac @ cov @ jac.T, rtol=1e-5, atol=1e-10)


def test_euler_covariance_undefined_at_vertical_pitch():
    p_cam, q_cam = camera_pose_from_truth([0, 0, -3], [0, 0, np.pi], [-4, 0, -1.5], [-30, 0, -3], [0, np.pi / 2, 0])
    pose = camera_to_landing(p_cam, q_cam, ZERO_COV, AFT_CAMERA)
    with pytest.raises(ValueError, match="pitch"):
        euler_covariance(pose)


def _unit_covariance_with(i, j, upper, lower):
    cov = np.eye(6)
    cov[i, j], cov[j, i] = upper, lower
    return cov


INDEFINITE = _unit_covariance_with(0, 1, 2.0, 2.0)  # positive variances, a correlation of 2: an eigenvalue −1
ASYMMETRIC = _unit_covariance_with(0, 1, 0.5, 0.5 + 1e-6)  # the pair differs in its 7th digit


@pytest.mark.parametrize(
    "position, quat, cov, message",
    [
        ([np.nan, 0, 1], [0, 0, 0, 1], ZERO_COV, "position"),
        ([0, 0], [0, 0, 0, 1], ZERO_COV, "position"),
        ([0, 0, 1], [0, 0, 0, 1.1], ZERO_COV, "unit"),
        ([0, 0, 1], [0, 0, np.nan, 1], ZERO_COV, "unit"),
        ([0, 0, 1], [0, 0, 0, 1], -np.eye(6), "positive semi-definite"),
        ([0, 0, 1], [0, 0, 0, 1], np.triu(np.ones((6, 6))), "symmetric"),
        ([0, 0, 1], [0, 0, 0, 1], np.full((6, 6), np.inf), "finite"),
        ([0, 0, 1], [0, 0, 0, 1], np.eye(5), "6×6"),
        ([0, 0, 1], [0, 0, 0, 1], np.diag([1.0, 1, 1, 1, 1, -1e-6]), "positive semi-definite"),
        ([0, 0, 1], [0, 0, 0, 1], np.eye(6) + np.diag([1e-6], k=5), "symmetric"),
        ([0, 0, np.inf], [0, 0, 0, 1], ZERO_COV, "position"),
        ([0, 0, 1], [0, 0, 0, 0.999], ZERO_COV, "unit"),  # too short, as well as too long
        ([0, 0, 1], [0, 0, 0, 0], ZERO_COV, "unit"),
        ([0, 0, 1], [0, 0, 0, 1.001], ZERO_COV, "unit"),
        ([0, 0, 1], [0, 0, 1], ZERO_COV, "quaternion"),  # three numbers of unit norm
        ([0, 0, 1], [0, 0, 0, 1], INDEFINITE, "positive semi-definite"),
        ([0, 0, 1], [0, 0, 0, 1], ASYMMETRIC, "symmetric"),
    ],
)
def test_bad_pose_is_rejected(position, quat, cov, message):
    with pytest.raises(ValueError, match=message):
        validate_pose(position, quat, cov)


def test_flat_ros_covariance_is_accepted():
    _, _, cov = validate_pose([0, 0, 1], [0, 0, 0, 1], np.eye(6).ravel())
    assert cov.shape == (6, 6)


def test_rounding_in_a_small_covariance_is_accepted():
    """The symmetry and PSD tolerances scale with max(1, |cov|), not with a tiny covariance."""
    cov = np.diag([1e-6, 1e-6, 1e-6, 1e-8, 1e-8, 0.0])
    cov[0, 1], cov[1, 0] = 1e-7, 1e-7 + 1e-12
    cov[5, 5] = -1e-12
    validate_pose([0, 0, 1], [0, 0, 0, 1], cov)


def test_rounding_in_a_large_covariance_is_accepted():
    """A UAV far out: variances of 10⁴ m². Rounding of 1e-8 in a correlation, or an eigenvalue
    of −1e-8, is 1e-12 of the covariance's scale and must not refuse the pose."""
    cov = np.diag([1e4, 1e4, 1e4, 1.0, 1.0, 1.0])
    cov[0, 1], cov[1, 0] = 1e3, 1e3 + 1e-8
    validate_pose([0, 0, 1], [0, 0, 0, 1], cov)
    cov = np.diag([1e4, 1e4, 1e4, 1.0, 1.0, -1e-8])
    validate_pose([0, 0, 1], [0, 0, 0, 1], cov)


def _landing_pose_by_scipy(deck_position, deck_rpy, net, p_cam, rot_cam):
    """Oracle (scipy): the landing-frame position and FRD attitude of a FLU pose in the optical frame."""
    mount = Rotation.from_euler("ZYX", [deck_rpy[2], deck_rpy[1], deck_rpy[0]]).as_matrix()
    r_sc = mount @ np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    p_land = r_sc @ p_cam + np.asarray(deck_position) - np.asarray(net)
    return p_land, Rotation.from_matrix(r_sc @ rot_cam.as_matrix() @ np.diag([1.0, -1.0, -1.0]))


def test_full_covariance_propagates_through_the_pose_chain():
    """Correlations between all six errors, position and rotation alike: the landing-frame
    covariance is J Σ Jᵀ, J the change of the landing pose (position, rotation vector about the
    landing axes) under small camera-frame errors (position, rotation about the optical axes),
    found by finite differences of a scipy-built chain."""
    deck_position, deck_rpy, net = [1.0, 2.0, -3.0], [0.1, 0.2, 2.5], [-4.0, 0.5, -1.0]
    deck = DeckGeometry.from_mount(deck_position, deck_rpy, net)
    rng = np.random.default_rng(11)
    a = rng.normal(size=(6, 6))
    cov = a @ a.T * 1e-2
    p_cam = np.array([3.0, -2.0, 40.0])
    rot_cam = Rotation.from_rotvec([0.4, -1.1, 0.7])
    p0, r0 = _landing_pose_by_scipy(deck_position, deck_rpy, net, p_cam, rot_cam)
    h = 1e-6
    jac = np.zeros((6, 6))
    for k in range(6):
        d = np.zeros(6)
        d[k] = h
        perturbed = Rotation.from_rotvec(d[3:]) * rot_cam  # a rotation error about the optical axes
        p1, r1 = _landing_pose_by_scipy(deck_position, deck_rpy, net, p_cam + d[:3], perturbed)
        jac[:3, k] = (p1 - p0) / h
        jac[3:, k] = (r1 * r0.inv()).as_rotvec() / h
    pose = camera_to_landing(p_cam, rot_cam.as_quat(), cov, deck)
    np.testing.assert_allclose(pose.covariance, jac @ cov @ jac.T, rtol=1e-6, atol=1e-8)


def test_euler_covariance_undefined_within_a_microradian_of_vertical_pitch():
    """0.1 µrad short of 90° pitch the Euler covariance is refused; 10 µrad short it is given."""
    def pose_at(pitch):
        p_cam, q_cam = camera_pose_from_truth([0, 0, -3], [0, 0, np.pi], [-4, 0, -1.5], [-30, 0, -3], [0, pitch, 0])
        return camera_to_landing(p_cam, q_cam, np.eye(6) * 1e-4, AFT_CAMERA)

    with pytest.raises(ValueError, match="pitch"):
        euler_covariance(pose_at(np.pi / 2 - 1e-7))
    assert np.all(np.isfinite(euler_covariance(pose_at(np.pi / 2 - 1e-5))))
