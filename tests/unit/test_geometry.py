"""Geometry against scipy.spatial.transform.Rotation (the independent oracle)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from uav_landing_vision import geometry as g

M = 500


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


@pytest.fixture
def quats(rng):
    return Rotation.random(M, random_state=rng).as_quat()


def test_product_matches_scipy_composition(quats, rng):
    other = Rotation.random(M, random_state=rng).as_quat()
    expected = (Rotation.from_quat(quats) * Rotation.from_quat(other)).as_matrix()
    np.testing.assert_allclose(g.quat_to_matrix(g.quat_multiply(quats, other)), expected, atol=1e-12)


def test_conjugate_is_inverse(quats):
    ident = g.quat_multiply(quats, g.quat_conjugate(quats))
    np.testing.assert_allclose(g.quat_canonical(ident), np.tile([0, 0, 0, 1.0], (M, 1)), atol=1e-12)


def test_canonical_is_one_representative_of_plus_minus_q(quats):
    half_turns = np.array([[1.0, 0, 0, 0], [0, -1.0, 0, 0], [0, 0.6, -0.8, 0], [-0.6, 0, 0.8, 0]])
    for q in (quats, half_turns):
        np.testing.assert_array_equal(g.quat_canonical(q), g.quat_canonical(-q))
    np.testing.assert_array_equal(g.quat_canonical(half_turns),
                                  [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0.6, -0.8, 0], [0.6, 0, -0.8, 0]])
    assert (g.quat_canonical(quats)[:, 3] >= 0).all()


def test_matrix_round_trip_matches_scipy(quats):
    mats = g.quat_to_matrix(quats)
    np.testing.assert_allclose(mats, Rotation.from_quat(quats).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(g.matrix_to_quat(mats), g.quat_canonical(quats), atol=1e-12)


def test_thesis_dcm_is_transpose_of_active_matrix(quats):
    q1, q2, q3, q4 = quats.T
    dcm = np.array(  # (3.2), passive
        [
            [q4**2 + q1**2 - q2**2 - q3**2, 2 * (q1 * q2 + q4 * q3), 2 * (q1 * q3 - q4 * q2)],
            [2 * (q1 * q2 - q4 * q3), q4**2 - q1**2 + q2**2 - q3**2, 2 * (q2 * q3 + q4 * q1)],
            [2 * (q1 * q3 + q4 * q2), 2 * (q2 * q3 - q4 * q1), q4**2 - q1**2 - q2**2 + q3**2],
        ]
    ).transpose(2, 0, 1)
    np.testing.assert_allclose(g.quat_to_matrix(quats), np.swapaxes(dcm, -1, -2), atol=1e-12)


def test_matrix_to_quat_near_180_degrees():
    axes = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [1.0, 1.0, 0]]) / np.array([[1], [1], [1], [np.sqrt(2)]])
    rot = Rotation.from_rotvec(axes * (np.pi - 1e-9))
    q = g.matrix_to_quat(rot.as_matrix())
    np.testing.assert_allclose(g.quat_to_matrix(q), rot.as_matrix(), atol=1e-9)


def test_euler_zyx_matches_scipy(rng):
    angles = rng.uniform([-np.pi, -np.pi / 2, -np.pi], [np.pi, np.pi / 2, np.pi], size=(M, 3))
    expected = Rotation.from_euler("ZYX", angles[:, ::-1])
    np.testing.assert_allclose(g.euler_zyx_to_matrix(angles), expected.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(g.euler_zyx_to_quat(angles), g.quat_canonical(expected.as_quat()), atol=1e-12)
    np.testing.assert_allclose(g.quat_to_euler_zyx(expected.as_quat()), angles, atol=1e-9)


def test_thesis_euler_dcm_is_transpose(rng):
    a, b, c = rng.uniform(-1, 1, 3)
    rx = np.array([[1, 0, 0], [0, np.cos(a), np.sin(a)], [0, -np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, -np.sin(b)], [0, 1, 0], [np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), np.sin(c), 0], [-np.sin(c), np.cos(c), 0], [0, 0, 1]])
    np.testing.assert_allclose(g.euler_zyx_to_matrix(np.array([a, b, c])), (rx @ ry @ rz).T, atol=1e-12)


def test_euler_gimbal_lock_round_trip():
    angles = np.array([[0.3, np.pi / 2, -0.4], [0.1, -np.pi / 2, 0.2]])
    m = g.euler_zyx_to_matrix(angles)
    np.testing.assert_allclose(g.euler_zyx_to_matrix(g.matrix_to_euler_zyx(m)), m, atol=1e-9)


def test_geodesic_angle_matches_scipy_and_log_map(quats, rng):
    other = Rotation.random(M, random_state=rng).as_quat()
    expected = (Rotation.from_quat(quats).inv() * Rotation.from_quat(other)).magnitude()
    np.testing.assert_allclose(g.geodesic_angle(quats, other), expected, atol=1e-12)
    # (3.3) literally: ||logm(R1^T R2)||_F / sqrt(2), the log map via scipy's rotation vector.
    rel = Rotation.from_matrix(np.swapaxes(g.quat_to_matrix(quats), -1, -2) @ g.quat_to_matrix(other))
    w = rel.as_rotvec()
    skew = np.zeros((M, 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    skew -= np.swapaxes(skew, -1, -2)
    np.testing.assert_allclose(g.geodesic_angle(quats, other), np.linalg.norm(skew, axis=(1, 2)) / np.sqrt(2), atol=1e-12)


def test_geodesic_angle_hand_cases():
    ident = np.array([0, 0, 0, 1.0])
    flip = np.array([1.0, 0, 0, 0])  # 180° about x
    assert g.geodesic_angle(ident, flip) == pytest.approx(np.pi)
    assert g.geodesic_angle(ident, -ident) == pytest.approx(0.0, abs=1e-15)
    small = Rotation.from_rotvec([1e-9, 0, 0]).as_quat()
    assert g.geodesic_angle(ident, small) == pytest.approx(1e-9, rel=1e-6)


def test_euler_error_matches_scipy(quats, rng):
    est = Rotation.random(M, random_state=rng).as_quat()
    q_e = Rotation.from_quat(quats) * Rotation.from_quat(est).inv()
    np.testing.assert_allclose(g.euler_error(quats, est), q_e.as_euler("ZYX")[:, ::-1], atol=1e-9)


def test_omega_integrates_constant_rate(rng):
    rates = rng.normal(size=(M, 3)) * 3.0
    dt = 0.034
    expected = Rotation.from_rotvec(rates * dt).as_quat()
    np.testing.assert_allclose(g.quat_canonical(g.omega_quat(rates, dt)), g.quat_canonical(expected), atol=1e-12)
    np.testing.assert_array_equal(g.omega_quat(np.zeros(3), dt), [0, 0, 0, 1.0])


def test_rodrigues_round_trip_and_small_angle(rng):
    e = Rotation.random(M, random_state=rng).as_quat()
    d = g.rodrigues_from_quat(e)
    np.testing.assert_allclose(g.quat_from_rodrigues(d), g.quat_canonical(e), atol=1e-12)
    # f = 2(a+1): ||d|| equals the rotation angle to first order.
    small = Rotation.from_rotvec(rng.normal(size=(M, 3)) * 1e-4)
    np.testing.assert_allclose(
        np.linalg.norm(g.rodrigues_from_quat(small.as_quat()), axis=-1), small.magnitude(), rtol=1e-7
    )


def test_rotate_vectors_matches_scipy(quats, rng):
    v = rng.normal(size=(M, 3))
    np.testing.assert_allclose(g.rotate_vectors(quats, v), Rotation.from_quat(quats).apply(v), atol=1e-12)


def test_normalise_rejects_zero():
    with pytest.raises(ValueError):
        g.quat_normalise(np.zeros(4))


quat_arrays = arrays(
    np.float64, (4,), elements=st.floats(-1, 1, allow_nan=False)
).filter(lambda q: np.linalg.norm(q) > 1e-3)


@settings(max_examples=200, deadline=None)
@given(quat_arrays, quat_arrays)
def test_sign_invariance_of_errors(a, b):
    a, b = g.quat_normalise(a), g.quat_normalise(b)
    base = g.geodesic_angle(a, b)
    assert g.geodesic_angle(-a, b) == pytest.approx(base, abs=1e-12)
    assert g.geodesic_angle(a, -b) == pytest.approx(base, abs=1e-12)
    np.testing.assert_allclose(g.quat_to_matrix(-a), g.quat_to_matrix(a), atol=1e-12)
    assert np.linalg.norm(g.quat_multiply(a, b)) == pytest.approx(1.0, abs=1e-12)


def test_normalise_scales_each_quaternion_of_a_batch_by_its_own_norm(quats, rng):
    """Each row by its own norm; one zero row in a batch is refused."""
    scales = rng.uniform(0.1, 10.0, (M, 1))
    np.testing.assert_allclose(g.quat_normalise(quats * scales), quats, atol=1e-12)
    batch = quats[:3].copy()
    batch[1] = 0.0  # one zero among unit quaternions
    with pytest.raises(ValueError, match="normalise"):
        g.quat_normalise(batch)


def test_euler_angles_of_a_quaternion_at_exactly_ninety_degrees_pitch_are_finite():
    """Yaw −2 and pitch ±90° give a matrix entry of ∓(1 + 2e−16) from rounding: β is ±π/2, not NaN."""
    for beta in (np.pi / 2, -np.pi / 2):
        rot = Rotation.from_euler("ZYX", [-2.0, beta, 0.0])
        assert abs(g.quat_to_matrix(rot.as_quat())[2, 0]) > 1.0
        angles = g.quat_to_euler_zyx(rot.as_quat())
        np.testing.assert_allclose(angles[:2], [0.0, beta], atol=1e-7)
        np.testing.assert_allclose(g.euler_zyx_to_matrix(angles), rot.as_matrix(), atol=1e-7)


def test_errors_do_not_depend_on_the_scale_of_the_quaternions(quats, rng):
    """Both errors normalise their arguments: non-unit quaternions give those of the rotations."""
    est = Rotation.random(M, random_state=rng).as_quat()
    scale_true, scale_est = rng.uniform(0.2, 5.0, (M, 1)), rng.uniform(0.2, 5.0, (M, 1))
    q_e = Rotation.from_quat(quats) * Rotation.from_quat(est).inv()
    expected = q_e.as_euler("ZYX")[:, ::-1]
    np.testing.assert_allclose(g.euler_error(quats * scale_true, est * scale_est), expected, atol=1e-9)
    angle = (Rotation.from_quat(quats).inv() * Rotation.from_quat(est)).magnitude()
    np.testing.assert_allclose(g.geodesic_angle(quats * scale_true, est * scale_est), angle, atol=1e-12)
