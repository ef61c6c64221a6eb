"""UBiF, UBiGaF and the common motion-filter interface (§5.3, App. E)."""

import dataclasses

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter, unscented_transform
from pyrecest.distributions import BinghamDistribution
from pyrecest.filters import BinghamFilter
from scipy.spatial.transform import Rotation

from uav_landing_vision.filters import bingham, concat_filters, take_filters
from uav_landing_vision.filters.motion import KINDS, MotionFilterConfig, TranslationFilter, make_rotation_filter
from uav_landing_vision.filters.simulation import SIM_CONFIG, Scenario, compare
from uav_landing_vision.filters.ubif import angular_velocity, fuse_angular_velocity
from uav_landing_vision.filters.ubigaf import UBiGaF, bingham_gauss_moments

DT = 0.034
PY = [3, 0, 1, 2]


def test_angular_velocity_matches_scipy():
    rng = np.random.default_rng(0)
    r0 = Rotation.random(20, random_state=1)
    omega = rng.normal(0, 20, (20, 3))
    r1 = r0 * Rotation.from_rotvec(omega * DT)
    expected = (r0.inv() * r1).as_rotvec() / DT
    np.testing.assert_allclose(angular_velocity(r0.as_quat(), -r1.as_quat(), DT), expected, atol=1e-9)
    assert np.all(angular_velocity(r0.as_quat(), r0.as_quat(), DT) == 0.0)


def test_ubif_update_equals_pyrecest_bingham_filter():
    cfg = MotionFilterConfig(rotation_filter="ubif", initial_z=(-40.0,) * 3, measurement_z=(-90.0,) * 3)
    filt = make_rotation_filter(cfg)
    q0, meas = Rotation.random(2, random_state=3).as_quat()
    state = filt.update(filt.init(q0[None], np.zeros((1, 3))), meas[None])
    ref = BinghamFilter()
    ref.filter_state = BinghamDistribution(np.r_[cfg.initial_z, 0.0], bingham.frame(q0)[PY])
    ref.update_identity(BinghamDistribution(np.r_[cfg.measurement_z, 0.0], np.eye(4)[PY]), meas[PY])
    np.testing.assert_allclose(np.sort(state.z[0]), np.asarray(ref.filter_state.Z)[:3], rtol=1e-9)
    est = np.asarray(ref.get_point_estimate())[np.argsort(PY)]
    assert abs(filt.estimate(state)[0][0] @ est) == pytest.approx(1.0)


@pytest.mark.parametrize("kind", KINDS)
def test_prediction_follows_the_angular_velocity_and_spreads(kind):
    rng = np.random.default_rng(4)
    q0 = Rotation.random(6, random_state=5)
    omega = rng.normal(0, 3, (6, 3))
    filt = make_rotation_filter(MotionFilterConfig(rotation_filter=kind))
    state = filt.init(q0.as_quat(), omega)
    cov0 = filt.covariance(state)
    state = filt.predict(state)
    q, w = filt.estimate(state)
    expected = q0 * Rotation.from_rotvec(omega * DT)  # steps of ~0.1 rad
    # The unscented mean carries second-order effects of the ω spread (2 rad/s → ~1e-4 rad).
    assert np.all((Rotation.from_quat(q) * expected.inv()).magnitude() < 1e-3)
    np.testing.assert_allclose(w, omega, atol=1e-9)
    assert np.all(np.trace(filt.covariance(state), axis1=1, axis2=2) > np.trace(cov0, axis1=1, axis2=2))


def test_ubigaf_sigma_points_reproduce_the_bingham_gauss_moments():
    rng = np.random.default_rng(6)
    filt = UBiGaF(DT, (-250.0,) * 3, (-800.0,) * 3, np.full(3, 0.1))
    q = Rotation.random(5, random_state=7).as_quat()
    a = rng.normal(0, 0.1, (5, 6, 6))
    p_r = a @ np.swapaxes(a, 1, 2) + 1e-3 * np.eye(6)  # joint [rotation, ω] covariance, as after an update
    p_q, p_qw = filt.quaternion_moments(q, p_r)
    p_w, m_w = p_r[:, 3:, 3:], rng.normal(0, 2, (5, 3))
    sq, sw, weights = filt.sigma_points(q, m_w, p_w, p_q, p_qw)
    assert np.allclose(weights.sum(axis=1), 1.0) and np.all(weights > 0)
    got = bingham_gauss_moments(sq, sw, weights)
    for g, want in zip(got, (m_w, p_w, p_q, p_qw)):
        np.testing.assert_allclose(g, want, atol=1e-3 * np.abs(want).max())


@pytest.mark.parametrize("kind", KINDS)
def test_predictions_without_an_update_keep_the_mean_angular_velocity(kind):
    """ω is a random walk: its mean must not move however many frames the filter predicts
    without a measurement (the tracker predicts up to 60 Δt across a gap). The UBiGaF's sigma
    points took the conditional mean of ω about zero, not about their own mean quaternion, and
    moved it by 0.26 rad/s after 20 predictions, 8 rad/s after 60."""
    filt = make_rotation_filter(MotionFilterConfig(rotation_filter=kind))
    q0, w0 = Rotation.random(1, random_state=1).as_quat(), np.array([[1.5, -2.0, 0.7]])
    state, truth = filt.init(q0, w0), Rotation.from_quat(q0)
    for _ in range(10):
        truth = truth * Rotation.from_rotvec(w0[0] * DT)
        state = filt.update(filt.predict(state), truth.as_quat())
    before = filt.estimate(state)[1].copy()
    for _ in range(30):
        state = filt.predict(state)
    np.testing.assert_allclose(filt.estimate(state)[1], before, atol=1e-9)


@pytest.mark.parametrize("kind", KINDS)
def test_states_can_be_resampled_and_joined(kind):
    filt = make_rotation_filter(MotionFilterConfig(rotation_filter=kind))
    q = Rotation.random(5, random_state=8).as_quat()
    state = filt.predict(filt.init(q, np.zeros((5, 3))))
    picked = take_filters(state, np.array([4, 4, 0]))
    np.testing.assert_allclose(filt.estimate(picked)[0], filt.estimate(state)[0][[4, 4, 0]])
    fresh = filt.init(q[:2], np.zeros((2, 3)))
    joined = concat_filters([picked, fresh])
    np.testing.assert_allclose(filt.estimate(joined)[0], np.r_[filt.estimate(picked)[0], q[:2] * np.sign(q[:2, 3:])])
    z = q[[4, 4, 0, 0, 1]]
    updated = filt.update(joined, z)  # the fresh part has no predicted sigma points
    np.testing.assert_allclose(filt.estimate(updated)[0][:3], filt.estimate(filt.update(picked, z[:3]))[0], atol=1e-12)


def test_translation_filter_tracks_constant_velocity():
    cfg = MotionFilterConfig(position_measurement_std=1e-3)
    filt = TranslationFilter(cfg)
    vel = np.array([[3.0, -1.0, 0.5]])
    state = filt.init(np.zeros((1, 3)), np.zeros((1, 3)))
    for k in range(1, 60):
        state = filt.update(filt.predict(state), vel * k * cfg.dt)
    pos, v = filt.estimate(state)
    np.testing.assert_allclose(v, vel, atol=0.05)
    np.testing.assert_allclose(pos, vel * 59 * cfg.dt, atol=0.01)


def test_translation_filter_is_the_kalman_filter_of_the_configured_standard_deviations():
    """The model (A.2) is linear, so the UKF is exactly the Kalman filter with ``P0``, ``Q``
    (taken through the model, A.12) and ``R`` the squares of the configured standard deviations."""
    cfg = MotionFilterConfig(position_process_std=0.2, velocity_process_std=0.7, position_measurement_std=0.4,
                             initial_position_std=1.5, initial_velocity_std=3.0)
    filt = TranslationFilter(cfg)
    ref = KalmanFilter(dim_x=6, dim_z=3)
    ref.F = np.block([[np.eye(3), cfg.dt * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])
    ref.H = np.eye(3, 6)
    ref.P = np.diag([1.5**2] * 3 + [3.0**2] * 3)
    ref.Q = ref.F @ np.diag([0.2**2] * 3 + [0.7**2] * 3) @ ref.F.T
    ref.R = 0.4**2 * np.eye(3)
    ref.x = np.array([1.0, -2.0, 30.0, 0.5, 0.0, -4.0])
    state = filt.init(ref.x[None, :3], ref.x[None, 3:])
    for z in np.random.default_rng(13).normal([1.0, -2.0, 29.0], 0.5, (5, 3)):
        ref.predict()
        ref.update(z)
        state = filt.update(filt.predict(state), z[None])
        np.testing.assert_allclose(state.x[0], ref.x, atol=1e-9)
        np.testing.assert_allclose(state.p[0], ref.P, atol=1e-9)


@pytest.mark.parametrize("kind", KINDS)
def test_outlier_aware_update_weighs_a_doubtful_measurement_by_its_inlier_probability(kind):
    """A measurement 0.27 rad off, ε = 0.9: the posterior inlier probability (ours) is, with
    concentrated noises, that of a Gaussian in rotation-vector coordinates (variance −2/z per
    axis of the prior and of the measurement) against the uniform rotation, 1/(8π²) per rad³
    (the Haar measure at small angles), w ≈ 0.52. Each filter moves that share of the thesis
    update's step (the UBiF mixes its scatter matrices by it)."""
    eps, z, delta = 0.9, -800.0, 0.27
    cov = 2 * (-2.0 / z)
    log_n = -0.5 * delta**2 / cov - 1.5 * np.log(2 * np.pi * cov)
    w_expected = 1.0 / (1.0 + eps / (1 - eps) / (8 * np.pi**2) * np.exp(-log_n))
    cfg = MotionFilterConfig(rotation_filter=kind, outlier_prob=eps, initial_z=(z,) * 3, measurement_z=(z,) * 3)
    aware, plain = make_rotation_filter(cfg), make_rotation_filter(dataclasses.replace(cfg, outlier_prob=0.0))
    q0 = Rotation.random(3, random_state=21)
    turn = Rotation.from_rotvec(delta * np.array([[1.0, 0.0, 0.0], [0.0, 0.6, 0.8], [0.0, 0.0, 1.0]]))
    state = aware.init(q0.as_quat(), np.zeros((3, 3)))
    mixed, updated = aware.update(state, (q0 * turn).as_quat()), plain.update(state, (q0 * turn).as_quat())
    if kind == "ubif":
        s0, s1, sw = (bingham.covariance(s.m, s.z).reshape(3, 16) for s in (state, updated, mixed))
        w = np.sum((sw - s0) * (s1 - s0), axis=1) / np.sum((s1 - s0) ** 2, axis=1)
    else:  # the step in the error coordinates, from an unbiased prediction (its mean is q0)
        step = [(Rotation.from_quat(f.estimate(s)[0]) * q0.inv()).magnitude()
                for f, s in ((aware, mixed), (plain, updated))]
        w = step[0] / step[1]
    assert w_expected == pytest.approx(0.52, abs=0.01)
    np.testing.assert_allclose(w, w_expected, atol=0.02)


@pytest.mark.parametrize(
    "change",
    [{"rotation_filter": "kalman"}, {"dt": 0.0}, {"process_z": (-250.0, 1.0, -250.0)}, {"measurement_z": (-1e6,) * 3},
     {"omega_process_std": -1.0}, {"ukf_alpha": 2.0}, {"ukf_kappa": np.inf}, {"ukf_beta": np.inf},
     {"outlier_prob": 1.0}, {"outlier_prob": -0.1}],
)
def test_invalid_configuration_is_an_error(change):
    with pytest.raises(ValueError):
        dataclasses.replace(MotionFilterConfig(), **change)


@pytest.mark.parametrize(
    "change",
    [{"steps": 5, "warm_up": 5}, {"warm_up": -1}, {"runs": 0}, {"flip_prob": 0.6, "outlier_prob": 0.5},
     {"outlier_prob": 0.6, "flip_prob": 0.4}, {"outlier_prob": -0.01}, {"outlier_deg": (90.0, 30.0)},
     {"outlier_deg": (-1.0, 30.0)}, {"outlier_deg": (30.0, 181.0)}],
)
def test_invalid_scenario_is_an_error(change):
    with pytest.raises(ValueError):
        dataclasses.replace(Scenario(), **change)


def test_scenario_accepts_values_at_its_inclusive_bounds():
    """``warm_up`` up to ``steps − 1``, outlier angles over all of [0°, 180°] and outlier plus flip
    probabilities up to (not including) 1."""
    Scenario(runs=1, steps=5, warm_up=4)
    Scenario(outlier_deg=(0.0, 180.0), outlier_prob=0.5, flip_prob=0.49)


def test_filters_under_heavy_tailed_noise_and_their_consistency():
    """Simulated large rotations with outliers and 180° flips (``simulation.compare``).

    Thesis update: all three filters are NEES-consistent when the truth follows their model.
    With 180° flips only the UBiGaF beats the UKF: the UBiF's Bingham product takes the more
    concentrated of two orthogonal modes, and its honest prediction is about as spread as the
    measurement, so it follows a flip whole (README, motion filters). Without flips both
    Bingham filters win. Outlier-aware update (ours): the outliers cost little and all three
    stay NEES-consistent under the heavy tails as well.
    """
    sc = Scenario(runs=24, steps=120)
    res = compare(seed=0, sc=sc)
    low, high = res["nees_band"]
    for kind in KINDS:
        assert low < res[kind]["nominal"]["mean_nees"] < high
    assert res["ubigaf"]["heavy"]["rmse_deg"] < res["ukf"]["heavy"]["rmse_deg"]
    no_flips = compare(seed=0, sc=dataclasses.replace(sc, flip_prob=0.0))
    for kind in ("ubif", "ubigaf"):
        assert no_flips[kind]["heavy"]["rmse_deg"] < no_flips["ukf"]["heavy"]["rmse_deg"]
    aware = compare(seed=0, cfg=dataclasses.replace(SIM_CONFIG, outlier_prob=0.12), sc=sc)
    for kind in KINDS:
        assert low < aware[kind]["heavy"]["mean_nees"] < high
        assert aware[kind]["heavy"]["rmse_deg"] < 1.25 * aware[kind]["nominal"]["rmse_deg"]
        assert aware[kind]["heavy"]["rmse_deg"] < 0.3 * res[kind]["heavy"]["rmse_deg"]


@pytest.mark.parametrize("kind", KINDS)
def test_outlier_aware_update_keeps_the_prediction_on_a_flip_and_takes_an_inlier(kind):
    cfg = MotionFilterConfig(rotation_filter=kind, outlier_prob=0.1)
    q0 = Rotation.random(4, random_state=6)
    aware, plain = make_rotation_filter(cfg), make_rotation_filter(dataclasses.replace(cfg, outlier_prob=0.0))
    state = aware.predict(aware.init(q0.as_quat(), np.zeros((4, 3))))
    flipped = (q0 * Rotation.from_rotvec([[np.pi, 0, 0], [0, np.pi, 0], [0, 0, np.pi], [np.pi, 0, 0]])).as_quat()
    kept = aware.update(state, flipped)
    assert np.all(np.degrees((Rotation.from_quat(aware.estimate(kept)[0]) * q0.inv()).magnitude()) < 0.1)
    np.testing.assert_allclose(aware.covariance(kept), aware.covariance(state), rtol=1e-3, atol=1e-9)
    close = (q0 * Rotation.from_rotvec(np.full((4, 3), 0.02))).as_quat()
    a, b = aware.estimate(aware.update(state, close))[0], plain.estimate(plain.update(state, close))[0]
    assert np.all(np.degrees((Rotation.from_quat(a) * Rotation.from_quat(b).inv()).magnitude()) < 0.01)


def test_fused_angular_velocity_equals_filterpy_kalman_update():
    rng = np.random.default_rng(9)
    a, b = rng.normal(size=(2, 3, 3))
    omega, measured = rng.normal(0, 2, (2, 3))
    omega_cov, measured_cov = a @ a.T + 0.1 * np.eye(3), b @ b.T + 0.1 * np.eye(3)
    fused, cov = fuse_angular_velocity(omega[None], omega_cov[None], measured[None], measured_cov[None])
    ref = KalmanFilter(dim_x=3, dim_z=3)
    ref.x, ref.P, ref.H, ref.R = omega.copy(), omega_cov.copy(), np.eye(3), measured_cov
    ref.update(measured)
    np.testing.assert_allclose(fused[0], ref.x, atol=1e-12)
    np.testing.assert_allclose(cov[0], ref.P, atol=1e-12)


def test_ubif_measures_omega_with_the_noise_of_both_estimates_it_differences():
    """(5.4)–(5.6) difference two estimates Δt apart, so the measured ω's noise is the sum of
    their rotation covariances over Δt² (ours, see ubif.py): the update's ω covariance is then
    filterpy's Kalman update of the predicted one with that noise."""
    filt = make_rotation_filter(MotionFilterConfig(rotation_filter="ubif"))
    q0 = Rotation.random(1, random_state=12)
    start = filt.init(q0.as_quat(), np.array([[0.3, -0.2, 0.1]]))
    predicted = filt.predict(start)
    updated = filt.update(predicted, (q0 * Rotation.from_rotvec([0.01, 0.02, -0.01])).as_quat())
    ref = KalmanFilter(dim_x=3, dim_z=3)
    ref.x, ref.P, ref.H = predicted.omega[0].copy(), predicted.omega_cov[0].copy(), np.eye(3)
    ref.R = (filt.covariance(start)[0] + filt.covariance(updated)[0]) / filt.dt**2
    ref.update(np.zeros(3))
    np.testing.assert_allclose(updated.omega_cov[0], ref.P, rtol=1e-9, atol=1e-12)


def test_ubif_learns_a_constant_angular_velocity_from_its_estimates():
    """ω is not measured directly: the update infers it from successive estimates (5.4)–(5.6)."""
    omega = np.array([[0.8, -1.5, 0.4]])
    q0 = Rotation.random(1, random_state=10)
    filt = make_rotation_filter(MotionFilterConfig(rotation_filter="ubif"))
    state = filt.init(q0.as_quat(), np.zeros((1, 3)))
    spread0 = np.trace(state.omega_cov[0])
    for k in range(1, 80):
        truth = q0 * Rotation.from_rotvec(omega * DT * k)
        state = filt.update(filt.predict(state), truth.as_quat())
    np.testing.assert_allclose(filt.estimate(state)[1], omega, atol=0.05)
    assert np.trace(state.omega_cov[0]) < 0.5 * spread0


def test_ubigaf_update_after_a_prior_wide_about_one_axis_has_no_negative_variance():
    # A prior much wider about one axis than the measurement noise (as after a symmetric-pose
    # confusion): the composition difference of the update's step 4 is then indefinite.
    from uav_landing_vision.filters.ubigaf import UBiGaF

    f = UBiGaF(0.034, (-250.0,) * 3, (-800.0,) * 3, np.full(3, 0.25))
    s = f.init(np.array([[0.0, 0.0, 0.0, 1.0]]), np.zeros((1, 3)), (-800.0,) * 3, np.full(3, 4.0))
    s = dataclasses.replace(s, p_q=bingham.covariance(np.eye(4), np.array([-1e5, -1e5, -0.5]))[None])
    after = f.update(s, np.array([[0.0, 0.0, np.sin(0.3), np.cos(0.3)]]))
    assert np.linalg.eigvalsh(f.covariance(after)[0]).min() >= -1e-12
    assert np.linalg.eigvalsh(after.p_q[0]).min() >= -1e-12


def test_ubigaf_prediction_with_process_noise_far_from_isotropic_does_not_fail():
    # Step 4 widens P_q but not P_qω: with near-uniform noise about one axis the conditional
    # covariance of the sigma points lost definiteness and the Cholesky raised (seed 5, step 73).
    f = make_rotation_filter(MotionFilterConfig(rotation_filter="ubigaf", process_z=(-1.0, -2000.0, -2000.0),
                                                outlier_prob=0.12))
    rng = np.random.default_rng(5)
    truth = Rotation.random(random_state=rng).as_quat()[None].repeat(8, 0)
    s = f.init(truth, np.zeros((8, 3)))
    for _ in range(100):
        s = f.predict(s)
        meas = Rotation.random(8, random_state=rng).as_quat() if rng.uniform() < 0.15 else truth
        s = f.update(s, meas)
    q, _ = f.estimate(s)
    assert np.all(np.isfinite(q)) and np.allclose(np.linalg.norm(q, axis=1), 1.0)
    assert np.linalg.eigvalsh(f.covariance(s)).min() >= -1e-12


@pytest.mark.parametrize("kind", KINDS)
def test_concentrations_with_the_trailing_zero_configure_the_same_filter(kind):
    """``Z = diag(z1, z2, z3, 0)`` given with its 0 is accepted and stored as the three values; the
    UKF (which maps Z to tangent variances) used to fail on it with a reshape error."""
    four = MotionFilterConfig(rotation_filter=kind, process_z=(-250.0, -300.0, -400.0, 0.0),
                              measurement_z=(-800, -900, -1000, 0), initial_z=(-700.0, -700.0, -700.0, 0.0))
    three = MotionFilterConfig(rotation_filter=kind, process_z=(-250.0, -300.0, -400.0),
                               measurement_z=(-800.0, -900.0, -1000.0), initial_z=(-700.0, -700.0, -700.0))
    assert four == three and four.process_z == (-250.0, -300.0, -400.0)
    assert all(type(v) is float for v in four.measurement_z)
    q = Rotation.random(3, random_state=11).as_quat()
    meas = (Rotation.from_quat(q) * Rotation.from_rotvec(np.full((3, 3), 0.05))).as_quat()
    a, b = make_rotation_filter(four), make_rotation_filter(three)
    sa = a.update(a.predict(a.init(q, np.ones((3, 3)))), meas)
    sb = b.update(b.predict(b.init(q, np.ones((3, 3)))), meas)
    np.testing.assert_array_equal(a.estimate(sa)[0], b.estimate(sb)[0])
    np.testing.assert_array_equal(a.covariance(sa), b.covariance(sb))


@pytest.mark.parametrize("kind", KINDS)
def test_a_single_unbatched_filter_equals_a_batch_of_one(kind):
    """States without a batch axis (``quat (4,)``) work with the outlier-aware update too
    (the UBiF's raised on ``np.nonzero`` of a 0-d array)."""
    filt = make_rotation_filter(MotionFilterConfig(rotation_filter=kind, outlier_prob=0.1))
    q = Rotation.random(random_state=12).as_quat()
    meas = (Rotation.from_quat(q) * Rotation.from_rotvec([0.3, -0.2, 0.1])).as_quat()  # partly trusted
    single = filt.update(filt.predict(filt.init(q, np.ones(3))), meas)
    batch = filt.update(filt.predict(filt.init(q[None], np.ones((1, 3)))), meas[None])
    np.testing.assert_allclose(filt.estimate(single)[0], filt.estimate(batch)[0][0], atol=1e-12)
    np.testing.assert_allclose(filt.estimate(single)[1], filt.estimate(batch)[1][0], atol=1e-12)
    np.testing.assert_allclose(filt.covariance(single), filt.covariance(batch)[0], atol=1e-12)


@pytest.mark.parametrize("cls", ["UBiF", "UBiGaF"])
@pytest.mark.parametrize("dt", [np.inf, np.nan, 0.0])
def test_bingham_filters_reject_a_non_finite_time_step(cls, dt):
    from uav_landing_vision.filters import ubif, ubigaf

    filt = {"UBiF": ubif.UBiF, "UBiGaF": ubigaf.UBiGaF}[cls]
    with pytest.raises(ValueError, match="dt"):
        filt(dt, (-250.0,) * 3, (-800.0,) * 3, np.full(3, 0.25))


def _translation_kalman_filter(cfg, x0, sigma):
    """filterpy's Kalman filter of the translation model (A.2) with ``cfg``'s ``P0`` and ``Q`` and
    measurement noise σ² I, started at ``x0``."""
    ref = KalmanFilter(dim_x=6, dim_z=3)
    ref.F = np.block([[np.eye(3), cfg.dt * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])
    ref.H = np.eye(3, 6)
    ref.P = np.diag([cfg.initial_position_std**2] * 3 + [cfg.initial_velocity_std**2] * 3)
    ref.Q = ref.F @ np.diag([cfg.position_process_std**2] * 3 + [cfg.velocity_process_std**2] * 3) @ ref.F.T
    ref.R = sigma**2 * np.eye(3)
    ref.x = np.array(x0, float)
    return ref


@pytest.mark.parametrize("depth, sigma", [(30.0, 0.5), (80.0, 0.8)])
def test_range_fraction_is_the_kalman_filter_of_a_range_grown_measurement_noise(depth, sigma):
    """With ``position_measurement_range_fraction`` 0.01 and σ 0.5 m, R^l is (0.5 m)² until 50 m
    of measured depth and (0.01 · depth)² beyond."""
    cfg = MotionFilterConfig(position_measurement_std=0.5, position_measurement_range_fraction=0.01)
    filt = TranslationFilter(cfg)
    ref = _translation_kalman_filter(cfg, [1.0, -2.0, depth, 0.0, 0.0, 0.0], sigma)
    state = filt.init(np.repeat(ref.x[None, :3], 2, 0), np.zeros((2, 3)))
    for z in np.random.default_rng(14).normal([1.0, -2.0, depth], [0.3, 0.3, 0.0], (5, 3)):
        ref.predict()
        ref.update(z)
        state = filt.update(filt.predict(state), np.broadcast_to(z, (2, 3)))
        np.testing.assert_allclose(state.x, [ref.x, ref.x], atol=1e-9)
        np.testing.assert_allclose(state.p, [ref.P, ref.P], atol=1e-9)


@pytest.mark.parametrize("fraction", [0.01, 0.02])
def test_range_grown_noise_follows_each_particles_own_absolute_measured_depth(fraction):
    """σ = max(std, fraction · |measured depth|) per particle: particles measured about 20, −80 and
    120 m deep, in one batch, update as three Kalman filters of their own σ (a negative depth
    grows the noise as its absolute value does)."""
    std = 0.5
    cfg = MotionFilterConfig(position_measurement_std=std, position_measurement_range_fraction=fraction)
    filt = TranslationFilter(cfg)
    depths = np.array([20.0, -80.0, 120.0])
    x0 = np.stack([np.array([1.0, -2.0, d, 0.0, 0.0, 0.0]) for d in depths])
    refs = [_translation_kalman_filter(cfg, x, std) for x in x0]
    state = filt.init(x0[:, :3].copy(), np.zeros((3, 3)))
    rng = np.random.default_rng(15)
    for _ in range(4):
        z = x0[:, :3] + rng.normal(0.0, 0.4, (3, 3))
        state = filt.update(filt.predict(state), z)
        for i, ref in enumerate(refs):
            ref.predict()
            sigma = max(std, fraction * abs(z[i, 2]))  # the measured depth's share
            ref.update(z[i], R=sigma**2 * np.eye(3))
            np.testing.assert_allclose(state.x[i], ref.x, atol=1e-9, err_msg=f"particle {i}")
            np.testing.assert_allclose(state.p[i], ref.P, atol=1e-9, err_msg=f"particle {i}")


@pytest.mark.parametrize("fraction", [-0.01, float("nan"), float("inf")])
def test_a_negative_or_non_finite_range_fraction_is_refused(fraction):
    with pytest.raises(ValueError, match="position_measurement_range_fraction"):
        MotionFilterConfig(position_measurement_range_fraction=fraction)


def test_ubif_measures_omega_against_the_previous_update_not_the_start():
    """Each prediction stores the estimate it starts from with its rotation covariance: at the
    second update, ω is measured against the first update's estimate, so its noise holds that
    estimate's (narrower) covariance, not the wide one of the start."""
    filt = make_rotation_filter(MotionFilterConfig(rotation_filter="ubif", initial_z=(-20.0, -40.0, -30.0)))
    q0 = Rotation.random(1, random_state=13)
    first = filt.update(filt.predict(filt.init(q0.as_quat(), np.array([[0.3, -0.2, 0.1]]))), q0.as_quat())
    predicted = filt.predict(first)
    meas = (q0 * Rotation.from_rotvec([0.01, -0.02, 0.015])).as_quat()
    second = filt.update(predicted, meas)
    ref = KalmanFilter(dim_x=3, dim_z=3)
    ref.x, ref.P, ref.H = predicted.omega[0].copy(), predicted.omega_cov[0].copy(), np.eye(3)
    ref.R = (filt.covariance(first)[0] + filt.covariance(second)[0]) / filt.dt**2
    ref.update(np.zeros(3))
    np.testing.assert_allclose(second.omega_cov[0], ref.P, rtol=1e-9, atol=1e-12)


def _hamilton(a, b):
    """Hamilton product ``a ⊗ b`` of ``[x, y, z, w]`` quaternions (last axis), written out."""
    ax, ay, az, aw = np.moveaxis(a, -1, 0)
    bx, by, bz, bw = np.moveaxis(b, -1, 0)
    return np.stack([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz], -1)


def test_ubigaf_update_is_the_kalman_update_of_the_propagated_sigma_points():
    """Algorithm 7 runs on the sigma points propagated by the prediction: their tangent
    coordinates ``2·vec(q̄⁻¹ ⊗ x)`` about the predicted mode (x in its hemisphere) and ω give the
    unscented moments, the noise is the tangent image of ``Cov(q ⊗ Λ) − P_q`` (C.7), and the
    result is filterpy's Kalman update, applied to the mode as ``q̄ ⊗ [d/2, √(1 − |d/2|²)]``."""
    filt = UBiGaF(DT, (-300.0, -150.0, -600.0), (-400.0, -900.0, -200.0), np.diag([0.3, 0.1, 0.2]))
    q0 = Rotation.random(1, random_state=21)
    state = filt.init(q0.as_quat(), np.array([[4.0, -3.0, 5.0]]), (-60.0, -200.0, -30.0), np.diag([4.0, 1.0, 2.0]))
    pred = filt.predict(state)
    meas = (q0 * Rotation.from_rotvec([0.05, -0.08, 0.1])).as_quat()
    q_bar = pred.q[0]
    x = pred.sig_q[0] * np.where(pred.sig_q[0] @ q_bar < 0, -1.0, 1.0)[:, None]
    conj = q_bar * np.array([-1.0, -1.0, -1.0, 1.0])
    d = 2.0 * _hamilton(conj, x)[:, :3]
    r_mean, p_rr = unscented_transform(np.hstack([d, pred.sig_w[0]]), pred.weights[0], pred.weights[0])
    # Cov(q ⊗ λ) = Σ_kl C_kl R_k P_q R_lᵀ with R_k q = q ⊗ e_k.
    right = [np.column_stack([_hamilton(e, ek) for e in np.eye(4)]) for ek in np.eye(4)]
    c = filt.measurement_cov
    composed = sum(c[k, l] * right[k] @ pred.p_q[0] @ right[l].T for k in range(4) for l in range(4))
    tangent = np.column_stack([_hamilton(q_bar, e) for e in np.eye(4)[:3]])
    values, vectors = np.linalg.eigh(4.0 * tangent.T @ (composed - pred.p_q[0]) @ tangent)
    ref = KalmanFilter(dim_x=6, dim_z=3)
    ref.x, ref.P, ref.H = r_mean, p_rr, np.hstack([np.eye(3), np.zeros((3, 3))])
    ref.R = vectors @ np.diag(np.maximum(values, 0.0)) @ vectors.T
    z = meas[0] * (1.0 if meas[0] @ q_bar >= 0 else -1.0)
    ref.update(2.0 * _hamilton(conj, z)[:3])
    half = ref.x[:3] / 2.0
    expected = _hamilton(q_bar, np.r_[half, np.sqrt(1.0 - half @ half)])
    updated = filt.update(pred, meas)
    q, omega = filt.estimate(updated)
    np.testing.assert_allclose(q[0], expected * np.sign(expected[3]), atol=1e-10)
    np.testing.assert_allclose(omega[0], ref.x[3:], atol=1e-9)
    np.testing.assert_allclose(updated.p_w[0], ref.P[3:, 3:], atol=1e-9)
