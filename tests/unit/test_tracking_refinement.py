"""The rotation-only refinement of the published estimate (tracking/refinement.py)."""

import numpy as np
import pytest

from uav_landing_vision.geometry import geodesic_angle
from uav_landing_vision.tracking.optimisation import rotate_body
from uav_landing_vision.tracking.particles import ParticleSet
from uav_landing_vision.tracking.refinement import RotationRefinement, RotationRefinementConfig

TARGET = np.array([0.2, -0.1, 0.3, 0.9]) / np.linalg.norm([0.2, -0.1, 0.3, 0.9])
POS = np.array([1.0, -2.0, 40.0])


class PeakAt:
    """A likelihood peaked at ``target`` (σ 3°), recording the positions it was asked about."""

    def __init__(self, target):
        self.target, self.positions, self.calls = target, [], 0

    def __call__(self, particles):
        self.calls += 1
        self.positions.append(particles.pos.copy())
        angle = np.degrees(geodesic_angle(particles.quat, self.target))
        return np.exp(-0.5 * (angle / 3.0) ** 2)


def test_refinement_climbs_towards_the_peak_at_the_given_position():
    start = rotate_body(TARGET[None], np.radians([[6.0, -4.0, 3.0]]))[0]
    score = PeakAt(TARGET)
    start_score = score(_one(start))[0]
    quat, best = RotationRefinement(RotationRefinementConfig(candidates=64, sigma_deg=(4.0, 1.5))).refine(
        score, POS, start, start_score, np.random.default_rng(0))
    assert score.calls == 1 + 2  # the start's score above, then one batched call per stage
    assert geodesic_angle(quat, TARGET) < 0.5 * geodesic_angle(start, TARGET)
    assert best > start_score
    np.testing.assert_allclose(best, score(_one(quat))[0])
    for pos in score.positions[1:3]:
        assert pos.shape == (64, 3)
        np.testing.assert_array_equal(pos, np.tile(POS, (64, 1)))


def test_refinement_keeps_a_rotation_that_nothing_beats():
    score = PeakAt(TARGET)
    quat, best = RotationRefinement(RotationRefinementConfig(candidates=32)).refine(
        score, POS, TARGET, 1.0, np.random.default_rng(1))
    np.testing.assert_array_equal(quat, TARGET)
    assert best == 1.0


def test_refinement_off_draws_and_scores_nothing():
    score, rng = PeakAt(TARGET), np.random.default_rng(2)
    before = rng.bit_generator.state
    quat, best = RotationRefinement(RotationRefinementConfig()).refine(score, POS, TARGET, 0.3, rng)
    np.testing.assert_array_equal(quat, TARGET)
    assert quat is not TARGET and best == 0.3 and score.calls == 0
    assert rng.bit_generator.state == before


def test_refinement_scores_an_unscored_start_in_its_first_batch():
    """With no score for the start (the particles' mean pose), the first batch holds the start
    too: it is kept if nothing beats it, and its score comes back."""
    score = PeakAt(TARGET)
    quat, best = RotationRefinement(RotationRefinementConfig(candidates=32)).refine(
        score, POS, TARGET, None, np.random.default_rng(1))
    np.testing.assert_allclose(quat, TARGET, atol=1e-15)
    assert best == pytest.approx(1.0) and score.calls == 1
    assert score.positions[0].shape == (33, 3)
    start = rotate_body(TARGET[None], np.radians([[6.0, -4.0, 3.0]]))[0]
    climbed, best = RotationRefinement(RotationRefinementConfig(candidates=64, sigma_deg=(4.0, 1.5))).refine(
        score, POS, start, None, np.random.default_rng(0))
    assert geodesic_angle(climbed, TARGET) < 0.5 * geodesic_angle(start, TARGET)
    np.testing.assert_allclose(best, score(_one(climbed))[0])


@pytest.mark.parametrize("bad", [{"candidates": -1}, {"candidates": 2.5}, {"sigma_deg": ()}, {"sigma_deg": (2.0, 0.0)}])
def test_refinement_config_is_validated(bad):
    with pytest.raises(ValueError):
        RotationRefinementConfig(**bad)


def _one(quat):
    return ParticleSet.from_poses(POS[None], np.asarray(quat)[None])
