"""The rotation-only refinement of the published estimate (tracking/refinement.py)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision.geometry import geodesic_angle
from uav_landing_vision.tracking.optimisation import rotate_body
from uav_landing_vision.tracking.particles import ParticleSet
from uav_landing_vision.tracking.refinement import RotationRefinement, RotationRefinementConfig

TARGET = np.array([0.2, -0.1, 0.3, 0.9]) / np.linalg.norm([0.2, -0.1, 0.3, 0.9])
POS = np.array([1.0, -2.0, 40.0])


class PeakAt:
    """A likelihood peaked at ``target`` (σ 3°), recording the poses it was asked about."""

    def __init__(self, target):
        self.target, self.positions, self.quats, self.calls = target, [], [], 0

    def __call__(self, particles):
        self.calls += 1
        self.positions.append(particles.pos.copy())
        self.quats.append(particles.quat.copy())
        angle = np.degrees(geodesic_angle(particles.quat, self.target))
        return np.exp(-0.5 * (angle / 3.0) ** 2)


def test_refinement_climbs_towards_the_peak_at_the_given_position():
    start = rotate_body(TARGET[None], np.radians([[6.0, -4.0, 3.0]]))[0]
    score = PeakAt(TARGET)
    start_score = score(_one(start))[0]
    quat, best = RotationRefinement(RotationRefinementConfig(candidates=64, sigma_deg=(4.0, 1.5))).refine(
        score, POS, start, np.random.default_rng(0))
    assert score.calls == 1 + 2  # the start's score above, then one batched call per stage
    assert geodesic_angle(quat, TARGET) < 0.5 * geodesic_angle(start, TARGET)
    assert best > start_score
    np.testing.assert_allclose(best, score(_one(quat))[0])
    assert score.positions[1].shape == (65, 3)  # the start is scored in the first batch
    assert score.positions[2].shape == (64, 3)
    for pos in score.positions[1:3]:
        np.testing.assert_array_equal(pos, np.tile(POS, (len(pos), 1)))


@pytest.mark.parametrize("sigma_deg", [(4.0,), (3.0, 3.0)])
def test_refinement_keeps_a_rotation_that_nothing_beats(sigma_deg):
    """Also over stages: a later stage's best replaces the rotation only when it scores higher."""
    score = PeakAt(TARGET)
    quat, best = RotationRefinement(RotationRefinementConfig(candidates=32, sigma_deg=sigma_deg)).refine(
        score, POS, TARGET, np.random.default_rng(1))
    np.testing.assert_allclose(quat, TARGET, atol=1e-15)
    assert best == pytest.approx(1.0) and score.calls == len(sigma_deg)


def test_refinement_off_draws_and_scores_nothing():
    score, rng = PeakAt(TARGET), np.random.default_rng(2)
    before = rng.bit_generator.state
    quat, best = RotationRefinement(RotationRefinementConfig()).refine(score, POS, TARGET, rng)
    np.testing.assert_array_equal(quat, TARGET)
    assert quat is not TARGET and best is None and score.calls == 0
    assert rng.bit_generator.state == before


def test_refinement_shifts_are_a_cross_of_the_alignment_step():
    np.testing.assert_array_equal(RotationRefinementConfig().shifts, [[0.0, 0.0]])
    shifts = RotationRefinementConfig(align_px=0.5).shifts
    np.testing.assert_array_equal(shifts[0], [0.0, 0.0])
    assert sorted(map(tuple, shifts[1:])) == [(-0.5, 0.0), (0.0, -0.5), (0.0, 0.5), (0.5, 0.0)]


@pytest.mark.parametrize("bad", [{"candidates": -1}, {"candidates": 2.5}, {"candidates": True}, {"sigma_deg": ()},
                                 {"sigma_deg": (2.0, 0.0)}, {"align_px": -0.5}, {"align_px": float("nan")}])
def test_refinement_config_is_validated(bad):
    with pytest.raises(ValueError):
        RotationRefinementConfig(**bad)


def _one(quat):
    return ParticleSet.from_poses(POS[None], np.asarray(quat)[None])


def test_each_refinement_stage_searches_about_the_best_rotation_found_so_far():
    """Stage 2 (σ 0.5°) draws its candidates about stage 1's winner, not about the start."""
    target = Rotation.from_euler("ZYX", [40.0, 10.0, -5.0], degrees=True).as_quat()
    start = (Rotation.from_rotvec(np.radians([0.0, 25.0, 0.0])) * Rotation.from_quat(target)).as_quat()
    score = PeakAt(target)
    cfg = RotationRefinementConfig(candidates=200, sigma_deg=(15.0, 0.5))
    RotationRefinement(cfg).refine(score, np.array([0.0, 0.0, 20.0]), start, np.random.default_rng(0))
    first, second = score.quats
    winner = first[int(np.argmax(score(ParticleSet.from_poses(np.zeros((len(first), 3)), first))))]
    assert np.degrees(geodesic_angle(winner[None], start))[0] > 5.0  # stage 1 moved
    spread = np.degrees(geodesic_angle(second, winner))
    assert spread.max() < 4.0  # 200 draws of a 0.5° σ per axis, all about the winner
