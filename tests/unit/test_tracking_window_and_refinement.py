"""The published rotation's window (tracking/smoothing.py) and rotation refinement
(tracking/refinement.py): cases with known answers, scipy as the oracle of rotation means."""

import numpy as np
from scipy.spatial.transform import Rotation

from uav_landing_vision.geometry import geodesic_angle
from uav_landing_vision.tracking.particles import ParticleSet
from uav_landing_vision.tracking.refinement import RotationRefinement, RotationRefinementConfig
from uav_landing_vision.tracking.smoothing import RotationWindow

DT_NS = 34_000_000


def angle_deg(a, b) -> float:
    return float(np.degrees(geodesic_angle(np.asarray(a)[None], np.asarray(b)))[0])


def test_estimates_exactly_the_step_apart_are_still_averaged():
    """The window restarts after a gap of *more than* ``max_step_s`` (0.0625 s is exact in binary)."""
    window = RotationWindow(2, 0.0625)
    q = Rotation.from_rotvec([0.0, 0.0, 0.1]).as_quat()
    p = Rotation.from_rotvec([0.0, 0.0, 0.2]).as_quat()
    window(0, q)
    assert angle_deg(window(62_500_000, p), Rotation.from_rotvec([0.0, 0.0, 0.15]).as_quat()) < 1e-6
    np.testing.assert_array_equal(window(62_500_000 + 62_500_001, q), q)  # one ns more: restarted


def test_a_steady_turn_in_small_steps_never_restarts_the_window():
    """The turn limit is between consecutive estimates: 6° a frame against a 10° limit keeps the
    window full, though its oldest and newest estimates are 18° apart; the output is scipy's mean
    of the last four."""
    window = RotationWindow(4, 0.051, max_turn_deg=10.0)
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    base = Rotation.from_euler("ZYX", [20.0, 5.0, -10.0], degrees=True)
    rots = [Rotation.from_rotvec(axis * np.radians(6.0 * k)) * base for k in range(7)]
    for k, r in enumerate(rots):
        out = window(k * DT_NS, r.as_quat())
        expected = Rotation.concatenate(rots[max(0, k - 3):k + 1]).mean()
        assert angle_deg(out, expected.as_quat()) < 1e-6, k


class Recorder:
    """A likelihood peaked at ``target`` (σ 3°) that records every batch of rotations it scores."""

    def __init__(self, target):
        self.target, self.batches = target, []

    def __call__(self, particles):
        self.batches.append(particles.quat.copy())
        return np.exp(-0.5 * (np.degrees(geodesic_angle(particles.quat, self.target)) / 3.0) ** 2)


def test_each_refinement_stage_searches_about_the_best_rotation_found_so_far():
    """Stage 2 (σ 0.5°) draws its candidates about stage 1's winner, not about the start."""
    target = Rotation.from_euler("ZYX", [40.0, 10.0, -5.0], degrees=True).as_quat()
    start = (Rotation.from_rotvec(np.radians([0.0, 25.0, 0.0])) * Rotation.from_quat(target)).as_quat()
    score = Recorder(target)
    cfg = RotationRefinementConfig(candidates=200, sigma_deg=(15.0, 0.5))
    RotationRefinement(cfg).refine(score, np.array([0.0, 0.0, 20.0]), start, np.random.default_rng(0))
    first, second = score.batches
    winner = first[int(np.argmax(score(ParticleSet.from_poses(np.zeros((len(first), 3)), first))))]
    assert angle_deg(winner, start) > 5.0  # stage 1 moved
    spread = np.degrees(geodesic_angle(second, winner))
    assert spread.max() < 4.0  # 200 draws of a 0.5° σ per axis, all about the winner
