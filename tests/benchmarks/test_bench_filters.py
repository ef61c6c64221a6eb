"""Timing of one predict + update step of each motion filter for 100 particles (pytest-benchmark)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision.filters import KINDS, MotionFilterConfig, TranslationFilter, make_rotation_filter

M = 100


@pytest.mark.parametrize("outlier_prob", [0.0, 0.12])
@pytest.mark.parametrize("kind", KINDS)
def test_rotation_filter_step(benchmark, kind, outlier_prob):
    filt = make_rotation_filter(MotionFilterConfig(rotation_filter=kind, outlier_prob=outlier_prob))
    quat = Rotation.random(M, random_state=0).as_quat()
    state = filt.init(quat, np.zeros((M, 3)))
    out = benchmark(lambda: filt.update(filt.predict(state), quat))
    assert np.allclose(np.linalg.norm(filt.estimate(out)[0], axis=1), 1.0)


def test_translation_filter_step(benchmark):
    filt = TranslationFilter(MotionFilterConfig())
    pos = np.random.default_rng(0).normal(0, 10, (M, 3))
    state = filt.init(pos, np.zeros((M, 3)))
    out = benchmark(lambda: filt.update(filt.predict(state), pos))
    assert np.allclose(filt.estimate(out)[0], pos, atol=1.0)
