"""Geometry edge cases and the general Rodrigues parameters against scipy."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision import geometry as g


@pytest.mark.parametrize("a, f, oracle", [
    (1.0, 1.0, lambda r: r.as_mrp()),  # modified Rodrigues parameters: tan(θ/4)·n
    (0.0, 1.0, lambda r: np.tan(r.magnitude() / 2)[:, None] * r.as_rotvec() / r.magnitude()[:, None]),  # Gibbs
    (1.0, 4.0, lambda r: 4.0 * r.as_mrp()),  # the filters' choice (A.5), f = 2(a + 1)
    (0.5, 3.0, None),
])
def test_general_rodrigues_parameters_match_scipy_and_invert(a, f, oracle):
    """(A.5)–(A.7) for several ``a``, ``f``: the forward map against scipy's MRP and the Gibbs
    vector, and the inverse (A.6)–(A.7) recovering the quaternion for every ``a``."""
    r = Rotation.random(200, random_state=np.random.default_rng(7))
    r = r[r.magnitude() < 2.5]  # the Gibbs vector diverges at a half turn
    e = g.quat_canonical(r.as_quat())
    d = g.rodrigues_from_quat(e, a, f)
    if oracle is not None:
        np.testing.assert_allclose(d, oracle(r), atol=1e-12)
    np.testing.assert_allclose(g.quat_from_rodrigues(d, a, f), e, atol=1e-12)


@pytest.mark.parametrize("bad", [[np.inf, 0.0, 0.0, 1.0], [np.nan, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 0.0]])
def test_normalising_a_non_finite_or_zero_quaternion_is_an_error(bad):
    with pytest.raises(ValueError, match="normalise"):
        g.quat_normalise(np.array(bad))


@pytest.mark.filterwarnings("ignore:Gimbal lock detected")
def test_euler_angles_at_gimbal_lock_put_the_whole_yaw_into_gamma():
    """At β = ±π/2 only α ∓ γ is observable; α is reported as 0 and the rotation is unchanged."""
    for beta in (np.pi / 2, -np.pi / 2):
        angles = np.array([[0.3, beta, -0.4], [-1.2, beta, 2.0]])
        m = g.euler_zyx_to_matrix(angles)
        got = g.matrix_to_euler_zyx(m)
        np.testing.assert_allclose(got[:, 0], 0.0, atol=1e-12)
        np.testing.assert_allclose(got[:, 1], beta, atol=1e-7)
        np.testing.assert_allclose(g.euler_zyx_to_matrix(got), m, atol=1e-9)
        expected = Rotation.from_matrix(m).as_euler("ZYX")  # scipy: [γ, β, α]; it also warns and sets α = 0
        np.testing.assert_allclose(np.cos(got[:, 2] - expected[:, 0]), 1.0, atol=1e-9)
    # just off the lock, α and γ are separate again
    angles = np.array([0.3, np.pi / 2 - 1e-5, -0.4])
    np.testing.assert_allclose(g.matrix_to_euler_zyx(g.euler_zyx_to_matrix(angles)), angles, atol=1e-6)


def test_default_rodrigues_parameters_are_a_1_and_f_4():
    """Without ``a``, ``f``: d = 4·tan(θ/4)·n, four times scipy's modified Rodrigues parameters."""
    r = Rotation.random(50, random_state=np.random.default_rng(8))
    e = g.quat_canonical(r.as_quat())
    np.testing.assert_allclose(g.rodrigues_from_quat(e), 4.0 * r.as_mrp(), atol=1e-12)
    np.testing.assert_allclose(g.quat_from_rodrigues(4.0 * r.as_mrp()), e, atol=1e-12)
