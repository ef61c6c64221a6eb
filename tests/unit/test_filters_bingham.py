"""Bingham toolkit (App. C.1, D) against pyrecest and an independent numerical integration."""

import numpy as np
import pytest
from pyrecest.distributions import BinghamDistribution
from pyrecest.filters import BinghamFilter
from scipy.special import ive
from scipy.spatial.transform import Rotation

from uav_landing_vision.filters import bingham, bingham_table
from uav_landing_vision.geometry import quat_multiply

PY = [3, 0, 1, 2]  # our [x, y, z, w] → pyrecest's scalar-first [w, x, y, z]


def _graded_nodes():
    """Gauss–Legendre nodes on [0, π/2], graded towards both ends (the integrand's peaks)."""
    inner = 10.0 ** np.arange(-6, 0)
    breaks = np.unique(np.r_[0.0, inner, np.pi / 4, np.pi / 2 - inner[::-1], np.pi / 2])
    x, w = np.polynomial.legendre.leggauss(24)
    lo, hi = breaks[:-1, None], breaks[1:, None]
    return (lo + (hi - lo) * (x + 1) / 2).ravel(), ((hi - lo) * w / 2).ravel()


def direct_integration(z):
    """F and ∂F/∂z_i by integrating over the tangent ball of the upper hemisphere.

    ``q = (ρn, √(1−ρ²))``, ``dS = ρ² dρ dn / √(1−ρ²)``; the radial integrals are closed-form
    (``ρ = sin θ``): ``∫ e^{−aρ²} sin²θ dθ`` and ``∫ e^{−aρ²} sin⁴θ dθ`` in Bessel functions
    ``e^{−b} I_ν(b) = ive(ν, b) e^{|b| − b}``, ``b = a/2`` (the factor is 1 unless a positive ``z_i``,
    as in the table's padding, makes ``a`` negative); the direction ``n ∈ S²`` is integrated
    numerically over one octant.
    """
    t, wt = _graded_nodes()
    th, ph = np.meshgrid(t, t, indexing="ij")
    wgt = np.outer(wt, wt) * np.sin(th)
    n = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)
    a = n**2 @ (-np.asarray(z, float))
    b = a / 2
    scale = np.exp(np.abs(b) - b)
    r1 = np.pi / 4 * (ive(0, b) - ive(1, b)) * scale
    r2 = np.pi / 8 * (1.5 * ive(0, b) - 2 * ive(1, b) + 0.5 * ive(2, b)) * scale
    f = 16 * np.sum(wgt * r1)  # 2 hemispheres × 8 octants
    df = np.array([16 * np.sum(wgt * n[..., i] ** 2 * r2) for i in range(3)])
    return f, np.r_[df, f - df.sum()]


def to_pyrecest(m, z):
    zz = np.r_[z, 0.0]
    order = np.argsort(zz)
    return BinghamDistribution(zz[order], m[PY][:, order])


def random_bingham(rng, low=1.0, high=300.0):
    m = np.linalg.qr(rng.standard_normal((4, 4)))[0]
    return m, -rng.uniform(low, high, 3)


CORNERS = [(0.0, 0.0, 0.0), (-1e5, -1e5, -1e5), (-1e5, -0.5, -1e5), (-3e4, -20.0, -7000.0),
           (-500.0, -2.0, -8e4), (-1e5, 0.0, 0.0), (-0.3, -0.7, -1.1)]


RANDOM = [tuple(-np.expm1(v)) for v in np.random.default_rng(3).uniform(0, 11.5, (8, 3))]


@pytest.mark.parametrize("z", CORNERS + RANDOM)
def test_normaliser_and_gradient_match_direct_integration_over_the_whole_table(z):
    f, df = direct_integration(z)
    assert bingham.normaliser(np.array(z)) == pytest.approx(f, rel=1e-3)
    np.testing.assert_allclose(bingham.normaliser_gradient(np.array(z)), df, rtol=1e-3)


def test_normaliser_and_gradient_match_pyrecest():
    rng = np.random.default_rng(0)
    z = np.concatenate([-rng.uniform(0, 600, (30, 3)), -np.exp(rng.uniform(-3, np.log(600), (30, 3)))])
    for zi in z:
        ref = to_pyrecest(np.eye(4), zi)
        order = np.argsort(np.r_[zi, 0.0])
        assert bingham.normaliser(zi) == pytest.approx(float(ref.F), rel=1e-3)
        np.testing.assert_allclose(bingham.normaliser_gradient(zi)[order], np.asarray(ref.dF), rtol=1e-3)


def test_density_integrates_to_one_and_matches_pyrecest():
    rng = np.random.default_rng(1)
    m, z = random_bingham(rng)
    q = rng.standard_normal((50, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    np.testing.assert_allclose(bingham.density(q, m, z), to_pyrecest(m, z).pdf(q[:, PY]), rtol=1e-3)


def test_product_and_mode_match_pyrecest():
    rng = np.random.default_rng(2)
    for _ in range(10):
        (m1, z1), (m2, z2) = random_bingham(rng), random_bingham(rng)
        m, z = bingham.product(m1, z1, m2, z2)
        ref = to_pyrecest(m1, z1).multiply(to_pyrecest(m2, z2))
        np.testing.assert_allclose(np.sort(z), np.asarray(ref.Z)[:3], rtol=1e-9)
        assert abs(bingham.mode(m) @ np.asarray(ref.mode())[np.argsort(PY)]) == pytest.approx(1.0, abs=1e-9)


def test_product_evidence_matches_integration_of_pyrecest_densities():
    """``∫ p1 p2`` over S³ by uniform Monte Carlo of pyrecest's densities (moderate concentrations)."""
    rng = np.random.default_rng(5)
    x = rng.standard_normal((1_000_000, 4))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    for _ in range(3):
        (m1, z1), (m2, z2) = random_bingham(rng, 0.5, 12.0), random_bingham(rng, 0.5, 12.0)
        expected = 2 * np.pi**2 * np.mean(to_pyrecest(m1, z1).pdf(x[:, PY]) * to_pyrecest(m2, z2).pdf(x[:, PY]))
        assert np.exp(bingham.product_log_evidence(m1, z1, m2, z2)) == pytest.approx(expected, rel=0.01)


def test_composition_matches_pyrecest_and_monte_carlo():
    rng = np.random.default_rng(3)
    for _ in range(5):
        (m1, z1), (m2, z2) = random_bingham(rng, 1, 50), random_bingham(rng, 1, 50)
        c = bingham.compose_covariance(bingham.covariance(m1, z1), bingham.covariance(m2, z2))
        ref = to_pyrecest(m1, z1).compose(to_pyrecest(m2, z2)).moment()  # moment of its refit
        np.testing.assert_allclose(c[PY][:, PY], np.asarray(ref), atol=2e-4)
    q1, q2 = bingham.sample(m1, z1, 40000, rng), bingham.sample(m2, z2, 40000, rng)
    np.testing.assert_allclose(bingham.scatter(quat_multiply(q1, q2)), c, atol=0.01)


def test_covariance_matches_pyrecest_and_sampling_reproduces_it():
    rng = np.random.default_rng(4)
    m, z = random_bingham(rng, 1, 40)
    s = bingham.covariance(m, z)
    np.testing.assert_allclose(s[PY][:, PY], np.asarray(to_pyrecest(m, z).moment()), atol=1e-5)
    q = bingham.sample(m, z, 20000, rng)
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0)
    sq = q[:, :, None] * q[:, None, :]
    se = sq.std(axis=0) / np.sqrt(len(q))  # Monte-Carlo standard error of each entry
    assert np.all(np.abs(sq.mean(axis=0) - s) < 5 * se + 1e-4)


def test_fit_inverts_the_covariance_and_matches_pyrecest():
    rng = np.random.default_rng(5)
    m = np.linalg.qr(rng.standard_normal((20, 4, 4)))[0]
    z = -np.exp(rng.uniform(-2, np.log(9e4), (20, 3)))
    m_fit, z_fit = bingham.fit(bingham.covariance(m, z))
    np.testing.assert_allclose(np.sort(z_fit, axis=1), np.sort(z, axis=1), rtol=1e-6)
    np.testing.assert_allclose(bingham.covariance(m_fit, z_fit), bingham.covariance(m, z), atol=1e-10)
    m1, z1 = random_bingham(rng, 1, 200)
    ref = BinghamDistribution.fit_to_moment(bingham.covariance(m1, z1)[PY][:, PY])
    np.testing.assert_allclose(np.sort(bingham.fit(bingham.covariance(m1, z1))[1]), np.asarray(ref.Z)[:3], rtol=1e-4)
    m0, z0 = bingham.fit(np.zeros((0, 4, 4)))  # an empty batch is no error
    assert m0.shape == (0, 4, 4) and z0.shape == (0, 3)


def test_rotation_moves_the_density_with_the_samples():
    rng = np.random.default_rng(6)
    m, z = random_bingham(rng)
    g = Rotation.random(random_state=7).as_quat()
    q = bingham.sample(m, z, 100, rng)
    for side, r in (("right", quat_multiply(q, g)), ("left", quat_multiply(g, q))):
        rotated = bingham.rotate(m, g, side)
        np.testing.assert_allclose(bingham.density(r, rotated, z), bingham.density(q, m, z), rtol=1e-9)
    with pytest.raises(ValueError):
        bingham.rotate(m, g, "middle")


def test_sigma_points_reproduce_the_covariance():
    rng = np.random.default_rng(8)
    m = np.linalg.qr(rng.standard_normal((6, 4, 4)))[0]
    z = -rng.uniform(1, 3000, (6, 3))
    pts, w = bingham.sigma_points(m, z)
    assert pts.shape == (6, 7, 4) and np.allclose(w.sum(axis=1), 1.0) and np.all(w > 0)
    np.testing.assert_allclose(bingham.scatter(pts, w), bingham.covariance(m, z), atol=1e-12)
    np.testing.assert_allclose(pts[:, 6], m[:, :, 3])  # the central point is the mode (D.4)


def test_measurement_noise_rotation_matches_pyrecest_update():
    rng = np.random.default_rng(9)
    m_state, z_state = random_bingham(rng, 5, 100)
    m_noise, z_noise = random_bingham(rng, 5, 100)
    meas = Rotation.random(random_state=10).as_quat()
    m, z = bingham.product(bingham.noise_frame_at(meas, m_noise), z_noise, m_state, z_state)
    filt = BinghamFilter()
    filt.filter_state = to_pyrecest(m_state, z_state)
    filt.update_identity(to_pyrecest(m_noise, z_noise), meas[PY])
    np.testing.assert_allclose(np.sort(z), np.asarray(filt.filter_state.Z)[:3], rtol=1e-9)
    assert abs(bingham.mode(m) @ np.asarray(filt.get_point_estimate())[np.argsort(PY)]) == pytest.approx(1.0)


def test_tangent_covariance_inverts_small_rotation_moment():
    rng = np.random.default_rng(11)
    a = rng.standard_normal((3, 3)) * 0.05
    sigma = a @ a.T
    q = Rotation.random(random_state=12).as_quat()
    s = bingham.frame(q) @ bingham.small_rotation_moment(sigma) @ bingham.frame(q).T
    np.testing.assert_allclose(bingham.tangent_covariance(q, s), sigma, atol=1e-12)
    assert np.trace(s) == pytest.approx(1.0, abs=1e-12)  # E[e eᵀ] of a unit quaternion


def test_scatter_without_weights_is_the_mean_outer_product():
    q = Rotation.random(5, random_state=13).as_quat()
    np.testing.assert_allclose(bingham.scatter(q), np.mean(q[:, :, None] * q[:, None, :], axis=0), atol=1e-15)


def test_concentrations_beyond_the_table_are_clamped_in_the_evidence():
    z_max = bingham.max_concentration()
    np.testing.assert_array_equal(bingham.clamp_concentration(np.array([-2 * z_max, -1.0, 0.0])), [-z_max, -1.0, 0.0])
    m = np.linalg.qr(np.random.default_rng(14).standard_normal((4, 4)))[0]
    z = np.full(3, -0.9 * z_max)  # the product's concentrations are −1.8 z_max, clamped to −z_max
    # Laplace's method at these concentrations (two antipodal Gaussian peaks): F(Z) = 2π^{3/2} / √|z1 z2 z3|;
    # the product's largest eigenvalue is 0, so the evidence is log F(−z_max) − 2 log F(−0.9 z_max).
    laplace = lambda zz: np.log(2 * np.pi**1.5 / np.sqrt(np.prod(np.abs(zz))))  # noqa: E731
    expected = laplace(np.full(3, -z_max)) - 2 * laplace(z)
    assert bingham.product_log_evidence(m, z, m, z) == pytest.approx(expected, abs=1e-4)


@pytest.mark.parametrize("z", [(-1.0, -2.0, 0.0), (-1.0, -2.0, -3.0, -0.5), (-1.0, -2.0), (-1.0, np.nan, -3.0)])
def test_invalid_concentrations_are_errors(z):
    with pytest.raises(ValueError, match="process_z"):
        bingham.check_concentration(z, "process_z")
    np.testing.assert_array_equal(bingham.check_concentration((-1.0, -2.0, -3.0, 0.0), "z"), [-1.0, -2.0, -3.0])


def test_lookups_outside_the_table_are_errors():
    with pytest.raises(ValueError):
        bingham.normaliser(np.array([-1.0, -2.0, 0.5]))
    with pytest.raises(ValueError):
        bingham.moments(np.array([-2e5, -1.0, -1.0]))


def test_quadrature_at_zero_is_the_area_of_s3_and_every_moment_a_quarter():
    f, m = bingham_table.normaliser_and_moments(np.zeros((1, 3)))
    assert f[0] == pytest.approx(2.0 * np.pi**2, rel=1e-12)
    np.testing.assert_allclose(m[0], 0.25, rtol=1e-12)


def _two_equal(a):
    """Z = diag(a, a, 0, 0): x1² + x2² is uniform on [0, 1] over S³, so F = 2π²(e^a − 1)/a and
    E[x1²] = E[x2²] = E[u]/2, E[x3²] = (1 − E[u])/2 with E[u] = e^a/(e^a − 1) − 1/a."""
    f = 2.0 * np.pi**2 * np.expm1(a) / a
    mean_u = np.exp(a) / np.expm1(a) - 1.0 / a
    return f, np.array([mean_u / 2, mean_u / 2, (1.0 - mean_u) / 2])


@pytest.mark.parametrize("a", [-0.5, -40.0, -1.0e3, -3.0e4, -1.0e5, 0.3])
def test_quadrature_in_closed_form_with_two_equal_concentrations(a):
    """Every placement of the zero among (z1, z2, z3), from the padding's small positive values to
    the table's largest |z|."""
    f_ref, m_ref = _two_equal(a)
    for zero in range(3):
        z = np.full(3, a)
        z[zero] = 0.0
        f, m = bingham_table.normaliser_and_moments(z[None])
        assert f[0] == pytest.approx(f_ref, rel=1e-9)
        np.testing.assert_allclose(m[0], np.where(np.arange(3) == zero, m_ref[2], m_ref[0]), rtol=1e-9)


QUADRATURE_Z = [(-5.0, -20.0, -1.0), (-20.0, -5.0, -1.0), (-30.0, -30.0, -2.0), (-1.0, -8.0, -40.0),
                (-12.0, 0.0, 0.0), (0.0, 0.0, -25.0), (-7.0, -3.0, -900.0), (-2500.0, -60.0, -0.5),
                (-1e5, -2e4, -5e4), (-3e3, -1e5, -8e3), (-6e4, -6e4, -1e3),
                (-3.0, -0.5, 0.4), (0.3, -2.0, -7.0), (-12.0, 0.3, 0.2)]


@pytest.mark.parametrize("z", QUADRATURE_Z)
def test_quadrature_matches_direct_integration_from_the_padding_to_the_largest_concentrations(z):
    """The table's one-dimensional Hopf quadrature against the tangent-ball integration, both
    orderings of z1 and z2, small positive (padding) values and |z| up to 1e5 included."""
    f_ref, df_ref = direct_integration(z)
    f, m = bingham_table.normaliser_and_moments(np.array([z]))
    assert f[0] == pytest.approx(f_ref, rel=1e-8)
    np.testing.assert_allclose(m[0], df_ref[:3] / f_ref, rtol=1e-7)


@pytest.fixture(scope="module")
def small_table():
    return bingham_table.build(grid_size=8, z_max=50.0)


def test_table_axis_spans_zero_to_log1p_z_max_in_equal_steps_with_padding(small_table):
    v = small_table["v"]
    pad = bingham_table.PAD
    assert len(v) == 8 + 2 * pad
    assert v[pad] == 0.0
    assert v[pad + 7] == pytest.approx(np.log1p(50.0), rel=1e-12)
    np.testing.assert_allclose(np.diff(v), np.log1p(50.0) / 7, rtol=1e-12)
    assert float(small_table["z_max"]) == 50.0


def test_every_table_cell_holds_the_quadrature_at_its_own_concentrations(small_table):
    """Cell (i, j, k) holds log F and log of the moments at z = −(e^{v} − 1) of its three axis
    values, in that order: diagonal cells, padding and all orderings of a triple included, and the
    table is symmetric under any swap of two axes."""
    v, log_f, log_m = small_table["v"], small_table["log_f"], small_table["log_m"]
    n = len(v)
    assert np.all(np.isfinite(log_f)) and np.all(np.isfinite(log_m))
    np.testing.assert_array_equal(log_f, log_f.transpose(1, 0, 2))
    np.testing.assert_array_equal(log_f, log_f.transpose(0, 2, 1))
    np.testing.assert_allclose(log_m[..., 0], log_m.transpose(1, 0, 2, 3)[..., 1], rtol=1e-12)
    np.testing.assert_allclose(log_m[..., 2], log_m.transpose(2, 1, 0, 3)[..., 0], rtol=1e-12)
    cells = np.random.default_rng(0).integers(0, n, (300, 3))
    cells = np.concatenate([cells, [[3, 3, 3], [0, 0, n - 1], [n - 1, 5, 5], [2, 9, 2]],
                            [[9, 2, 14], [14, 9, 2], [2, 14, 9], [9, 14, 2]]])
    f, m = bingham_table.normaliser_and_moments(-np.expm1(v[cells]))
    i, j, k = cells.T
    np.testing.assert_allclose(log_f[i, j, k], np.log(f), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(log_m[i, j, k], np.log(m), rtol=1e-10, atol=1e-12)


def test_table_command_builds_a_table_that_matches_the_quadrature(tmp_path):
    out = tmp_path / "table.npz"
    assert bingham_table.main([str(out), "--grid-size", "8", "--z-max", "50"]) == 0
    with np.load(out) as t:
        v, log_f = t["v"], t["log_f"]
    i = bingham_table.PAD + np.array([1, 4, 7])
    f, _ = bingham_table.normaliser_and_moments(-np.expm1(v[i])[None])
    assert log_f[i[0], i[1], i[2]] == pytest.approx(np.log(f[0]), rel=1e-6)
    assert log_f[i[2], i[0], i[1]] == pytest.approx(np.log(f[0]), rel=1e-6)


@pytest.mark.parametrize("args", [["--z-max", "inf"], ["--z-max", "nan"], ["--z-max", "0"], ["--grid-size", "4"]])
def test_table_command_rejects_bad_arguments(tmp_path, args, capsys):
    """``--z-max inf`` used to write a table of NaNs."""
    out = tmp_path / "table.npz"
    with pytest.raises(SystemExit) as exc:
        bingham_table.main([str(out), *args])
    assert exc.value.code == 2 and "--z-max" in capsys.readouterr().err and not out.exists()
