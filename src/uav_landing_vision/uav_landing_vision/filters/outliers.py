"""Outlier-aware measurement update (ours; the thesis's filters trust every measurement).

A measured orientation is the filter's own noise model with probability ``1 − ε`` and, with
probability ``ε``, an unrelated rotation, uniform over SO(3): a symmetric-pose confusion or a
wrong best particle (§6.5). The exact posterior is then the mixture ``w·updated + (1 − w)·
predicted``, with ``w`` the posterior probability that the measurement is an inlier; each
filter replaces it by the one density of its family with the mixture's first two moments, as
a probabilistic data association filter does. Densities are per rad³ of rotation vector.
"""

import numpy as np
from scipy.special import expit

# The uniform density on SO(3) in rotation-vector coordinates at small angles: 1 / (8π²).
UNIFORM_ROTATION_LOG_DENSITY = -np.log(8.0 * np.pi**2)


def check_outlier_prob(eps: float) -> float:
    """``ε`` in [0, 1)."""
    if not (np.isfinite(eps) and 0.0 <= eps < 1.0):
        raise ValueError(f"outlier_prob must lie in [0, 1), got {eps}")
    return float(eps)


def inlier_probability(log_likelihood: np.ndarray, eps: float) -> np.ndarray:
    """Posterior probability ``w`` that a measurement of inlier log density ``log_likelihood`` is
    not an outlier, with prior outlier probability ``eps``."""
    if eps == 0.0:
        return np.ones_like(log_likelihood)
    return expit(np.log1p(-eps) - np.log(eps) + log_likelihood - UNIFORM_ROTATION_LOG_DENSITY)


def gaussian_log_density(nu: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """``log N(ν; 0, cov)`` of innovations ``nu (..., n)`` with covariances ``cov (..., n, n)``."""
    chol = np.linalg.cholesky(cov)
    y = np.linalg.solve(chol, nu[..., None])[..., 0]
    half_logdet = np.sum(np.log(np.diagonal(chol, axis1=-2, axis2=-1)), axis=-1)
    return -0.5 * np.sum(y**2, axis=-1) - half_logdet - 0.5 * nu.shape[-1] * np.log(2.0 * np.pi)


def mix_gaussians(w, mean1, cov1, mean0, cov0) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of ``w·N(mean1, cov1) + (1 − w)·N(mean0, cov0)``; ``w (...,)``."""
    w = np.asarray(w)[..., None]
    mean = w * mean1 + (1.0 - w) * mean0
    d1, d0 = mean1 - mean, mean0 - mean
    spread = w[..., None] * (cov1 + d1[..., :, None] * d1[..., None, :])
    cov = spread + (1.0 - w[..., None]) * (cov0 + d0[..., :, None] * d0[..., None, :])
    return mean, 0.5 * (cov + np.swapaxes(cov, -1, -2))


def gaussian_update(eps: float, nu, innovation_cov, mean, cov, prior_mean, prior_cov):
    """The outlier-aware form of a Kalman update: ``(mean, cov)`` updated with innovation ``nu``
    of covariance ``innovation_cov``, mixed with the prediction ``(prior_mean, prior_cov)`` by
    the inlier probability; unchanged when ``eps`` is 0."""
    if eps == 0.0:
        return mean, cov
    w = inlier_probability(gaussian_log_density(nu, innovation_cov), eps)
    return mix_gaussians(w, mean, cov, prior_mean, prior_cov)
