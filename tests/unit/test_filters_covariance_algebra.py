"""Rotation and translation filters checked against first-order covariance algebra, scipy and
hand-made cases: what each prediction and update adds, in which frame, and the configured bounds."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision.filters import bingham
from uav_landing_vision.filters.bingham_table import normaliser_and_moments
from uav_landing_vision.filters.motion import KINDS, MotionFilterConfig, TranslationFilter, make_rotation_filter
from uav_landing_vision.filters.ukf import RotationUKF, TranslationUKF, UnscentedParams

DT = 0.034
# Anisotropic and concentrated, so that a wrong axis, frame or noise term shows and the
# tangent-space (small angle) algebra below holds to a fraction of a percent.
ANISO = dict(dt=DT, initial_z=(-2000.0, -1000.0, -4000.0), process_z=(-3000.0, -1500.0, -6000.0),
             measurement_z=(-500.0, -3000.0, -1500.0), initial_omega_std=0.5, omega_process_std=0.3)


def tangent_variances(z):
    """Rotation-angle variances ``4·E[q_i²]`` of ``P_B(I, diag(z, 0))`` by direct quadrature (not the table)."""
    return np.diag(4.0 * normaliser_and_moments(np.array([z], float))[1][0])


@pytest.mark.parametrize("kind", KINDS)
def test_one_prediction_adds_process_noise_and_dt_squared_angular_velocity_covariance(kind):
    """To first order, one step ``q ⊗ Ω(ωΔt)`` maps the body-frame error covariance ``Σ`` to
    ``Rᵀ Σ R`` (``R`` the rotation ωΔt) and adds ``Δt²(P_ω + Q_ω)`` and the process noise. The
    UKF (A.12) and the UBiGaF (Algorithm 6, step 4) add the process noise before the motion,
    the UBiF after it (Algorithm 4, step 6)."""
    cfg = MotionFilterConfig(rotation_filter=kind, **ANISO)
    filt = make_rotation_filter(cfg)
    q0 = Rotation.random(3, random_state=2).as_quat()
    omega = np.array([0.5, -1.0, 2.0])
    state = filt.init(q0, np.tile(omega, (3, 1)))
    s0, sp = tangent_variances(cfg.initial_z), tangent_variances(cfg.process_z)
    np.testing.assert_allclose(filt.covariance(state), np.broadcast_to(s0, (3, 3, 3)), rtol=0, atol=1e-4 * s0.max())
    r = Rotation.from_rotvec(omega * DT).as_matrix()
    moved = r.T @ s0 @ r + sp if kind == "ubif" else r.T @ (s0 + sp) @ r
    expected = moved + DT**2 * (cfg.initial_omega_std**2 + cfg.omega_process_std**2) * np.eye(3)
    got = filt.covariance(filt.predict(state))
    np.testing.assert_allclose(got, np.broadcast_to(expected, (3, 3, 3)), atol=5e-3 * expected.max(), rtol=0)


@pytest.mark.parametrize("kind", KINDS)
def test_update_combines_prior_and_measurement_noise_in_the_body_frame(kind):
    """A measurement ``q0 ⊗ exp(δ)`` of the prior's mode ``q0``: to first order the posterior
    error covariance is ``(Σ0⁻¹ + Σm⁻¹)⁻¹`` and its mean ``Σpost Σm⁻¹ δ``, with ``Σ0`` and ``Σm`` the
    tangent variances of the initial and the measurement Bingham noise, both about body axes."""
    cfg = MotionFilterConfig(rotation_filter=kind, **ANISO)
    filt = make_rotation_filter(cfg)
    q0 = Rotation.random(3, random_state=2)
    delta = np.array([0.02, -0.01, 0.015])
    state = filt.init(q0.as_quat(), np.zeros((3, 3)))
    updated = filt.update(state, (q0 * Rotation.from_rotvec(np.tile(delta, (3, 1)))).as_quat())
    s0, sm = tangent_variances(cfg.initial_z), tangent_variances(cfg.measurement_z)
    post = np.linalg.inv(np.linalg.inv(s0) + np.linalg.inv(sm))
    np.testing.assert_allclose(filt.covariance(updated), np.broadcast_to(post, (3, 3, 3)), atol=1e-2 * post.max(), rtol=0)
    step = (q0.inv() * Rotation.from_quat(filt.estimate(updated)[0])).as_rotvec()
    mean = post @ np.linalg.solve(sm, delta)
    np.testing.assert_allclose(step, np.tile(mean, (3, 1)), atol=1e-2 * np.abs(mean).max(), rtol=0)


def test_rotation_ukf_estimate_applies_the_mean_error_parameters_to_the_reference():
    """Between updates the error state keeps a mean ``d ≠ 0``; the estimate is ``q ⊗ R⁻¹(d)``,
    with ``d = 4·MRP`` (a = 1, f = 4) read by scipy."""
    ukf = RotationUKF(DT, np.full(6, 1e-4), np.full(3, 1e-2))
    q0 = Rotation.random(2, random_state=1)
    p0 = np.diag([0.3, 0.1, 0.2, 25.0, 16.0, 9.0])
    state = ukf.predict(ukf.init(q0.as_quat(), np.tile([8.0, -5.0, 3.0], (2, 1)), p0))
    assert np.all(np.linalg.norm(state.x[:, :3], axis=1) > 5e-4)  # a noticeable mean error
    expected = Rotation.from_quat(state.q) * Rotation.from_mrp(state.x[:, :3] / 4.0)
    got = Rotation.from_quat(ukf.estimate(state)[0])
    assert np.all((got * expected.inv()).magnitude() < 1e-12)


def test_ukf_prediction_adds_the_configured_angular_velocity_variance():
    """The UKF's ``Q^ω`` is ``omega_process_std²`` per axis: ``P_ω`` grows by exactly that."""
    cfg = MotionFilterConfig(rotation_filter="ukf", initial_omega_std=0.5, omega_process_std=0.3)
    filt = make_rotation_filter(cfg)
    state = filt.init(Rotation.random(2, random_state=3).as_quat(), np.zeros((2, 3)))
    np.testing.assert_allclose(state.p[:, 3:, 3:], np.broadcast_to(0.25 * np.eye(3), (2, 3, 3)), atol=1e-15)
    predicted = filt.predict(state)
    np.testing.assert_allclose(predicted.p[:, 3:, 3:], np.broadcast_to(0.34 * np.eye(3), (2, 3, 3)), atol=1e-12)


@pytest.mark.parametrize("kind", ["ubif", "ubigaf"])
def test_bingham_filters_add_the_angular_velocity_random_walk_at_each_prediction(kind):
    """ω is a random walk: each prediction adds ``omega_process_std²`` per axis to its covariance."""
    cfg = MotionFilterConfig(rotation_filter=kind, initial_omega_std=0.5, omega_process_std=0.3)
    filt = make_rotation_filter(cfg)
    state = filt.init(Rotation.random(2, random_state=3).as_quat(), np.zeros((2, 3)))
    for k in range(1, 4):
        state = filt.predict(state)
        cov = state.omega_cov if kind == "ubif" else state.p_w
        np.testing.assert_allclose(cov, np.broadcast_to((0.25 + k * 0.09) * np.eye(3), (2, 3, 3)), atol=1e-9)


def test_unscented_parameter_bounds_are_inclusive():
    """β and κ may be 0 to 100 inclusive; a negative β (a negative central covariance weight
    beyond what α allows) and anything above 100 are refused."""
    UnscentedParams(alpha=1.0, beta=100.0, kappa=100.0)
    UnscentedParams(alpha=1e-3, beta=0.0, kappa=0.0)
    for bad in ({"beta": -0.5}, {"beta": 100.5}, {"kappa": 100.5}, {"alpha": 1.0 + 1e-9}):
        with pytest.raises(ValueError):
            UnscentedParams(**bad)


def test_time_step_bound_is_ten_seconds_inclusive():
    TranslationUKF(10.0, np.ones(6), np.ones(3))
    RotationUKF(10.0, np.ones(6), np.ones(3))
    for dt in (10.001, 0.0):
        with pytest.raises(ValueError, match="dt"):
            TranslationUKF(dt, np.ones(6), np.ones(3))


@pytest.mark.parametrize("name", ["omega_process_std", "initial_omega_std", "position_process_std",
                                  "velocity_process_std", "position_measurement_std", "initial_position_std",
                                  "initial_velocity_std"])
def test_standard_deviations_are_bounded_by_a_thousand(name):
    dataclasses.replace(MotionFilterConfig(), **{name: 1e3})
    for bad in (1e3 * (1 + 1e-9), 0.0, np.inf, np.nan):
        with pytest.raises(ValueError, match=name):
            dataclasses.replace(MotionFilterConfig(), **{name: bad})


def test_range_fraction_of_one_is_accepted():
    filt = TranslationFilter(MotionFilterConfig(position_measurement_range_fraction=1.0))
    state = filt.update(filt.predict(filt.init(np.zeros((1, 3)), np.zeros((1, 3)))), np.array([[0.0, 0.0, 2.0]]))
    assert np.all(np.isfinite(state.x))
    with pytest.raises(ValueError, match="position_measurement_range_fraction"):
        MotionFilterConfig(position_measurement_range_fraction=1.0 + 1e-9)


def test_outlier_aware_ubif_mixes_the_angular_velocity_with_the_inlier_probability():
    """ε > 0: the UBiF's ω posterior is the two-component mixture ``w·fused + (1 − w)·predicted``
    (mean, and covariance with the spread of the means), with the same inlier probability ``w``
    as its orientation (read off the mixed second moments)."""
    cfg = MotionFilterConfig(rotation_filter="ubif", outlier_prob=0.9, initial_z=(-800.0,) * 3,
                             measurement_z=(-800.0,) * 3)
    aware, plain = make_rotation_filter(cfg), make_rotation_filter(dataclasses.replace(cfg, outlier_prob=0.0))
    q0 = Rotation.random(3, random_state=21)
    turn = Rotation.from_rotvec(0.27 * np.array([[1.0, 0.0, 0.0], [0.0, 0.6, 0.8], [0.0, 0.0, 1.0]]))
    state = aware.init(q0.as_quat(), np.tile([0.3, -0.2, 0.1], (3, 1)))
    mixed, updated = aware.update(state, (q0 * turn).as_quat()), plain.update(state, (q0 * turn).as_quat())
    s0, s1, sw = (bingham.covariance(s.m, s.z).reshape(3, 16) for s in (state, updated, mixed))
    w = np.sum((sw - s0) * (s1 - s0), axis=1) / np.sum((s1 - s0) ** 2, axis=1)
    assert np.all((w > 0.3) & (w < 0.7))  # a doubtful measurement: both components matter
    d = updated.omega - state.omega
    assert np.all(np.linalg.norm(d, axis=1) > 1.0)  # the fused ω moved by several rad/s
    np.testing.assert_allclose(mixed.omega, state.omega + w[:, None] * d, atol=1e-3 * np.abs(d).max())
    wc = w[:, None, None]
    cov = wc * updated.omega_cov + (1 - wc) * state.omega_cov + wc * (1 - wc) * d[:, :, None] * d[:, None, :]
    np.testing.assert_allclose(mixed.omega_cov, cov, atol=2e-3 * np.abs(cov).max())


def test_outlier_aware_ubif_keeps_the_predicted_angular_velocity_on_a_half_turn():
    cfg = MotionFilterConfig(rotation_filter="ubif", outlier_prob=0.1)
    filt = make_rotation_filter(cfg)
    q0 = Rotation.random(3, random_state=6)
    state = filt.predict(filt.init(q0.as_quat(), np.tile([0.3, -0.2, 0.1], (3, 1))))
    flipped = (q0 * Rotation.from_rotvec(np.pi * np.eye(3))).as_quat()
    kept = filt.update(state, flipped)
    np.testing.assert_allclose(kept.omega, state.omega, atol=1e-6)
    np.testing.assert_allclose(kept.omega_cov, state.omega_cov, atol=1e-6)


def test_ubif_update_of_two_concentrated_densities_stays_within_the_table():
    """A prior and a measurement noise each near the table's limit: their product (C.3) is
    more concentrated than the table covers and is held at its edge, not an error."""
    z_max = bingham.max_concentration()
    cfg = MotionFilterConfig(rotation_filter="ubif", initial_z=(-0.9 * z_max,) * 3,
                             measurement_z=(-0.8 * z_max, -0.9 * z_max, -0.7 * z_max))
    filt = make_rotation_filter(cfg)
    q0 = Rotation.random(2, random_state=8)
    state = filt.init(q0.as_quat(), np.zeros((2, 3)))
    meas = (q0 * Rotation.from_rotvec([[1e-3, 0.0, 0.0], [0.0, -1e-3, 5e-4]])).as_quat()
    updated = filt.update(state, meas)
    np.testing.assert_allclose(updated.z, -z_max, rtol=1e-9)
    q, omega = filt.estimate(updated)
    assert np.all(np.isfinite(q)) and np.all(np.isfinite(omega))
    # the mode lies between prior and measurement, by their (similar) concentrations
    assert np.all((Rotation.from_quat(q) * q0.inv()).magnitude() < 1e-3)


def test_ubigaf_sigma_points_reproduce_the_moments_after_predictions_without_an_update():
    """After predictions without a measurement the mean of the sigma points' quaternions is not
    the zero of the antipodal density, so the conditional covariance is taken about it: the
    points still reproduce ``m_ω`` (E.19), ``P_ω`` (E.20) and ``P_q`` (E.21)."""
    from uav_landing_vision.filters.ubigaf import bingham_gauss_moments

    filt = make_rotation_filter(MotionFilterConfig(rotation_filter="ubigaf"))
    q0, w0 = Rotation.random(2, random_state=1).as_quat(), np.array([[1.5, -2.0, 0.7], [0.2, 0.4, -3.0]])
    state = filt.init(q0, w0)
    for _ in range(20):
        state = filt.predict(state)
    sq, sw, weights = filt.sigma_points(state.q, state.m_w, state.p_w, state.p_q, state.p_qw)
    got = bingham_gauss_moments(sq, sw, weights)
    for g, want in zip(got[:3], (state.m_w, state.p_w, state.p_q)):
        np.testing.assert_allclose(g, want, rtol=0, atol=1e-9 * np.abs(want).max())


def test_ubigaf_update_with_wide_prior_and_wide_measurement_noise_returns_unit_quaternions():
    """With a prior nearly uniform about one axis (a symmetric-pose confusion) and a measurement
    noise wide about another, the Kalman step in tangent coordinates can exceed the length a
    quaternion's vector part can have (|d/2| > 1); the error quaternion is then taken along its
    direction and the estimate and its moments stay unit and finite."""
    from uav_landing_vision.filters.ubigaf import UBiGaF

    filt = UBiGaF(DT, (-250.0,) * 3, (-150.0, -800.0, -3.0), np.full(3, 0.25))
    rng = np.random.default_rng(1)
    q = Rotation.random(400, random_state=rng).as_quat()
    omega = rng.normal(0, 2, (400, 3))
    state = filt.predict(filt.init(q, omega, (-3000.0, -250.0, -0.6), np.full(3, 4.0)))
    updated = filt.update(state, Rotation.random(400, random_state=rng).as_quat())
    est, w = filt.estimate(updated)
    np.testing.assert_allclose(np.linalg.norm(est, axis=1), 1.0, rtol=0, atol=1e-12)
    assert np.all(np.isfinite(w)) and np.all(np.isfinite(updated.p_q))
    np.testing.assert_allclose(np.trace(updated.p_q, axis1=1, axis2=2), 1.0, atol=1e-9)  # E[q qᵀ] of unit q


def test_ubigaf_predicted_mode_is_the_principal_eigenvector_of_the_predicted_second_moment():
    """(C.15): the Bingham part's mode is the principal eigenvector of ``P_q``; with a spread ω
    it differs from the propagated central sigma point by about 1e-3 rad."""
    filt = make_rotation_filter(MotionFilterConfig(rotation_filter="ubigaf", process_z=(-1.0, -2000.0, -2000.0)))
    q0 = Rotation.random(20, random_state=3).as_quat()
    state = filt.predict(filt.init(q0, np.random.default_rng(0).normal(0, 3, (20, 3))))
    principal = np.linalg.eigh(state.p_q)[1][:, :, 3]
    np.testing.assert_allclose(np.abs(np.sum(principal * state.q, axis=1)), 1.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(state.q, axis=1), 1.0, atol=1e-12)


def test_ubigaf_propagated_sigma_points_share_the_hemisphere_of_the_central_one():
    """(C.17): with a nearly uniform spread about one axis and a wide ω, propagated points cross
    into the other hemisphere; each is taken there as its antipode so that ``P_qω`` keeps its sign."""
    from uav_landing_vision.filters.ubigaf import UBiGaF, bingham_gauss_moments

    filt = UBiGaF(DT, (-1.0, -2000.0, -2000.0), (-800.0,) * 3, np.full(3, 100.0))
    rng = np.random.default_rng(0)
    state = filt.init(Rotation.random(50, random_state=1).as_quat(), rng.normal(0, 20, (50, 3)),
                      (-0.3, -0.3, -2000.0), np.full(3, 900.0))
    predicted = filt.predict(state)
    assert np.all(np.sum(predicted.sig_q * predicted.sig_q[:, 12:13, :], axis=-1) >= 0.0)
    assert np.all(np.sum(predicted.q * predicted.sig_q[:, 12, :], axis=-1) >= 0.0)
    moments = bingham_gauss_moments(predicted.sig_q, predicted.sig_w, predicted.weights)
    np.testing.assert_allclose(moments[3], predicted.p_qw, atol=1e-12)


def test_negative_variances_are_set_to_zero_and_the_others_kept():
    from uav_landing_vision.filters.ubigaf import _without_negative_variance

    rot = Rotation.random(2, random_state=4).as_matrix()
    values = np.array([[-0.3, 0.2, 1.5], [0.1, 0.2, 0.3]])
    cov = rot @ (values[:, :, None] * np.swapaxes(rot, 1, 2))
    out = _without_negative_variance(cov)
    np.testing.assert_allclose(out[0], rot[0] @ np.diag([0.0, 0.2, 1.5]) @ rot[0].T, atol=1e-14)
    np.testing.assert_array_equal(out[1], cov[1])
