"""The UPF tracker (tracking/upf.py): the carried set, the weights it resamples on, the
optimisation and its elitism, the published rotation and covariance band, on synthetic frames."""

import copy

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision.camera import CameraModel
from uav_landing_vision.geometry import geodesic_angle
from uav_landing_vision.model import fixed_wing_mesh
from uav_landing_vision.render import Renderer
from uav_landing_vision.sim.trajectory import FACING_CAMERA
from uav_landing_vision.tracking.optimisation import rotate_body
from uav_landing_vision.tracking.particles import ParticleSet
from uav_landing_vision.tracking.refinement import RotationRefinement, RotationRefinementConfig
from uav_landing_vision.tracking.upf import Tracker, TrackerConfig

CAMERA = CameraModel(320, 240, [[280.0, 0, 160.0], [0, 280.0, 120.0], [0, 0, 1]])
TRUE_QUAT = np.array(FACING_CAMERA, float)
TRUE_POS = np.array([0.1, -0.05, 6.0])
SKY = np.broadcast_to(np.array([90, 140, 210], np.uint8), (240, 320, 3)).copy()
DT_NS = 34_000_000  # the motion model's Δt (0.034 s)


@pytest.fixture(scope="module")
def renderer():
    return Renderer(CAMERA, fixed_wing_mesh("low"), max_batch=512)


@pytest.fixture(scope="module")
def frame(renderer):
    mask = renderer.silhouette_full(TRUE_QUAT, TRUE_POS)
    img = SKY.copy()
    img[mask] = (60, 60, 60)
    return img


class Hyps:
    def __init__(self, quats, positions):
        self.quats, self.positions = quats, positions


def hypotheses(seed: int, count: int = 60) -> Hyps:
    """Truth plus noise: σ 5 cm in X, Y, 15 cm in depth, 4° per axis."""
    rng = np.random.default_rng(seed)
    quats = rotate_body(np.tile(TRUE_QUAT, (count, 1)), rng.normal(size=(count, 3)) * np.radians(4.0))
    return Hyps(quats, TRUE_POS + rng.normal(size=(count, 3)) * 0.05 * np.array([1, 1, 3]))


def tracker(renderer, variant="C4N0", **overrides) -> Tracker:
    return Tracker(TrackerConfig.from_variant(variant, particles=40, boosted=10, **overrides), CAMERA, renderer)


@pytest.mark.parametrize("variant", ["C2N0", "C4N0"])
def test_a_frame_without_hypotheses_carries_all_m_particles(renderer, frame, variant):
    """Alg. 3 step 4 mixes M − M0 boosted poses with the best M0 carried ones; with no boosted
    poses the whole set of M is carried (predicted), none left out for absent hypotheses."""
    t = tracker(renderer, variant)
    for k in range(2):
        t.step(frame, k * DT_NS, hypotheses(10 + k))
    result = t.step(frame, 2 * DT_NS, None)
    assert result.has_pose and len(result.particles) == 40


@pytest.mark.parametrize("variant", ["C3N0", "C4N0", "C5N0"])
def test_the_weights_resampled_on_are_the_scores_of_the_filtered_poses(renderer, frame, variant):
    """§5.4.1 after §5.2.3: the carried particles are scored where their filters put them after the
    z_t update, so every published particle's weight is the objective at its own pose (no
    optimisation here, N = 0; the rotation prior, whose anchor moves at the end of a frame, off)."""
    t = tracker(renderer, variant, rotation_prior_sigma_deg=0.0)
    for k in range(3):
        result = t.step(frame, k * DT_NS, hypotheses(20 + k))
    assert len(t.filters) == 40 and result.has_pose
    np.testing.assert_allclose(result.particles.weight, t._score(result.particles), rtol=1e-9, atol=1e-12)


class RecordingOptimiser:
    def __init__(self, inner):
        self.inner, self.iterations = inner, []

    def run(self, particles, score, rng, iterations):
        self.iterations.append(iterations)
        return self.inner.run(particles, score, rng, iterations)


@pytest.mark.parametrize("variant, runs", [("C4N0", []), ("C4N1", [1, 1]), ("C4N3", [3, 3])])
def test_pose_optimisation_runs_n_iterations_every_frame(renderer, frame, variant, runs):
    """§5.5: N optimisation iterations per frame, N = 1 included; N = 0 skips the stage."""
    t = tracker(renderer, variant)
    t.optimiser = RecordingOptimiser(t.optimiser)
    for k in range(2):
        t.step(frame, k * DT_NS, hypotheses(30 + k))
    assert t.optimiser.iterations == runs


class FixedOptimiser:
    """Returns a given set whatever it is asked."""

    def __init__(self, out):
        self.out = out

    def run(self, particles, score, rng, iterations):
        return self.out


def test_elitism_puts_the_best_pre_optimisation_pose_in_place_of_the_worst_optimised_one(renderer):
    t = tracker(renderer, "C4N2")
    rng = np.random.default_rng(0)
    quats = Rotation.random(10, random_state=1).as_quat()
    before = ParticleSet.from_poses(rng.normal(size=(5, 3)) + [0, 0, 6], quats[:5], [0.2, 0.9, 0.1, 0.3, 0.4])
    out = ParticleSet.from_poses(rng.normal(size=(5, 3)) + [0, 0, 6], quats[5:], [0.5, 0.1, 0.7, 0.2, 0.6])
    t.optimiser = FixedOptimiser(out)
    kept = t._optimise(before)
    assert sorted(kept.weight) == sorted([0.9, 0.5, 0.7, 0.2, 0.6])
    poses = {tuple(p) for p in kept.pos}
    assert tuple(before.pos[1]) in poses and tuple(out.pos[1]) not in poses
    assert all(tuple(out.pos[i]) in poses for i in (0, 2, 3, 4))
    better = ParticleSet.from_poses(out.pos, out.quat, [0.5, 0.1, 0.95, 0.2, 0.6])
    t.optimiser = FixedOptimiser(better)
    assert t._optimise(before) is better  # an optimised pose beat it: the optimiser's set as it is


def test_the_published_rotation_is_the_weighted_mean_refined_by_the_aligned_objective(renderer, frame):
    """Output step (ours): the refinement searches about the particles' weighted mean rotation at
    the mean position, scoring each candidate at its best image shift (``refine.align_px``); with
    a one-frame window the published rotation is its result (the refinement's own generator)."""
    refine = RotationRefinementConfig(candidates=32, sigma_deg=(4.0, 1.5), align_px=0.5)
    t = tracker(renderer, "C4N2", refine=refine, rotation_window=1, rotation_prior_sigma_deg=0.0, estimate="mean")
    for k in range(3):
        rng = copy.deepcopy(t._refine_rng)
        result = t.step(frame, k * DT_NS, hypotheses(40 + k))
        pos, quat = result.particles.mean_pose()
        np.testing.assert_allclose(result.position, pos, rtol=0, atol=1e-12)
        expected, _ = RotationRefinement(refine).refine(t._refinement_score, pos, quat, rng)
        assert np.degrees(geodesic_angle(result.quat, expected)) < 1e-6


def test_the_rotation_window_averages_frames_one_dt_apart_and_restarts_after_a_dropped_frame(renderer, frame):
    """At the camera's rate (stamps Δt apart) ``rotation_window: 2`` publishes scipy's mean of this
    and the last frame's rotations; after a frame two Δt later (one dropped) it restarts."""
    stamps = [0, DT_NS, 2 * DT_NS, 4 * DT_NS, 5 * DT_NS]
    results = {}
    for window in (1, 2):
        t = tracker(renderer, "C4N1", rotation_window=window)
        results[window] = [t.step(frame, s, hypotheses(50 + k)) for k, s in enumerate(stamps)]
    plain, windowed = results[1], results[2]
    for k in (1, 2, 4):
        expected = Rotation.from_quat([plain[k - 1].quat, plain[k].quat]).mean().as_quat()
        assert np.degrees(geodesic_angle(windowed[k].quat, expected)) < 1e-6
    np.testing.assert_array_equal(windowed[3].quat, plain[3].quat)


def test_the_covariance_band_is_that_of_the_estimate_depth_not_its_range(renderer, frame):
    """The bands of ``covariance_bands_m`` split the estimate's depth z: with a bound between the
    estimate's depth and its range (≥ depth off the optical axis) the first band's σ apply."""
    floors, fractions = (1.0, 2.0, 3.0), (0.1, 0.2, 0.3)
    zero = {"covariance_floor_deg": (0.0,) * 3, "covariance_range_fraction": (0.0,) * 3}

    def last(**overrides):
        t = tracker(renderer, "C4N1", **overrides)
        return [t.step(frame, k * DT_NS, hypotheses(60 + k)) for k in range(2)][-1]

    a = last(**zero)
    depth, rng = a.position[2], np.linalg.norm(a.position)
    assert rng - depth > 1e-4
    b = last(covariance_floor_deg=floors, covariance_range_fraction=fractions,
             covariance_bands_m=(0.5 * (depth + rng), 60.0))
    np.testing.assert_array_equal(a.position, b.position)
    np.testing.assert_allclose(b.covariance[3:, 3:] - a.covariance[3:, 3:], np.radians(floors[0]) ** 2 * np.eye(3),
                               atol=1e-15)
    np.testing.assert_allclose(b.covariance[:3, :3] - a.covariance[:3, :3],
                               fractions[0] ** 2 * np.outer(a.position, a.position))


def test_c4_is_the_ukf_with_the_ubif_as_table_6_11_says():
    assert TrackerConfig(variant="C3").motion.rotation_filter == "ukf"
    assert TrackerConfig(variant="C4").motion.rotation_filter == "ubif"
    assert TrackerConfig(variant="C5").motion.rotation_filter == "ubigaf"
    assert not TrackerConfig(variant="C1").uses_filters and not TrackerConfig(variant="C2").uses_filters
