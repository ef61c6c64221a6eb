"""The outlier-aware update's pieces (ours) against scipy and Monte Carlo."""

import numpy as np
import pytest
from scipy import stats
from scipy.spatial.transform import Rotation

from uav_landing_vision.filters import outliers


def test_gaussian_log_density_matches_scipy():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(5, 3, 3))
    cov = a @ np.swapaxes(a, 1, 2) + 0.1 * np.eye(3)
    nu = rng.normal(size=(5, 3))
    expected = [stats.multivariate_normal(np.zeros(3), c).logpdf(n) for n, c in zip(nu, cov)]
    np.testing.assert_allclose(outliers.gaussian_log_density(nu, cov), expected, rtol=1e-12)


def test_mixture_moments_match_samples_of_the_mixture():
    rng = np.random.default_rng(1)
    mean1, mean0 = np.array([1.0, -2.0]), np.array([-0.5, 0.5])
    cov1, cov0 = np.array([[0.5, 0.2], [0.2, 0.3]]), np.array([[0.2, -0.1], [-0.1, 0.4]])
    w, n = 0.3, 400_000
    pick = rng.uniform(size=n) < w
    x = np.where(pick[:, None], rng.multivariate_normal(mean1, cov1, n), rng.multivariate_normal(mean0, cov0, n))
    mean, cov = outliers.mix_gaussians(np.array(w), mean1, cov1, mean0, cov0)
    np.testing.assert_allclose(mean, x.mean(0), atol=0.01)
    np.testing.assert_allclose(cov, np.cov(x.T), atol=0.01)


def test_the_outlier_density_is_that_of_uniform_rotations_at_small_angles():
    """Uniform rotations (scipy) within 0.4 rad of the identity, per rad³ of the rotation-vector ball."""
    r = 0.4
    inside = np.mean(Rotation.random(400_000, random_state=3).magnitude() < r)
    assert np.log(inside / (4 / 3 * np.pi * r**3)) == pytest.approx(outliers.UNIFORM_ROTATION_LOG_DENSITY, abs=0.06)


def test_inlier_probability():
    log_lik = np.array([5.0, -np.log(8 * np.pi**2), -300.0])  # the middle one: as likely as an outlier
    np.testing.assert_array_equal(outliers.inlier_probability(log_lik, 0.0), 1.0)
    w = outliers.inlier_probability(log_lik, 0.2)
    assert w[0] > 0.999 and w[1] == pytest.approx(0.8) and w[2] < 1e-100


@pytest.mark.parametrize("eps", [1.0, -0.01, float("nan")])
def test_outlier_probability_out_of_range_is_an_error(eps):
    with pytest.raises(ValueError):
        outliers.check_outlier_prob(eps)
