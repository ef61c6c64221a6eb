"""The simulated orientation tracks behind the rotation filters' comparison (``filters.simulation``):
the truth follows the model q ⊗ Ω(ω) ⊗ Φ in the body frame, the measurements' inliers, outliers
and flips are what they claim to be, and the scores are computed as documented.

Rotations are checked with scipy's Rotation; Bingham second moments come from the quadrature of
``bingham_table`` (checked against an independent integration in test_filters_bingham.py).
"""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision.filters import simulation
from uav_landing_vision.filters.bingham_table import normaliser_and_moments
from uav_landing_vision.filters.motion import MotionFilterConfig
from uav_landing_vision.filters.simulation import Scenario, compare, run_filters, simulate

NO_OUTLIERS = {"outlier_prob": 0.0, "flip_prob": 0.0}


def _body_errors(a, b):
    """Rotations a⁻¹·b (body frame of a) of quaternion arrays ``(..., 4)`` as scipy Rotations."""
    a, b = a.reshape(-1, 4), b.reshape(-1, 4)
    return Rotation.from_quat(a).inv() * Rotation.from_quat(b)


def _second_moments(z):
    return normaliser_and_moments(np.asarray([z], float))[1][0]


class _RecordedNormals:
    """A seeded generator whose ``normal(loc, scale, size)`` is ``loc + scale · u`` with the standard
    draws ``u`` recorded; every other method is the seeded generator's own."""

    def __init__(self, seed):
        self._rng = np.random.default_rng(seed)
        self.units = []

    def normal(self, loc=0.0, scale=1.0, size=None):
        u = self._rng.standard_normal(size)
        self.units.append(u)
        return loc + scale * u

    def __getattr__(self, name):
        return getattr(self._rng, name)


def test_measurement_inliers_are_body_frame_bingham_noise_of_measurement_z():
    """Without outliers, truth⁻¹·measurement has the second moments E[e_i²] of Bingham(I, Z^Λ)."""
    z = (-500.0, -2000.0, -5000.0)
    cfg = MotionFilterConfig(measurement_z=z, process_z=(-300.0, -300.0, -300.0))
    truth, meas, flags = simulate(cfg, Scenario(runs=50, steps=80, **NO_OUTLIERS), np.random.default_rng(0))
    assert not flags.any()
    err = _body_errors(truth, meas).as_quat()
    np.testing.assert_allclose((err[:, :3] ** 2).mean(axis=0), _second_moments(z), rtol=0.12)


def test_truth_increments_are_body_frame_bingham_process_noise_when_omega_is_still():
    """With ω ≈ 0, q_t⁻¹·q_{t+1} = Φ_t: the second moments of Bingham(I, Z^Φ), axis by axis."""
    z = (-300.0, -1200.0, -4800.0)
    cfg = MotionFilterConfig(process_z=z, measurement_z=(-5000.0, -2000.0, -500.0),
                             initial_omega_std=1e-9, omega_process_std=1e-9)
    truth, _, _ = simulate(cfg, Scenario(runs=50, steps=41, **NO_OUTLIERS), np.random.default_rng(1))
    inc = _body_errors(truth[:-1], truth[1:]).as_quat()
    np.testing.assert_allclose((inc[:, :3] ** 2).mean(axis=0), _second_moments(z), rtol=0.12)


def test_truth_turns_by_the_body_frame_angular_velocity_of_a_random_walk():
    """(3.12) with Φ nearly the identity: each step q_t⁻¹·q_{t+1} is the rotation vector ω_t Δt, with
    ω_0 = initial_omega_std · u_0 and ω_{t+1} = ω_t + omega_process_std · u_{t+1} from the
    generator's standard normal draws u."""
    cfg = MotionFilterConfig(process_z=(-1e5,) * 3, initial_omega_std=1.5, omega_process_std=0.4)
    rng = _RecordedNormals(3)
    truth, _, _ = simulate(cfg, Scenario(runs=5, steps=40, warm_up=0, **NO_OUTLIERS), rng)
    np.testing.assert_allclose(np.linalg.norm(truth, axis=-1), 1.0, atol=1e-12)
    scaled = [cfg.initial_omega_std * rng.units[0]] + [cfg.omega_process_std * u for u in rng.units[1:]]
    omega = np.cumsum(scaled, axis=0)[:39]
    steps = _body_errors(truth[:-1], truth[1:]).as_rotvec().reshape(39, 5, 3)
    residual = steps - omega * cfg.dt
    assert np.abs(residual).max() < 0.03  # Φ: ~0.26° per axis
    assert np.abs(residual.mean(axis=(0, 1))).max() < 3e-3  # no systematic difference


@pytest.fixture(scope="module")
def heavy():
    """Measurements with 30 % outliers and 20 % flips, the inliers nearly exact (|z^Λ| = 1e5):
    unit quaternions, flags, error angles (deg) and rotation vectors of truth⁻¹·measurement."""
    cfg = MotionFilterConfig(measurement_z=(-1e5,) * 3)
    sc = Scenario(runs=50, steps=100, outlier_prob=0.3, flip_prob=0.2, outlier_deg=(30.0, 120.0))
    truth, meas, flags = simulate(cfg, sc, np.random.default_rng(3))
    rel = _body_errors(truth, meas)
    return meas, flags, np.degrees(rel.magnitude()).reshape(flags.shape), rel.as_rotvec().reshape(flags.shape + (3,))


def test_measurements_are_unit_quaternions_and_the_first_is_never_an_outlier(heavy):
    meas, flags, angle, _ = heavy
    np.testing.assert_allclose(np.linalg.norm(meas, axis=-1), 1.0, atol=1e-12)
    assert not flags[0].any()
    assert angle[0].max() < 2.0


def test_outlier_flags_mark_exactly_the_large_errors_at_the_configured_rates(heavy):
    _, flags, angle, _ = heavy
    flags, angle = flags[1:], angle[1:]
    np.testing.assert_array_equal(flags, angle > 15.0)
    assert angle[~flags].max() < 2.0  # inliers: measurement noise only
    flips = angle > 179.999
    assert flips.mean() == pytest.approx(0.2, abs=0.03)
    assert (flags & ~flips).mean() == pytest.approx(0.3, abs=0.03)


def test_large_outliers_are_uniform_over_the_configured_angle_range(heavy):
    _, flags, angle, _ = heavy
    big = angle[1:][flags[1:] & (angle[1:] < 179.9)]
    assert big.min() >= 30.0 - 1e-6 and big.max() <= 120.0 + 1e-6
    assert big.mean() == pytest.approx(75.0, abs=4.0)
    assert np.mean(big < 52.5) == pytest.approx(0.25, abs=0.05)


def test_flips_are_half_turns_about_the_body_x_y_or_z_axis_equally_often(heavy):
    _, _, angle, rotvec = heavy
    axes = np.abs(rotvec[angle > 179.999]) / np.pi
    nearest = np.argmax(axes, axis=1)
    np.testing.assert_allclose(axes, np.eye(3)[nearest], atol=1e-6)
    np.testing.assert_allclose(np.bincount(nearest, minlength=3) / len(nearest), 1 / 3, atol=0.06)


class _EchoFilter:
    """A rotation filter whose estimate is the last measurement it took, with a fixed covariance;
    it records the measurements it is initialised and updated with."""

    def __init__(self, cov):
        self.cov = cov
        self.calls = []

    def init(self, q, omega):
        self.calls.append(("init", q.copy()))
        return q.copy()

    def predict(self, state):
        return state

    def update(self, state, z):
        self.calls.append(("update", z.copy()))
        return z.copy()

    def estimate(self, state):
        return state, None

    def covariance(self, state):
        return self.cov


def test_run_filters_starts_from_the_first_measurement_and_scores_body_frame_errors(monkeypatch):
    """Errors are geodesic angles; NEES is eᵀP⁻¹e with e the Rodrigues parameters (A.5, a = 1,
    f = 4) of the estimate-to-truth rotation in the estimate's body frame."""
    rng = np.random.default_rng(4)
    steps, runs = 6, 5
    truth = Rotation.random(steps * runs, random_state=5).as_quat().reshape(steps, runs, 4)
    small = Rotation.from_rotvec(rng.normal(0.0, 0.2, (steps * runs, 3)))
    meas = (Rotation.from_quat(truth.reshape(-1, 4)) * small).as_quat().reshape(steps, runs, 4)
    a = rng.normal(size=(runs, 3, 3))
    cov = a @ a.transpose(0, 2, 1) + 0.05 * np.eye(3)
    echo = _EchoFilter(cov)
    monkeypatch.setattr(simulation, "make_rotation_filter", lambda cfg: echo)
    out = run_filters(MotionFilterConfig(), truth, meas, kinds=("ukf",))["ukf"]
    assert [c[0] for c in echo.calls] == ["init"] + ["update"] * (steps - 1)
    for t in range(steps):
        np.testing.assert_array_equal(echo.calls[t][1], meas[t])
    rel = Rotation.from_quat(meas.reshape(-1, 4)).inv() * Rotation.from_quat(truth.reshape(-1, 4))
    np.testing.assert_allclose(out["error"], rel.magnitude().reshape(steps, runs), atol=1e-9)
    q = rel.as_quat()
    q = np.where(q[:, 3:] < 0, -q, q)
    e = (4.0 * q[:, :3] / (1.0 + q[:, 3:])).reshape(steps, runs, 3)
    expected = np.einsum("tri,rij,trj->tr", e, np.linalg.inv(cov), e)
    np.testing.assert_allclose(out["nees"], expected, rtol=1e-9)


def test_compare_scores_after_the_warm_up_and_judges_the_nominal_run_without_outliers(monkeypatch):
    """RMSE, median and mean NEES over the frames after ``warm_up``, for the scenario as given
    (heavy) and for the same seed without outliers or flips (nominal)."""
    sc = Scenario(runs=4, steps=10, warm_up=3, outlier_prob=0.1, flip_prob=0.05)
    seen = []

    def fake_simulate(cfg, scenario, rng):
        seen.append((scenario, rng.integers(0, 2**62)))
        return np.zeros((10, 4, 4)), np.zeros((10, 4, 4)), np.zeros((10, 4), bool)

    error = np.radians(np.arange(40.0).reshape(10, 4) ** 1.5)
    error[:3] = 10.0  # warm-up frames: huge, must not count
    nees = np.arange(40.0).reshape(10, 4)
    nees[:3] = 1e6
    monkeypatch.setattr(simulation, "simulate", fake_simulate)
    monkeypatch.setattr(simulation, "run_filters", lambda cfg, truth, meas: {"ukf": {"error": error, "nees": nees}})
    table = compare(seed=7, sc=sc)
    (heavy, draw_h), (nominal, draw_n) = seen
    assert heavy == sc and draw_h == draw_n  # the same seed for both
    assert nominal == dataclasses.replace(sc, **NO_OUTLIERS)
    e = np.degrees(error[3:])
    for name in ("heavy", "nominal"):
        row = table["ukf"][name]
        assert row["rmse_deg"] == pytest.approx(np.sqrt(np.mean(e**2)), rel=1e-12)
        assert row["median_deg"] == pytest.approx(np.median(e), rel=1e-12)
        assert row["mean_nees"] == pytest.approx(nees[3:].mean(), rel=1e-12)


def test_nees_band_holds_95_percent_of_run_averaged_chi2_3_values(monkeypatch):
    """The band of one frame's NEES averaged over R runs: 2.5 % below and 2.5 % above, by Monte Carlo."""
    runs = 12
    monkeypatch.setattr(simulation, "simulate", lambda cfg, sc, rng: (None, None, None))
    monkeypatch.setattr(simulation, "run_filters", lambda cfg, truth, meas: {})
    low, high = compare(sc=Scenario(runs=runs, steps=5, warm_up=0))["nees_band"]
    draws = np.random.default_rng(6).chisquare(3, (200_000, runs)).mean(axis=1)
    assert np.mean(draws < low) == pytest.approx(0.025, abs=0.002)
    assert np.mean(draws > high) == pytest.approx(0.025, abs=0.002)
