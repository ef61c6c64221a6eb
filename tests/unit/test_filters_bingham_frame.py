"""Bingham toolkit pieces against scipy rotations, hand-made cases and invariances."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision.filters import bingham


def _symmetric_rotvecs(sigma):
    """Six rotation vectors ±√3·Lₖ (``Σ = L Lᵀ``), equally weighted: mean 0, covariance ``Σ``."""
    root = np.sqrt(3.0) * np.linalg.cholesky(sigma)
    return np.concatenate([root.T, -root.T])


def test_tangent_covariance_is_the_body_frame_covariance_of_the_error_rotation():
    """Quaternions ``x = q ⊗ exp(θ)`` (scipy, body-frame errors θ): the tangent covariance at
    ``q`` of ``E[x xᵀ]`` is ``E[(2 sin(|θ|/2) θ̂)(…)ᵀ]`` exactly, not a world-frame rotation of it."""
    rng = np.random.default_rng(0)
    a = rng.standard_normal((3, 3)) * np.array([0.05, 0.02, 0.01])
    sigma = a @ a.T + np.diag([1e-3, 4e-4, 1e-4])
    thetas = _symmetric_rotvecs(sigma)
    for q in Rotation.random(4, random_state=1):
        x = (q * Rotation.from_rotvec(thetas)).as_quat()
        x *= np.sign(x @ q.as_quat())[:, None]  # one hemisphere, as the filters take them
        s = bingham.scatter(x)
        angle = np.linalg.norm(thetas, axis=1, keepdims=True)
        v = 2.0 * np.sin(angle / 2.0) * thetas / angle
        np.testing.assert_allclose(bingham.tangent_covariance(q.as_quat(), s), v.T @ v / len(v), atol=1e-14)


def test_frame_columns_are_body_frame_rotations_of_the_mode():
    """``frame(q)``'s columns are ``q ⊗ e_x, q ⊗ e_y, q ⊗ e_z, q`` (scipy's composition q * e)."""
    q = Rotation.random(5, random_state=2)
    m = bingham.frame(q.as_quat())
    for k in range(3):
        e = np.zeros(4)
        e[k] = 1.0  # a half turn about axis k
        expected = (q * Rotation.from_quat(e)).as_quat()
        col = m[:, :, k]
        np.testing.assert_allclose(col * np.sign(np.sum(col * expected, axis=1))[:, None], expected, atol=1e-12)
    np.testing.assert_allclose(m[:, :, 3], q.as_quat(), atol=0)
    np.testing.assert_allclose(np.swapaxes(m, 1, 2) @ m, np.broadcast_to(np.eye(4), (5, 4, 4)), atol=1e-12)


def test_mean_rotation_of_a_cluster_with_mixed_signs_is_its_centre():
    """The mean of rotations spread symmetrically about ``q`` (about body axes, with random
    quaternion signs and weights that respect the symmetry) is ``q`` itself, sign-canonical."""
    rng = np.random.default_rng(3)
    centre = Rotation.random(random_state=4)
    thetas = _symmetric_rotvecs(np.diag([0.04, 0.01, 0.09]))
    x = (centre * Rotation.from_rotvec(thetas)).as_quat() * rng.choice([-1.0, 1.0], (6, 1))
    expected = centre.as_quat() * np.sign(centre.as_quat()[3])
    np.testing.assert_allclose(bingham.mean_rotation(x), expected, atol=1e-12)
    w = np.tile(rng.uniform(0.1, 1.0, 3), 2)
    np.testing.assert_allclose(bingham.mean_rotation(x, w / w.sum()), expected, atol=1e-12)
    far = Rotation.from_rotvec([[2.5, 0.0, 0.0]]).as_quat()
    both = np.concatenate([x, far])
    w = np.r_[np.full(6, 0.99 / 6), 0.01]  # a light outlier does not take the mean
    assert (Rotation.from_quat(bingham.mean_rotation(both, w)) * centre.inv()).magnitude() < 0.05


def test_fit_depends_only_on_the_shape_of_the_scatter_matrix():
    """(C.8) divides the scatter matrix by the number of samples: a scatter matrix scaled by any
    positive factor fits the same Bingham."""
    rng = np.random.default_rng(5)
    m = np.linalg.qr(rng.standard_normal((4, 4, 4)))[0]
    z = -np.exp(rng.uniform(0.0, 8.0, (4, 3)))
    s = bingham.covariance(m, z)
    ref_m, ref_z = bingham.fit(s)
    for scale in (0.2, 7.0):
        got_m, got_z = bingham.fit(scale * s)
        np.testing.assert_allclose(got_z, ref_z, rtol=1e-9)
        np.testing.assert_allclose(np.abs(np.sum(got_m * ref_m, axis=1)), 1.0, atol=1e-9)


def test_fit_of_a_rank_deficient_scatter_is_the_most_concentrated_bingham():
    """Three samples span a 3-dimensional subspace: the fitted concentration across the missing
    direction is the table's limit, finite, and the others finite and negative."""
    q = Rotation.random(3, random_state=6).as_quat()
    m, z = bingham.fit(bingham.scatter(q))
    assert np.all(np.isfinite(z)) and np.all(np.isfinite(m))
    assert np.min(z) == pytest.approx(-bingham.max_concentration(), rel=1e-6)
    assert np.all(z < 0)
