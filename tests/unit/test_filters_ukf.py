"""Unscented Kalman filters of Appendix A against filterpy and scipy."""

import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter, unscented_transform
from scipy.spatial.transform import Rotation

from uav_landing_vision.filters.ukf import RotationUKF, TranslationUKF, UnscentedParams

DT = 0.034


@pytest.mark.parametrize("params", [UnscentedParams(), UnscentedParams(alpha=0.5, beta=2.0, kappa=1.0)])
def test_translation_ukf_equals_filterpy(params):
    rng = np.random.default_rng(0)
    m = 4
    q = np.diag([0.01, 0.02, 0.03, 0.3, 0.2, 0.1])
    r = np.diag([0.5, 0.4, 0.3])
    p0 = np.diag([1.0, 1.0, 2.0, 4.0, 4.0, 4.0])
    ukf = TranslationUKF(DT, q, r, params)
    pos, vel = rng.normal(0, 10, (m, 3)), rng.normal(0, 2, (m, 3))
    state = ukf.init(pos, vel, p0)
    f = np.block([[np.eye(3), DT * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])  # constant velocity (A.1)
    refs = []
    for i in range(m):
        pts = MerweScaledSigmaPoints(6, alpha=params.alpha, beta=params.beta, kappa=params.kappa)
        ref = UnscentedKalmanFilter(6, 3, DT, hx=lambda x: x[:3], fx=lambda x, dt: f @ x, points=pts)
        ref.x, ref.P = np.r_[pos[i], vel[i]], p0.copy()
        # (A.12) puts Q into the sigma points before the model, filterpy adds it after: F Q Fᵀ.
        ref.Q, ref.R = f @ q @ f.T, r
        refs.append(ref)
    for _ in range(20):
        z = rng.normal(0, 10, (m, 3))
        state = ukf.update(ukf.predict(state), z)
        for i, ref in enumerate(refs):
            ref.predict()
            ref.update(z[i])
            np.testing.assert_allclose(state.x[i], ref.x, atol=1e-9, rtol=0)
            np.testing.assert_allclose(state.p[i], ref.P, atol=1e-9, rtol=0)


@pytest.mark.parametrize("params", [UnscentedParams(), UnscentedParams(alpha=0.5, beta=2.0, kappa=1.0)])
def test_rotation_ukf_equals_filterpy_on_the_error_state(params):
    """filterpy runs ``[d, ω]`` about a reference that moves with the central sigma point (A.3),
    (A.8) and is reset by the update (A.9); rotations and ``d = 4·MRP`` (a = 1, f = 4) by scipy."""
    rng = np.random.default_rng(4)
    q = np.diag([1e-3, 2e-3, 3e-3, 0.5, 0.3, 0.2])
    r = np.diag([0.01, 0.02, 0.015])
    p0 = np.diag([0.05, 0.02, 0.03, 1.0, 2.0, 0.5])
    ukf = RotationUKF(DT, q, r, params)
    q0, w0 = Rotation.random(random_state=5), rng.normal(0, 3, 3)
    state = ukf.init(q0.as_quat()[None], w0[None], p0)
    ref_q = q0
    pts = MerweScaledSigmaPoints(6, alpha=params.alpha, beta=params.beta, kappa=params.kappa)
    ref = UnscentedKalmanFilter(6, 3, DT, hx=lambda x: x[:3], fx=None, points=pts)
    ref.x, ref.P, ref.Q, ref.R = np.r_[np.zeros(3), w0], p0.copy(), np.zeros((6, 6)), r

    def moved(ref_q, x):
        return ref_q * Rotation.from_mrp(x[:3] / 4) * Rotation.from_rotvec(x[3:] * DT)

    for _ in range(15):
        new_q = moved(ref_q, ref.x)
        ref.P = ref.P + q  # (A.12): Q before the sigma points
        # filterpy's predict redraws the sigma points afterwards; (A.22) reuses the propagated ones.
        ref.compute_process_sigmas(DT, lambda x, dt: np.r_[4 * (new_q.inv() * moved(ref_q, x)).as_mrp(), x[3:]])
        ref.x, ref.P = unscented_transform(ref.sigmas_f, ref.Wm, ref.Wc)
        z = new_q * Rotation.from_rotvec(rng.normal(0, 0.1, 3))
        ref.update(4 * (new_q.inv() * z).as_mrp())
        ref_q, ref.x[:3] = new_q * Rotation.from_mrp(ref.x[:3] / 4), 0.0

        state = ukf.update(ukf.predict(state), z.as_quat()[None])
        assert (Rotation.from_quat(state.q[0]) * ref_q.inv()).magnitude() < 1e-9
        np.testing.assert_allclose(state.x[0], ref.x, atol=1e-9, rtol=0)
        np.testing.assert_allclose(state.p[0], ref.P, atol=1e-9, rtol=0)


def test_rotation_ukf_prediction_follows_the_angular_velocity():
    rng = np.random.default_rng(1)
    q0 = Rotation.random(5, random_state=2)
    omega = rng.normal(0, 3, (5, 3))
    ukf = RotationUKF(DT, np.full(6, 1e-12), np.full(3, 1e-2))
    state = ukf.init(q0.as_quat(), omega, np.full(6, 1e-12))
    for _ in range(10):
        state = ukf.predict(state)
    q, w = ukf.estimate(state)
    expected = q0 * Rotation.from_rotvec(omega * DT * 10)  # body-frame rate (3.12)
    assert np.all((Rotation.from_quat(q) * expected.inv()).magnitude() < 1e-7)
    np.testing.assert_allclose(w, omega, atol=1e-9)


def test_rotation_ukf_update_moves_towards_the_measurement_and_resets():
    q0 = Rotation.from_euler("z", 0.0).as_quat()
    meas = Rotation.from_euler("z", 0.2).as_quat()
    p = np.r_[np.full(3, 0.01), np.full(3, 1e-6)]
    ukf = RotationUKF(DT, np.full(6, 1e-12), np.full(3, 0.01))
    state = ukf.update(ukf.init(q0[None], np.zeros((1, 3)), p), meas[None])
    angle = Rotation.from_quat(state.q[0]).as_rotvec()
    # Equal prior and measurement variances: about half-way (Rodrigues ≈ angle for small angles).
    assert angle[2] == pytest.approx(0.1, abs=2e-3) and np.allclose(angle[:2], 0.0, atol=1e-12)
    assert np.all(state.x[:, :3] == 0.0)
    assert state.p[0, 2, 2] == pytest.approx(0.005, rel=1e-3)


def test_invalid_parameters_are_errors():
    with pytest.raises(ValueError):
        UnscentedParams(alpha=0.0)
    with pytest.raises(ValueError):
        UnscentedParams(kappa=-1.0)
    with pytest.raises(ValueError):
        TranslationUKF(DT, np.full(6, -1.0), np.ones(3))
    with pytest.raises(ValueError):
        TranslationUKF(0.0, np.ones(6), np.ones(3))
    with pytest.raises(ValueError):
        RotationUKF(DT, np.ones(5), np.ones(3))
    with pytest.raises(ValueError, match="positive definite"):
        TranslationUKF(DT, np.ones(6), np.array([1.0, 1.0, 0.0]))  # singular
    with pytest.raises(ValueError, match="symmetric"):
        TranslationUKF(DT, np.ones(6), np.eye(3) + np.diag([0.1, 0.1], k=1))


@pytest.mark.parametrize("change", [{"kappa": np.inf}, {"beta": np.inf}, {"beta": np.nan}, {"beta": 1e60}])
def test_non_finite_or_huge_unscented_parameters_are_errors(change):
    """An infinite κ or β made every sigma-point weight NaN; β = 1e60 made the filters' matrices singular."""
    with pytest.raises(ValueError, match="beta and kappa must be within 0 to 100"):
        UnscentedParams(**change)


@pytest.mark.parametrize("dt", [np.inf, np.nan, -0.01, 1e155])  # 1e155: its square overflowed in the UBiF
def test_non_finite_or_negative_time_steps_are_errors(dt):
    """An infinite Δt made the transition matrix (A.2) and every prediction NaN."""
    with pytest.raises(ValueError, match="dt"):
        TranslationUKF(dt, np.ones(6), np.ones(3))
    with pytest.raises(ValueError, match="dt"):
        RotationUKF(dt, np.ones(6), np.ones(3))


def test_asymmetry_of_a_small_covariance_is_an_error():
    """The symmetry check was absolute (1e-8): at 1e-9 scale it let through a matrix whose
    symmetric part is indefinite (eigenvalues −4e-9, 1e-9, 6e-9), while the definiteness check
    reads only the lower triangle (here diagonal)."""
    r = np.array([[1e-9, 5e-9, 0.0], [0.0, 1e-9, 0.0], [0.0, 0.0, 1e-9]])
    with pytest.raises(ValueError, match="symmetric"):
        TranslationUKF(DT, np.ones(6), r)
    ukf = TranslationUKF(DT, np.ones(6) * 1e-12, 0.5 * (r + r.T) + 5e-9 * np.eye(3))  # symmetric, tiny: accepted
    np.testing.assert_array_equal(ukf.r, 0.5 * (r + r.T) + 5e-9 * np.eye(3))
