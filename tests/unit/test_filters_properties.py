"""Property tests: quaternion sign invariance and normalised outputs of the rotation filters."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from uav_landing_vision.filters import bingham
from uav_landing_vision.filters.motion import KINDS, MotionFilterConfig, make_rotation_filter

FILTERS = {(k, eps): make_rotation_filter(MotionFilterConfig(rotation_filter=k, outlier_prob=eps))
           for k in KINDS for eps in (0.0, 0.1)}
quats = arrays(np.float64, (3, 4), elements=st.floats(-1, 1)).filter(
    lambda q: np.all(np.linalg.norm(q, axis=1) > 0.1)
).map(lambda q: q / np.linalg.norm(q, axis=1, keepdims=True))
rates = arrays(np.float64, (3, 3), elements=st.floats(-10, 10))


@settings(max_examples=40, deadline=None)
@given(q=quats, z=quats, w=rates, kind=st.sampled_from(sorted(FILTERS)))
def test_filters_ignore_the_sign_of_quaternions_and_return_unit_ones(q, z, w, kind):
    """Thesis and outlier-aware updates alike."""
    filt = FILTERS[kind]
    a = filt.update(filt.predict(filt.init(q, w)), z)
    b = filt.update(filt.predict(filt.init(-q, w)), -z)
    qa, wa = filt.estimate(a)
    qb, wb = filt.estimate(b)
    np.testing.assert_allclose(qa, qb, atol=1e-9)
    np.testing.assert_allclose(wa, wb, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(qa, axis=1), 1.0, atol=1e-12)
    assert np.all(qa[:, 3] >= 0.0)
    cov = filt.covariance(a)
    assert np.all(np.linalg.eigvalsh(cov) > 0.0)


@settings(max_examples=25, deadline=None)
@given(q=quats, signs=arrays(np.float64, (4,), elements=st.sampled_from([-1.0, 1.0])),
       z=arrays(np.float64, (3,), elements=st.floats(-2000, -0.01)))
def test_bingham_outputs_are_sign_invariant_and_normalised(q, signs, z):
    m = bingham.frame(q[0])
    np.testing.assert_allclose(bingham.density(-q, m, z), bingham.density(q, m, z), rtol=1e-12)
    np.testing.assert_allclose(bingham.density(q, m * signs, z), bingham.density(q, m, z), rtol=1e-12)
    m2 = bingham.frame(q[1])
    mp, zp = bingham.product(m * signs, z, m2, z[::-1])
    mq, zq = bingham.product(m, z, m2 * signs, z[::-1])
    np.testing.assert_allclose(zp, zq, atol=1e-8)
    assert np.isclose(abs(bingham.mode(mp) @ bingham.mode(mq)), 1.0)
    np.testing.assert_allclose(mp.T @ mp, np.eye(4), atol=1e-12)
    pts, w = bingham.sigma_points(m, z)
    np.testing.assert_allclose(np.linalg.norm(pts, axis=-1), 1.0, atol=1e-12)
    s = bingham.scatter(q * signs[:3, None])
    np.testing.assert_allclose(bingham.fit(s)[1], bingham.fit(bingham.scatter(q))[1], rtol=1e-9)
