"""The per-particle motion filters of C3–C5 (tracking/motion_bank.py): the measurement update of
§5.2.3 and recentring onto a pose, against hand-made oracles."""

import copy
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision.filters.motion import MotionFilterConfig
from uav_landing_vision.geometry import geodesic_angle
from uav_landing_vision.tracking.motion_bank import MotionBank
from uav_landing_vision.tracking.optimisation import rotate_body

TRUE_QUAT = Rotation.from_euler("ZYX", [30.0, -10.0, 5.0], degrees=True).as_quat()
TRUE_POS = np.array([0.4, -0.3, 12.0])


def hamilton(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a ⊗ b of [x, y, z, w] quaternions, written out."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz])


def right_product_matrix(delta: np.ndarray) -> np.ndarray:
    """The 4×4 matrix R with R q = q ⊗ delta for every q."""
    return np.column_stack([hamilton(e, delta) for e in np.eye(4)])


def moving_bank(kind: str, m: int = 6, seed: int = 0) -> MotionBank:
    """``m`` filters of ``kind`` spread about the truth, turning at 1–2 rad/s, predicted 3 Δt on."""
    rng = np.random.default_rng(seed)
    bank = MotionBank(MotionFilterConfig(rotation_filter=kind))
    quat = rotate_body(np.tile(TRUE_QUAT, (m, 1)), rng.normal(size=(m, 3)) * 0.2)
    bank.init(TRUE_POS + rng.normal(size=(m, 3)) * 0.3, quat)
    bank.predict()
    bank.update(TRUE_POS, TRUE_QUAT)  # velocities and correlations become non-trivial
    bank.predict(3)
    return bank


def test_hamilton_product_agrees_with_scipy():
    rng = np.random.default_rng(1)
    for a, b in Rotation.random(20, random_state=2).as_quat().reshape(10, 2, 4):
        expected = (Rotation.from_quat(a) * Rotation.from_quat(b)).as_quat()
        got = hamilton(a, b)
        assert abs(abs(got @ expected) - 1.0) < 1e-12
        q = rng.normal(size=4)
        np.testing.assert_allclose(right_product_matrix(b) @ q, hamilton(q, b), atol=1e-12)


@pytest.mark.parametrize("kind", ["ukf", "ubif", "ubigaf"])
def test_the_measurement_update_pulls_both_the_position_and_the_rotation_of_every_filter_towards_z(kind):
    """§5.2.3: every filter is updated with the one measurement z_t, in translation (UKF) and in
    rotation (UKF / UBiF / UBiGaF): each estimate ends closer to z_t than its prediction was."""
    bank = moving_bank(kind)
    z_pos = TRUE_POS + np.array([0.5, -0.4, 1.0])
    z_quat = rotate_body(TRUE_QUAT[None], np.radians([[12.0, -8.0, 6.0]]))[0]
    pos0, _, quat0, _ = bank.estimates()
    bank.update(z_pos, z_quat)
    pos1, _, quat1, _ = bank.estimates()
    assert np.all(np.linalg.norm(pos1 - z_pos, axis=1) < 0.9 * np.linalg.norm(pos0 - z_pos, axis=1))
    assert np.all(geodesic_angle(quat1, z_quat) < 0.9 * geodesic_angle(quat0, z_quat))


def test_ukf_recentring_after_a_prediction_puts_the_estimate_on_the_given_rotation():
    """The rotational UKF's estimate is q ⊗ R⁻¹(d); after a prediction (no update) its error d is
    not zero, so recentring must reset d as well as q for the estimate to be the given rotation."""
    bank = moving_bank("ukf")
    assert np.abs(bank.rot_state.x[:, :3]).max() > 1e-5  # a predicted filter carries an error d
    rng = np.random.default_rng(3)
    target_q = rotate_body(np.tile(TRUE_QUAT, (6, 1)), rng.normal(size=(6, 3)) * 0.1)
    target_p = TRUE_POS + rng.normal(size=(6, 3))
    bank.recentre(target_p, target_q)
    pos, _, quat, _ = bank.estimates()
    np.testing.assert_allclose(pos, target_p, atol=1e-12)
    assert np.degrees(geodesic_angle(quat, target_q)).max() < 1e-7


def test_ubigaf_recentring_turns_the_whole_joint_distribution_by_the_body_rotation():
    """(C.4): moving the mode by δ = q̂⁻¹ ⊗ q is the linear map q ↦ q ⊗ δ = R(δ) q on the attitude
    part of the joint [q, ω] moments: P_q ↦ R P_q Rᵀ, P_qω ↦ R P_qω; ω's moments stay."""
    bank = moving_bank("ubigaf")
    before = copy.deepcopy(bank.rot_state)
    rng = np.random.default_rng(4)
    target = rotate_body(before.q, rng.normal(size=(6, 3)) * 0.3)
    target[::2] *= -1.0  # either sign of a target is the same rotation
    bank.recentre(bank.estimates()[0], target)
    after = bank.rot_state
    for k in range(6):
        assert abs(abs(after.q[k] @ target[k]) - 1.0) < 1e-12  # the mode is the target, ±q alike
        delta = hamilton(before.q[k] * np.array([-1, -1, -1, 1.0]), after.q[k])  # in the mode's own hemisphere
        r = right_product_matrix(delta)
        np.testing.assert_allclose(after.p_q[k], r @ before.p_q[k] @ r.T, atol=1e-12)
        np.testing.assert_allclose(after.p_qw[k], r @ before.p_qw[k], atol=1e-12)
        np.testing.assert_array_equal(after.m_w[k], before.m_w[k])
        np.testing.assert_array_equal(after.p_w[k], before.p_w[k])
    assert np.abs(before.p_qw).max() > 1e-4  # the correlation is there to be turned
