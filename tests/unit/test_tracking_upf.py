"""The UPF tracker (tracking/upf.py) on synthetic frames: proposals, determinism, track states,
covariance, configuration."""

import copy
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision.camera import CameraModel
from uav_landing_vision.config import ConfigError
from uav_landing_vision.filters.motion import MotionFilterConfig
from uav_landing_vision.geometry import geodesic_angle, omega_quat, quat_conjugate, quat_multiply
from uav_landing_vision.model import fixed_wing_mesh
from uav_landing_vision.render import Renderer
from uav_landing_vision.sim.trajectory import FACING_CAMERA
from uav_landing_vision.tracking.motion_bank import MotionBank
from uav_landing_vision.tracking.optimisation import PFOConfig, rotate_body
from uav_landing_vision.tracking.particles import ParticleSet
from uav_landing_vision.tracking.refinement import RotationRefinement, RotationRefinementConfig
from uav_landing_vision.tracking.track_state import TrackMonitor, TrackState, TrackStateConfig
from uav_landing_vision.tracking.upf import (
    MAX_PREDICTION_STEPS,
    Tracker,
    _hypothesis_set,
    TrackerConfig,
    coasting_covariance,
    constant_velocity_prediction,
    depth_band,
    load_tracker_config,
    parse_variant,
    particle_covariance,
    prediction_steps,
)

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
    """The UAV (dark grey) at the true pose over a plain sky, as a rectified frame."""
    mask = renderer.silhouette_full(TRUE_QUAT, TRUE_POS)
    img = SKY.copy()
    img[mask] = (60, 60, 60)
    return img


def shot(img: np.ndarray, k: int) -> np.ndarray:
    """``img`` as a live camera's frame k: ±1 of seeded sensor noise, so no two frames are identical."""
    noise = np.random.default_rng(k).integers(-1, 2, size=img.shape)
    return np.clip(img.astype(int) + noise, 0, 255).astype(np.uint8)


class Hyps:
    """Boosted poses as the pose_boosting node publishes them: arrays, best first."""

    def __init__(self, quats, positions):
        self.quats, self.positions = quats, positions


def hypotheses(seed: int, count: int = 60, trans_sigma: float = 0.05, rot_sigma_deg: float = 4.0) -> Hyps:
    """Truth plus noise: σ 5 cm in X, Y, 15 cm in Z (depth), 4° per axis."""
    rng = np.random.default_rng(seed)
    quats = rotate_body(np.tile(TRUE_QUAT, (count, 1)), rng.normal(size=(count, 3)) * np.radians(rot_sigma_deg))
    return Hyps(quats, TRUE_POS + rng.normal(size=(count, 3)) * trans_sigma * np.array([1, 1, 3]))


def run(renderer, frame, variant: str, seed: int = 0, frames: int = 4, **overrides):
    cfg = TrackerConfig.from_variant(variant, particles=40, boosted=10, seed=seed, **overrides)
    tracker = Tracker(cfg, CAMERA, renderer)
    return tracker, [tracker.step(frame, k, hypotheses(100 + k)) for k in range(frames)]


def with_decoys(hyps: Hyps) -> Hyps:
    """Every other hypothesis replaced by a decoy 1.5 m to the side and turned by 25°: a tracker
    that did not score the frame would take them as readily as the others."""
    quats, positions = hyps.quats.copy(), hyps.positions.copy()
    positions[::2] += (1.5, 0.0, 0.0)
    quats[::2] = rotate_body(quats[::2], np.tile([0.0, 0.0, np.radians(25.0)], (len(quats[::2]), 1)))
    return Hyps(quats, positions)


@pytest.mark.parametrize("variant", ["C1N0", "C2N1", "C3N0", "C4N2", "C5N1"])
def test_every_variant_tracks_the_synthetic_uav(renderer, frame, variant):
    """A live camera's frames (no two the same) with half the hypotheses decoys: the track is
    confirmed, and its pose is the UAV's, not the decoys' nor a mix of the two."""
    tracker = Tracker(TrackerConfig.from_variant(variant, particles=40, boosted=10), CAMERA, renderer)
    results = [tracker.step(shot(frame, k), k, with_decoys(hypotheses(100 + k))) for k in range(4)]
    last = results[-1]
    assert last.has_pose and last.state == TrackState.TRACKING
    assert np.linalg.norm(last.position - TRUE_POS) < 0.3
    assert np.degrees(geodesic_angle(last.quat, TRUE_QUAT)) < 8.0
    assert 1.0 <= last.effective_particles <= 40.0
    assert set(last.stage_ms) >= {"weighting", "optimisation"} and all(v >= 0 for v in last.stage_ms.values())
    assert len(last.particles) == 40


def test_hypothesis_counts_follow_the_variant(renderer, frame):
    c4 = Tracker(TrackerConfig.from_variant("C4N0", particles=40, boosted=10), CAMERA, renderer)
    c1 = Tracker(TrackerConfig.from_variant("C1N0", particles=40, boosted=10), CAMERA, renderer)
    assert c4.hypotheses_needed() == 40 and c1.hypotheses_needed() == 40
    c4.step(frame, 0, hypotheses(1))
    c1.step(frame, 0, hypotheses(1))
    assert c4.hypotheses_needed() == 10 and c1.hypotheses_needed() == 40


def assert_same_poses(particles, pos, quat):
    np.testing.assert_allclose(particles.pos, pos, rtol=0, atol=1e-12)
    assert np.degrees(geodesic_angle(particles.quat, quat)).max() < 1e-6


@pytest.mark.parametrize("variant", ["C2N0", "C4N0"])
def test_the_mix_is_the_best_carried_particles_and_the_first_hypotheses_pose_by_pose(renderer, frame, variant):
    """Alg. 3 step 1: hypotheses come best first, so a frame takes the first ``hypotheses_needed()``
    of them, each position with its own rotation, after the best M0 carried particles (the set is
    kept best first) predicted over the frames' gap: by (3.12) in C2 (the oracle: the same
    draws), by the filters in C4 (a track at rest stays where it was)."""
    tracker = Tracker(TrackerConfig.from_variant(variant, particles=40, boosted=10), CAMERA, renderer)
    first = hypotheses(1)  # 60 poses
    tracker.step(frame, 0, first)
    assert_same_poses(tracker._fresh, first.positions[:40], first.quats[:40])
    carried = tracker.particles
    assert np.all(np.diff(carried.weight) <= 0) and carried.weight[0] > carried.weight[-1]  # best first
    second = hypotheses(2)
    best, rng = carried.take(np.arange(30)), copy.deepcopy(tracker.rng)
    for _ in range(3 if variant == "C2N0" else 0):
        best = constant_velocity_prediction(best, tracker.config.motion, rng)
    mixed = tracker._mix(_hypothesis_set(second, tracker.hypotheses_needed()), 3)  # two frames unseen
    assert len(mixed) == 40
    assert_same_poses(mixed.take(np.arange(30)), best.pos, best.quat)
    assert_same_poses(mixed.take(np.arange(30, 40)), second.positions[:10], second.quats[:10])


def test_optimisation_does_not_lose_the_best_pose(renderer, frame):
    """With elitism, N > 0 never ends a frame below the best pre-optimisation score."""
    _, n0 = run(renderer, frame, "C4N0", frames=1)
    _, n3 = run(renderer, frame, "C4N3", frames=1)
    assert n3[0].best_likelihood >= n0[0].best_likelihood


@pytest.mark.parametrize("optimiser", ["pfo", "pso", "constricted_pso", "gabf"])
def test_every_optimiser_keeps_m_particles_and_copes_with_one_hypothesis(renderer, frame, optimiser):
    big = Tracker(TrackerConfig.from_variant("C4N2", particles=150, boosted=25, optimiser=optimiser), CAMERA, renderer)
    for k in range(2):  # GAbF optimises its top_b (100) best and carries the rest
        assert len(big.step(frame, k, hypotheses(100 + k, count=150)).particles) == 150
    cfg = TrackerConfig.from_variant("C4N2", particles=40, boosted=10, optimiser=optimiser)
    one = Tracker(cfg, CAMERA, renderer).step(frame, 0, hypotheses(1, count=1))
    assert one.has_pose and len(one.particles) == 1


def test_a_renderer_too_small_for_the_refinement_is_refused_at_construction(renderer):
    cfg = TrackerConfig.from_variant("C4N2", particles=40, refine=RotationRefinementConfig(candidates=512))
    with pytest.raises(ValueError, match="512 \\+ 1 refinement poses"):
        Tracker(cfg, CAMERA, renderer)


def test_effective_particles_are_those_of_the_importance_weights_before_resampling(renderer, frame):
    """(6.5): one pose on the UAV among 39 off the image is one effective particle, not the 40
    copies of it that resampling makes."""
    hyps = hypotheses(3, count=40)
    hyps.positions[1:] = [50.0, 0.0, 6.0]  # off the image: they score 0
    result = Tracker(TrackerConfig.from_variant("C4N0", particles=40, boosted=10), CAMERA, renderer).step(frame, 0, hyps)
    assert result.has_pose and result.effective_particles == pytest.approx(1.0)
    spread = Tracker(TrackerConfig.from_variant("C4N0", particles=40, boosted=10), CAMERA, renderer)
    assert 5.0 < spread.step(frame, 0, hypotheses(3, count=40)).effective_particles <= 40.0


def test_a_frame_not_after_the_last_is_refused_before_anything_changes(renderer, frame):
    tracker, results = run(renderer, frame, "C4N2", frames=3)
    particles = tracker.particles
    with pytest.raises(ValueError, match="not after the last one"):
        tracker.step(frame, 2, hypotheses(7))  # repeated stamp
    assert tracker.particles is particles and tracker.state == results[-1].state
    tracker.reset()  # a new time-line: earlier stamps are frames again
    assert tracker.step(frame, 0, hypotheses(8)).has_pose


@pytest.mark.parametrize("bad", ["frame", "hypotheses"])
def test_a_refused_frame_leaves_no_trace(renderer, frame, bad):
    """A frame refused for a bad image or bad hypotheses changes nothing: its stamp may come
    again, and the next frame is predicted from the last tracked one, as if it never came."""
    dt_ns = 34_000_000
    steps = [(0, hypotheses(100)), (dt_ns, hypotheses(101)), (3 * dt_ns, hypotheses(102))]
    plain, refused = (Tracker(TrackerConfig.from_variant("C4N2", particles=40, boosted=10), CAMERA, renderer)
                      for _ in range(2))
    expected = [plain.step(frame, s, h) for s, h in steps]
    refused.step(frame, *steps[0])
    refused.step(frame, *steps[1])
    nan_hyps = Hyps(hypotheses(9).quats, np.full((60, 3), np.nan))
    args = (frame[:120], hypotheses(9)) if bad == "frame" else (frame, nan_hyps)
    with pytest.raises(ValueError, match="shape|finite"):
        refused.step(args[0], 2 * dt_ns, args[1])
    last = refused.step(frame, *steps[2])
    np.testing.assert_array_equal(last.position, expected[-1].position)
    np.testing.assert_array_equal(last.quat, expected[-1].quat)


def test_a_best_particle_at_zero_depth_does_not_break_the_depth_gate(renderer, frame):
    """A track whose best particle sits at depth 0 (hypotheses on the camera centre, all scoring
    0) gates out the next frame's boosted depth instead of dividing by zero."""
    tracker = Tracker(TrackerConfig.from_variant("C4N0", particles=40, boosted=10), CAMERA, renderer)
    on_centre = hypotheses(1)
    on_centre.positions = on_centre.positions * np.array([1.0, 1.0, 0.0])
    assert not tracker.step(frame, 0, on_centre).has_pose and tracker.particles.pos[0, 2] == 0.0
    result = tracker.step(frame, 1, hypotheses(2))
    assert tracker._anchor is None and result.state == TrackState.ACQUIRING


def test_a_lost_track_still_refuses_a_frame_not_after_the_last(renderer, frame):
    """Losing the track (here: an empty sky) is no new time-line; only reset() starts one."""
    track = TrackStateConfig(acquire_likelihood=0.1, lost_likelihood=0.01, lost_frames=1)
    tracker = Tracker(TrackerConfig.from_variant("C4N0", particles=40, boosted=10, track=track), CAMERA, renderer)
    assert tracker.step(frame, 10, hypotheses(1)).has_pose
    assert tracker.step(SKY, 11, hypotheses(2)).state == TrackState.LOST
    with pytest.raises(ValueError, match="not after the last one"):
        tracker.step(frame, 5, hypotheses(3))
    assert tracker.step(SKY, 12, None).state == TrackState.LOST  # nothing to track at all
    with pytest.raises(ValueError, match="not after the last one"):
        tracker.step(frame, 12, hypotheses(3))
    tracker.reset()
    assert tracker.step(frame, 5, hypotheses(3)).has_pose


def test_prediction_steps_are_the_stamp_gap_in_whole_dt():
    dt_ns = 34_000_000
    assert prediction_steps(None, 0.034) == 1  # the first frame
    gaps = (1, dt_ns - 1, dt_ns, dt_ns + 1, 3 * dt_ns, int(2.4 * dt_ns), int(2.6 * dt_ns), int(1.5 * dt_ns) + 1)
    assert [prediction_steps(g, 0.034) for g in gaps] == [1, 1, 1, 1, 3, 2, 3, 2]  # rounded, not cut
    assert prediction_steps(10**18, 0.034) == MAX_PREDICTION_STEPS  # a clock jump costs a bounded prediction


@pytest.mark.parametrize("variant", ["C3N0", "C4N0", "C5N0"])
def test_the_prediction_spans_the_frames_the_tracker_did_not_see(renderer, frame, variant):
    """(3.12) over the time since the last frame: three Δt after the last one (two frames
    dropped), carried particles moving at v are predicted 3·v·Δt on, not v·Δt."""
    dt_ns = 34_000_000
    cfg = TrackerConfig.from_variant(variant, particles=40, boosted=10, refine=RotationRefinementConfig())
    tracker = Tracker(cfg, CAMERA, renderer)
    for k in range(2):
        tracker.step(frame, k * dt_ns, hypotheses(100 + k))
    v = np.array([4.0, 0.0, 0.0])
    ts = tracker.filters.trans_state
    tracker.filters.trans_state = replace(ts, x=np.hstack([ts.x[:, :3], np.tile(v, (len(ts.x), 1))]))
    before = tracker.particles.pos.mean(axis=0)
    assert tracker.step(frame, 4 * dt_ns, None).has_pose  # frames 2 and 3 not seen, no hypotheses
    shift = tracker.particles.pos.mean(axis=0) - before
    assert shift[0] == pytest.approx(3 * v[0] * 0.034, abs=0.06)  # along v; one Δt would be 0.136 m


def test_same_seed_same_estimates_other_seed_differs(renderer, frame):
    """Also after reset(): a replay started again (the tracker node resets on a new time-line)
    gives the estimates of the first time; the generators kept running through it before."""
    tracker, a = run(renderer, frame, "C4N2", seed=7)
    _, b = run(renderer, frame, "C4N2", seed=7)
    _, c = run(renderer, frame, "C4N2", seed=8)
    tracker.reset()
    again = [tracker.step(frame, k, hypotheses(100 + k)) for k in range(len(a))]
    for ra, rb in [*zip(a, b), *zip(a, again)]:
        np.testing.assert_array_equal(ra.position, rb.position)
        np.testing.assert_array_equal(ra.quat, rb.quat)
        np.testing.assert_array_equal(ra.covariance, rb.covariance)
    assert any(not np.array_equal(ra.position, rc.position) for ra, rc in zip(a, c))


def test_track_states_lost_reinitialise_acquire_track(renderer, frame):
    cfg = TrackerConfig.from_variant("C4N0", particles=40, boosted=10,
                                     track=TrackStateConfig(acquire_likelihood=0.1, acquire_frames=2,
                                                            lost_likelihood=0.01, lost_frames=2))
    tracker = Tracker(cfg, CAMERA, renderer)
    nothing = tracker.step(shot(frame, 0), 0, None)  # no particles, no hypotheses
    assert nothing.state == TrackState.LOST and not nothing.has_pose
    states = [tracker.step(shot(frame, k), k, hypotheses(k)).state for k in range(1, 4)]
    assert states == [TrackState.ACQUIRING, TrackState.TRACKING, TrackState.TRACKING]
    # the UAV leaves: an empty sky scores 0 everywhere
    first = tracker.step(SKY, 4, hypotheses(4))
    assert first.state == TrackState.ACQUIRING and not first.has_pose  # not TRACKING on a frame that scored nothing
    second = tracker.step(SKY, 5, hypotheses(5))
    assert second.state == TrackState.LOST and tracker.particles is None
    assert tracker.hypotheses_needed() == 40
    again = tracker.step(shot(frame, 6), 6, hypotheses(6))
    assert again.state == TrackState.ACQUIRING and again.has_pose


def test_a_track_coasting_without_hypotheses_is_no_longer_vouched_for(renderer, frame):
    """The UAV leaves a sky-and-sea frame: the particles settle on the horizon, which the colour
    metric scores above lost_likelihood, so only the coasting limit ends TRACKING; hypotheses
    must come back before the track is TRACKING again."""
    track = TrackStateConfig(acquire_likelihood=0.1, acquire_frames=2, lost_likelihood=0.01, max_coast_frames=4)
    tracker = Tracker(TrackerConfig.from_variant("C4N0", particles=40, boosted=10, track=track), CAMERA, renderer)
    assert [tracker.step(shot(frame, k), k, hypotheses(k)).state for k in range(3)][-1] == TrackState.TRACKING
    horizon = SKY.copy()
    horizon[118:] = (40, 70, 90)  # sea below a horizon through the UAV's last position
    gone = [tracker.step(shot(horizon, k), k, None) for k in range(3, 11)]
    assert min(r.best_likelihood for r in gone) > track.lost_likelihood  # the horizon scores: no LOST
    assert [r.state for r in gone] == [TrackState.TRACKING] * 3 + [TrackState.ACQUIRING] * 5
    assert all(r.has_pose for r in gone)  # the estimate is still published, as unconfirmed
    back = [tracker.step(shot(frame, k), k, hypotheses(k)).state for k in range(11, 14)]
    assert back == [TrackState.ACQUIRING, TrackState.TRACKING, TrackState.TRACKING]
    with pytest.raises(ValueError, match="max_coast_frames"):
        TrackStateConfig(max_coast_frames=-1)


def test_a_frozen_camera_repeating_its_last_frame_no_longer_vouches_for_the_track(renderer, frame):
    """A camera or driver that freezes re-sends its last picture with new stamps: boosting finds
    the UAV in it every frame and the track holds it still, so the likelihood alone would say
    TRACKING while the aircraft flies on. After max_repeated_frames identical frames in a row the
    track is unconfirmed until the picture changes; one repeat below the limit changes nothing."""
    track = TrackStateConfig(acquire_likelihood=0.1, acquire_frames=2, lost_likelihood=0.01, max_repeated_frames=3)
    tracker = Tracker(TrackerConfig.from_variant("C4N0", particles=40, boosted=10, track=track), CAMERA, renderer)
    live = [tracker.step(shot(frame, k), k, hypotheses(k)).state for k in range(3)]
    assert live == [TrackState.ACQUIRING, TrackState.TRACKING, TrackState.TRACKING]
    frozen = shot(frame, 2)  # frame 2's picture again and again
    states = [tracker.step(frozen.copy(), k, hypotheses(k)) for k in range(3, 8)]
    assert [r.state for r in states] == [TrackState.TRACKING] * 2 + [TrackState.ACQUIRING] * 3
    assert all(r.has_pose and r.best_likelihood > track.acquire_likelihood for r in states)  # only the repeats tell
    back = [tracker.step(shot(frame, k), k, hypotheses(k)).state for k in range(8, 11)]
    assert back == [TrackState.ACQUIRING, TrackState.TRACKING, TrackState.TRACKING]
    tracker.reset()  # a new time-line forgets the last picture: its first frame is not a repeat
    assert [tracker.step(frozen, k, hypotheses(k)).state for k in range(3)] == [
        TrackState.ACQUIRING, TrackState.TRACKING, TrackState.TRACKING]
    with pytest.raises(ValueError, match="max_repeated_frames"):
        TrackStateConfig(max_repeated_frames=-1)


def test_coasting_and_repeats_count_frame_intervals_not_tracked_frames(renderer, frame):
    """A tracker that sees every 3rd frame (stamps 3 Δt apart) coasts 3 intervals per frame without
    hypotheses, so a limit of 4 intervals unconfirms its track at the 2nd such frame, not the 4th,
    and one repeated picture over 3 intervals reaches a limit of 3; the coasting covariance grows
    by 3 intervals per frame."""
    gap = round(3 * 0.034e9)
    track = TrackStateConfig(acquire_likelihood=0.1, acquire_frames=2, lost_likelihood=0.01, max_coast_frames=4,
                             max_repeated_frames=3)
    cfg = TrackerConfig.from_variant("C4N1", particles=40, boosted=10, track=track)
    tracker = Tracker(cfg, CAMERA, renderer)
    assert [tracker.step(shot(frame, k), k * gap, hypotheses(k)).state for k in range(3)][-1] == TrackState.TRACKING
    coasting = [tracker.step(shot(frame, k), k * gap, None) for k in range(3, 5)]
    assert [r.state for r in coasting] == [TrackState.TRACKING, TrackState.ACQUIRING]
    first, second = coasting[0].position, coasting[1].position
    s_pos = [n * cfg.covariance_coast_fraction * np.linalg.norm(p) for n, p in ((3, first), (6, second))]
    off = Tracker(replace(cfg, covariance_coast_fraction=0.0, covariance_coast_deg=0.0), CAMERA, renderer)
    for k in range(3):
        off.step(shot(frame, k), k * gap, hypotheses(k))
    for k, r, s in zip(range(3, 5), coasting, s_pos):
        extra = r.covariance - off.step(shot(frame, k), k * gap, None).covariance
        np.testing.assert_allclose(np.diag(extra)[:3], s**2)

    tracker = Tracker(cfg, CAMERA, renderer)
    assert [tracker.step(shot(frame, k), k * gap, hypotheses(k)).state for k in range(3)][-1] == TrackState.TRACKING
    assert tracker.step(shot(frame, 2), 3 * gap, hypotheses(3)).state == TrackState.ACQUIRING  # frame 2 again


def test_prediction_carries_the_track_through_a_frame_without_hypotheses(renderer, frame):
    tracker, _ = run(renderer, frame, "C4N1", frames=3)
    res = tracker.step(frame, 3, None)
    assert res.has_pose and res.state != TrackState.LOST
    assert np.linalg.norm(res.position - TRUE_POS) < 0.5
    c1, _ = run(renderer, frame, "C1N0", frames=2)
    assert c1.step(frame, 2, None).state == TrackState.LOST  # C1 has no prediction


def test_c2_prediction_is_3_12():
    """(3.12): ``p + v Δt + ξ^l_p``, ``v + ξ^l_v``, ``q ⊗ Ω(ω) ⊗ Ω(ξ^r)`` and ``ω + ξ^r``, the
    disturbances drawn in that order."""
    cfg = MotionFilterConfig(dt=0.1, omega_process_std=2.0)
    rng = np.random.default_rng(5)
    p = ParticleSet(rng.normal(size=(6, 3)), Rotation.random(6, random_state=5).as_quat(), rng.normal(size=(6, 3)),
                    rng.normal(size=(6, 3)) * 5.0, np.full(6, 1 / 6))
    out = constant_velocity_prediction(p, cfg, np.random.default_rng(9))
    noise = np.random.default_rng(9).normal(size=(3, 6, 3)) * np.array([0.05, 0.5, 2.0])[:, None, None]
    np.testing.assert_allclose(out.pos, p.pos + p.vel * 0.1 + noise[0])
    np.testing.assert_allclose(out.vel, p.vel + noise[1])
    np.testing.assert_allclose(out.omega, p.omega + noise[2])
    expected = quat_multiply(quat_multiply(p.quat, omega_quat(p.omega, 0.1)), omega_quat(noise[2], 0.1))
    assert np.degrees(geodesic_angle(out.quat, expected)).max() < 1e-9


def test_track_monitor_transitions():
    m = TrackMonitor(TrackStateConfig(acquire_likelihood=0.5, acquire_frames=2, lost_likelihood=0.1, lost_frames=3))
    assert m.state == TrackState.LOST
    m.initialised()
    assert [m.update(v) for v in (0.6, 0.3, 0.6, 0.6)] == [TrackState.ACQUIRING] * 3 + [TrackState.TRACKING]
    # A bad frame is not vouched for (the bridge sent its pose); LOST only after lost_frames in a row.
    assert [m.update(v) for v in (0.05, 0.05, 0.2, 0.6, 0.6)] == [TrackState.ACQUIRING] * 4 + [TrackState.TRACKING]
    assert [m.update(v) for v in (0.2, 0.1, 0.6)] == [TrackState.TRACKING] * 3  # on lost_likelihood: not bad
    assert [m.update(v) for v in (0.05, 0.05)] == [TrackState.ACQUIRING] * 2
    assert m.update(0.0) == TrackState.LOST
    m.initialised()
    assert [m.update(0.6, coasting=c) for c in (0, 0, 15, 16, 0, 0)] == [  # max_coast_frames 15 by default
        TrackState.ACQUIRING, TrackState.TRACKING, TrackState.ACQUIRING, TrackState.ACQUIRING,
        TrackState.ACQUIRING, TrackState.TRACKING]
    with pytest.raises(ValueError):
        TrackStateConfig(acquire_likelihood=0.1, lost_likelihood=0.2)


def test_track_monitor_thresholds_are_inclusive_as_documented_and_coasting_limit_zero_is_off():
    """``b ≥ acquire_likelihood`` counts toward TRACKING and ``b < lost_likelihood`` toward LOST
    (a score on a threshold: good, not bad); ``max_coast_frames: 0`` and ``max_repeated_frames: 0``
    never unconfirm a track, a repeat count at the limit does;
    a re-initialisation starts both counts afresh."""
    cfg = TrackStateConfig(acquire_likelihood=0.5, acquire_frames=2, lost_likelihood=0.1, lost_frames=2)
    m = TrackMonitor(cfg)
    m.initialised()
    assert [m.update(0.5) for _ in range(2)] == [TrackState.ACQUIRING, TrackState.TRACKING]  # on it: good
    m.initialised()  # the good frames before it do not count
    assert m.update(0.9) == TrackState.ACQUIRING
    assert [m.update(0.1) for _ in range(4)] == [TrackState.ACQUIRING] * 4  # on lost_likelihood: not bad
    m.update(0.05)
    m.initialised()  # nor the bad one: one more bad frame is not lost_frames in a row
    assert m.update(0.05) == TrackState.ACQUIRING and m.update(0.05) == TrackState.LOST
    never = TrackMonitor(replace(cfg, max_coast_frames=0, max_repeated_frames=0))
    never.initialised()
    states = [never.update(0.9, coasting=c, repeated=c) for c in (0, 0, 1, 50, 1000)]
    assert states == [TrackState.ACQUIRING] + [TrackState.TRACKING] * 4
    limit = TrackMonitor(cfg)  # max_repeated_frames 3 by default, inclusive
    limit.initialised()
    assert [limit.update(0.9, repeated=r) for r in (0, 1, 2, 3, 0, 0)] == [
        TrackState.ACQUIRING, TrackState.TRACKING, TrackState.TRACKING, TrackState.ACQUIRING,
        TrackState.ACQUIRING, TrackState.TRACKING]


def test_covariance_is_the_weighted_particle_spread_about_the_estimate_in_camera_axes():
    rng = np.random.default_rng(3)
    m = 500
    rot = rng.normal(size=(m, 3)) * np.radians([2.0, 4.0, 1.0])
    pos = TRUE_POS + rng.normal(size=(m, 3)) * [0.1, 0.2, 0.5]
    from scipy.spatial.transform import Rotation

    quat = (Rotation.from_rotvec(rot) * Rotation.from_quat(TRUE_QUAT)).as_quat()  # camera-axis rotations
    w = rng.uniform(0.5, 1.0, m)
    cloud = ParticleSet(pos, quat, np.zeros((m, 3)), np.zeros((m, 3)), w)
    cov = particle_covariance(cloud, TRUE_POS, TRUE_QUAT)
    d = np.hstack([pos - TRUE_POS, rot])
    mean = w @ d / w.sum()
    # the spread about the cloud's mean plus the estimate's offset from it
    ref = np.cov(d.T, aweights=w, bias=True) + np.outer(mean, mean)
    np.testing.assert_allclose(cov, ref, atol=1e-10)
    turned = (Rotation.from_rotvec([0.0, 0.0, 0.3]) * Rotation.from_quat(TRUE_QUAT)).as_quat()  # 17° off the cloud
    assert particle_covariance(cloud, TRUE_POS, turned)[5, 5] >= 0.3**2 * 0.95
    assert np.all(np.linalg.eigvalsh(cov) >= -1e-12)
    one = cloud.take(np.zeros(m, int))  # every particle at the estimate: the floors alone
    floored = particle_covariance(one, one.pos[0], one.quat[0], 0.05, np.radians(1.0))
    np.testing.assert_allclose(floored, np.diag([0.05**2] * 3 + [np.radians(1.0) ** 2] * 3), atol=1e-12)


def test_tracker_covariance_is_psd_and_floored(renderer, frame):
    _, results = run(renderer, frame, "C4N2")
    cov = results[-1].covariance
    assert cov.shape == (6, 6) and np.allclose(cov, cov.T)
    assert np.linalg.eigvalsh(cov).min() >= 0.999 * np.radians(1.0) ** 2  # the smaller floor (1°)
    assert np.all(np.diag(cov)[:3] >= 0.05**2)
    pos = results[-1].position
    line_of_sight = pos / np.linalg.norm(pos)
    assert line_of_sight @ cov[:3, :3] @ line_of_sight >= (0.05 * np.linalg.norm(pos)) ** 2


@pytest.mark.parametrize("bands, used", [((15.0, 60.0), 0), ((3.0, 60.0), 1), ((1.0, 3.0), 2)])
def test_covariance_floors_and_range_fraction_of_the_estimate_depth_band(renderer, frame, bands, used):
    floors, fractions = (1.0, 2.0, 3.0), (0.1, 0.2, 0.3)
    _, without = run(renderer, frame, "C4N2", covariance_floor_deg=(0.0,) * 3, covariance_range_fraction=(0.0,) * 3,
                     covariance_bands_m=bands)
    _, with_ = run(renderer, frame, "C4N2", covariance_floor_deg=floors, covariance_range_fraction=fractions,
                   covariance_bands_m=bands)
    a, b = without[-1], with_[-1]
    assert 3.0 < a.position[2] < 15.0  # the estimate's depth picks the band
    np.testing.assert_array_equal(a.position, b.position)  # the estimate does not change
    np.testing.assert_array_equal(a.quat, b.quat)
    np.testing.assert_allclose(b.covariance[:3, :3] - a.covariance[:3, :3],
                               fractions[used] ** 2 * np.outer(a.position, a.position))  # along the line of sight
    np.testing.assert_allclose(b.covariance[3:, 3:] - a.covariance[3:, 3:], np.radians(floors[used]) ** 2 * np.eye(3))
    np.testing.assert_array_equal(b.covariance[3:, :3], a.covariance[3:, :3])


def test_covariance_grows_while_the_track_coasts_and_resets_with_hypotheses(renderer, frame):
    """Each frame in a row without hypotheses adds σ = n·fraction·range per position axis and n·deg
    per rotation axis; the estimates are those of a tracker without the term."""
    off = {"covariance_coast_fraction": 0.0, "covariance_coast_deg": 0.0}
    on = {"covariance_coast_fraction": 0.02, "covariance_coast_deg": 0.5}
    trackers = [run(renderer, frame, "C4N1", frames=3, **kw)[0] for kw in (off, on)]
    for k, (n, hyps) in enumerate([(1, None), (2, None), (3, None), (0, hypotheses(7)), (1, None)]):
        a, b = (t.step(frame, 10 + k, hyps) for t in trackers)
        assert a.has_pose and b.has_pose
        np.testing.assert_array_equal(a.position, b.position)
        np.testing.assert_array_equal(a.quat, b.quat)
        s_pos, s_rot = n * 0.02 * np.linalg.norm(a.position), n * np.radians(0.5)
        np.testing.assert_allclose(b.covariance - a.covariance, np.diag([s_pos**2] * 3 + [s_rot**2] * 3), atol=1e-15)
    np.testing.assert_allclose(coasting_covariance(np.array([3.0, 0.0, 4.0]), 2, 0.1, 0.25),
                               np.diag([1.0] * 3 + [0.25] * 3))
    with pytest.raises(ValueError):
        TrackerConfig(covariance_coast_deg=-1.0)


def test_depth_bands():
    bands = (15.0, 60.0)
    depths = [0.5, 14.9, 15.0, 15.1, 60.0, 60.1, 500.0]
    assert [depth_band(z, bands) for z in depths] == [0, 0, 0, 1, 1, 2, 2]
    assert depth_band(80.0, ()) == 0  # one band for every depth
    TrackerConfig(covariance_floor_deg=(1.0,), covariance_range_fraction=(0.05,), covariance_bands_m=())
    for bad in ({"covariance_range_fraction": (0.1, 0.05)},  # one too few for two bounds
                {"covariance_floor_deg": (1.0, 2.0, 3.0, 4.0)},
                {"covariance_range_fraction": (0.1,), "covariance_floor_deg": (1.0,), "covariance_bands_m": (15.0,)},
                {"covariance_bands_m": (60.0, 15.0)}, {"covariance_bands_m": (0.0, 15.0)},
                {"covariance_range_fraction": (0.1, -0.01, 0.1)}, {"covariance_floor_deg": (1.0, -1.0, 1.0)}):
        with pytest.raises(ValueError):
            TrackerConfig(**bad)


def _updated_bank(kind: str):
    """Five filters of ``kind`` a little off the truth, predicted and updated once; and a
    rotation 11.5° from where they started, to recentre them on."""
    bank = MotionBank(MotionFilterConfig(rotation_filter=kind))
    rng = np.random.default_rng(0)
    q0 = rotate_body(np.tile(TRUE_QUAT, (5, 1)), rng.normal(size=(5, 3)) * 0.1)
    bank.init(np.tile(TRUE_POS, (5, 1)), q0)
    bank.predict()
    bank.update(TRUE_POS, TRUE_QUAT)
    return bank, quat_multiply(q0, np.array([0.0, np.sin(0.1), 0.0, np.cos(0.1)])), rng


@pytest.mark.parametrize("kind", ["ukf", "ubif", "ubigaf"])
def test_recentred_filters_estimate_the_given_poses(kind):
    bank, target_q, rng = _updated_bank(kind)
    unmoved = copy.deepcopy(bank)
    target_p = TRUE_POS + rng.normal(size=(5, 3))
    bank.recentre(target_p, target_q)
    pos, _, quat, _ = bank.estimates()
    np.testing.assert_allclose(pos, target_p, atol=1e-12)
    assert np.degrees(geodesic_angle(quat, target_q)).max() < 1e-6
    # The spread turns with the mode: the recentred filters move as the others would have, from
    # the new pose (a filter that kept its old spread, or its old attitude-ω correlation, is
    # pulled back towards the attitude it left).
    moved = copy.deepcopy(unmoved)
    moved.predict()
    turn = quat_multiply(quat_conjugate(unmoved.estimates()[2]), moved.estimates()[2])
    bank.predict()
    assert np.degrees(geodesic_angle(bank.estimates()[2], quat_multiply(target_q, turn))).max() < 0.5


@pytest.mark.parametrize("kind", ["ukf", "ubif", "ubigaf"])
def test_recentring_on_q_or_minus_q_is_the_same(kind):
    """-q is the same rotation as q. The UBiGaF turned its attitude-ω correlation into the
    hemisphere of the quaternion given but kept the canonical one as its mode, so with w < 0 the
    correlation's sign flipped (the next prediction's attitude variance 0.0113 against 0.0130)."""
    covariances = []
    for sign in (1.0, -1.0):
        bank, target_q, _ = _updated_bank(kind)
        bank.recentre(np.tile(TRUE_POS, (5, 1)), sign * target_q)
        bank.predict()
        covariances.append(bank.rotation.covariance(bank.rot_state))
    np.testing.assert_allclose(covariances[0], covariances[1], atol=1e-12)


def test_variant_parsing_and_configuration():
    assert parse_variant("c4n2") == ("C4", 2) and parse_variant("C5N10") == ("C5", 10)
    for bad in ("C6N0", "C4", "C4N-1", "X4N2", "", "C4N2x"):
        with pytest.raises(ValueError, match="CxNy"):
            parse_variant(bad)
    assert TrackerConfig(variant="C3").motion.rotation_filter == "ukf"
    assert TrackerConfig(variant="C5").motion.rotation_filter == "ubigaf"
    assert TrackerConfig.from_variant("C4N2").name == "C4N2"
    for bad in ({"particles": 1}, {"boosted": 0}, {"metric": "sift"}, {"optimiser": "adam"}, {"variant": "C7"},
                {"depth_prior_sigma": -0.1}, {"depth_prior_floor": 0.0}, {"depth_prior_max_m": 0.0},
                {"depth_prior_gate": -0.1}, {"estimate": "median"},
                {"rotation_prior_sigma_deg": -1.0}, {"rotation_prior_floor": 0.0}, {"rotation_prior_max_m": 0.0}):
        with pytest.raises(ValueError):
            TrackerConfig(**bad)
    with pytest.raises(ValueError, match="seed must be a non-negative integer, got -1"):
        TrackerConfig(seed=-1)
    with pytest.raises(ValueError, match="M = 5, boosted = 25"):  # fewer particles than boosted
        TrackerConfig(particles=5)


def test_shipped_tracker_yaml_is_the_default(tmp_path):
    assert load_tracker_config() == TrackerConfig()
    bad = tmp_path / "tracker.yaml"
    bad.write_text("tracker:\n  ros__parameters:\n    particels: 100\n")
    with pytest.raises(ConfigError, match="particels"):
        load_tracker_config(bad)


def test_depth_prior_shape():
    from uav_landing_vision.tracking.upf import depth_prior

    z = np.array([10.0, 10.5, 11.0, 20.0])
    p = depth_prior(z, 10.0, 0.05, 0.25)
    assert p[0] == 1.0 and 1.0 > p[1] > p[2] > p[3] >= 0.25
    np.testing.assert_allclose(p[1], 0.25 + 0.75 * np.exp(-0.5))
    np.testing.assert_allclose(p[3], 0.25)


def test_depth_prior_pulls_depth_to_the_boosted_depth_and_reports_the_likelihood(renderer, frame):
    """Boosted depths 8 % too far: the prior moves the estimate towards them; best_likelihood
    stays the likelihood alone; beyond depth_prior_max_m the tracker is the thesis's."""
    far = Hyps(hypotheses(5).quats, hypotheses(5).positions * np.array([1.0, 1.0, 1.08]))
    anchor = np.median(far.positions[:40, 2])

    def last(**overrides):
        # the thesis's absolute PFO noise, large at 6 m: the estimate moves off the hypotheses' depth
        cfg = TrackerConfig.from_variant("C4N2", particles=40, boosted=10, pfo=PFOConfig(), **overrides)
        tracker = Tracker(cfg, CAMERA, renderer)
        return tracker, [tracker.step(frame, k, far) for k in range(3)][-1]

    _, plain = last(depth_prior_sigma=0.0)
    tracker, pulled = last(depth_prior_sigma=0.02, depth_prior_floor=0.05)
    assert abs(pulled.position[2] - anchor) < abs(plain.position[2] - anchor)
    alone = tracker.likelihood.score(pulled.particles.quat[:1], pulled.particles.pos[:1])[0]
    np.testing.assert_allclose(pulled.best_likelihood, alone)
    _, gated = last(depth_prior_sigma=0.02, depth_prior_floor=0.05, depth_prior_max_m=6.0)
    np.testing.assert_array_equal(gated.position, plain.position)


def test_depth_prior_gate_drops_a_boosted_depth_that_jumps_off_the_track(renderer, frame):
    """With ``depth_prior_gate``, a boosted depth more than that fraction off the last best particle's
    depth sets no prior (scores are the likelihood alone); one within it does. Without a track
    (first frame) the gate does not apply."""
    cfg = TrackerConfig.from_variant("C4N2", particles=40, boosted=10, depth_prior_gate=0.25,
                                     rotation_prior_sigma_deg=0.0)
    tracker = Tracker(cfg, CAMERA, renderer)
    tracker.step(frame, 0, hypotheses(5))
    assert tracker._anchor == pytest.approx(np.median(hypotheses(5).positions[:40, 2]))
    last = tracker.particles.pos[0, 2]
    near = hypotheses(6)
    near.positions = near.positions * np.array([1.0, 1.0, 0.7 * last / TRUE_POS[2]])  # 30 % nearer
    tracker.step(frame, 1, near)
    assert tracker._anchor is None
    np.testing.assert_array_equal(tracker._prior(ParticleSet.from_poses([[0, 0, 4.0], [0, 0, 6.0]], [TRUE_QUAT] * 2)), 1.0)
    close = hypotheses(7)
    close.positions = close.positions * np.array([1.0, 1.0, 0.9])  # 10 % nearer: within the gate
    tracker.step(frame, 2, close)
    assert tracker._anchor == pytest.approx(np.median(close.positions[:10, 2]))  # the 10 boosted of a track


def test_rotation_prior_against_scipy_angles():
    from scipy.spatial.transform import Rotation

    from uav_landing_vision.tracking.upf import rotation_prior

    rng = np.random.default_rng(3)
    anchor = Rotation.random(random_state=4)
    turns = Rotation.from_rotvec(rng.normal(size=(50, 3)) * 0.3)
    quats = (turns * anchor).as_quat()
    quats[::2] *= -1  # q and -q are one rotation
    sigma, floor = np.radians(8.0), 0.3
    angle = (turns * anchor * anchor.inv()).magnitude()
    expected = floor + (1 - floor) * np.exp(-0.5 * (angle / sigma) ** 2)
    np.testing.assert_allclose(rotation_prior(quats, anchor.as_quat(), sigma, floor), expected, atol=1e-9)
    assert rotation_prior(anchor.as_quat()[None], anchor.as_quat(), sigma, floor)[0] == pytest.approx(1.0)


def test_rotation_prior_anchors_on_the_last_refined_rotation_near_the_ship(renderer, frame):
    """Within ``rotation_prior_max_m`` every score is multiplied by the rotation prior about the
    last refined rotation (the published one before the window); best_likelihood stays the likelihood alone; beyond it, or with
    σ = 0, the tracker is as without it."""
    cfg = TrackerConfig.from_variant("C4N2", particles=40, boosted=10, rotation_prior_sigma_deg=5.0,
                                     rotation_prior_floor=0.2, depth_prior_sigma=0.0)
    tracker = Tracker(cfg, CAMERA, renderer)
    first = tracker.step(frame, 0, hypotheses(5))
    np.testing.assert_array_equal(tracker._turn_anchor, first.quat)
    turned = rotate_body(np.tile(first.quat, (2, 1)), np.array([[0.0, 0.0, 0.0], [np.radians(5.0), 0.0, 0.0]]))
    prior = tracker._prior(ParticleSet.from_poses(np.tile(first.position, (2, 1)), turned))
    np.testing.assert_allclose(prior, [1.0, 0.2 + 0.8 * np.exp(-0.5)], rtol=1e-6)
    second = tracker.step(frame, 1, hypotheses(6))
    alone = tracker.likelihood.score(second.particles.quat[:1], second.particles.pos[:1])[0]
    np.testing.assert_allclose(second.best_likelihood, alone)
    _, off = run(renderer, frame, "C4N2", rotation_prior_sigma_deg=0.0)
    _, far = run(renderer, frame, "C4N2", rotation_prior_sigma_deg=5.0, rotation_prior_max_m=5.0)
    for a, b in zip(off, far):
        np.testing.assert_array_equal(a.position, b.position)
        np.testing.assert_array_equal(a.quat, b.quat)
    tracker.reset()
    assert tracker._turn_anchor is None


def test_rotation_prior_anchor_is_held_while_the_track_coasts(renderer, frame):
    """With ``rotation_prior_hold`` frames without hypotheses keep the anchor of the last frame with
    them, and the next frame with hypotheses moves it again; without the hold it follows every frame."""
    def anchors(hold):
        cfg = TrackerConfig.from_variant("C4N2", particles=40, boosted=10, rotation_prior_hold=hold)
        tracker = Tracker(cfg, CAMERA, renderer)
        out = []
        for k, hyps in enumerate([hypotheses(5), None, None, hypotheses(6)]):
            tracker.step(frame, k, hyps)
            out.append(tracker._turn_anchor.copy())
        return out

    held, followed = anchors(True), anchors(False)
    np.testing.assert_array_equal(held[0], followed[0])
    np.testing.assert_array_equal(held[1], held[0])
    np.testing.assert_array_equal(held[2], held[0])
    assert not np.array_equal(held[3], held[0])
    assert not np.array_equal(followed[1], followed[0]) and not np.array_equal(followed[2], followed[1])


def test_rotation_refinement_changes_only_the_published_rotation(renderer, frame):
    """The refinement turns the published rotation to one that scores at least as well as the best
    particle's, at the same position; the particles, and so every later frame, stay as without it
    (without the rotation prior, whose anchor is the refined rotation, and without the window)."""
    off = RotationRefinementConfig()
    on = RotationRefinementConfig(candidates=32, sigma_deg=(3.0, 1.0))
    _, a = run(renderer, frame, "C4N2", rotation_prior_sigma_deg=0.0, refine=off, estimate="best", rotation_window=1)
    b_tracker, b = run(renderer, frame, "C4N2", rotation_prior_sigma_deg=0.0, refine=on, estimate="best",
                       rotation_window=1)
    for ra, rb in zip(a, b):
        np.testing.assert_array_equal(ra.position, rb.position)
        np.testing.assert_array_equal(ra.particles.pos, rb.particles.pos)
        np.testing.assert_array_equal(ra.particles.quat, rb.particles.quat)
        np.testing.assert_array_equal(ra.quat, ra.particles.quat[0])
        scores = b_tracker._score(ParticleSet.from_poses(np.tile(rb.position, (2, 1)), np.stack([rb.quat, ra.quat])))
        assert scores[0] >= scores[1]
    assert any(not np.array_equal(ra.quat, rb.quat) for ra, rb in zip(a, b))
    assert b[-1].stage_ms["refinement"] > 0.0


def test_aligned_refinement_compares_rotations_at_their_best_image_shift(renderer, frame):
    """With ``refine.align_px`` the refinement's objective is each pose's score at the best of its
    image shifts: never below the plain score, equal to it without alignment. Only the published
    rotation changes; positions and particles stay as without the refinement (no rotation prior)."""
    off = RotationRefinementConfig()
    aligned = RotationRefinementConfig(candidates=32, sigma_deg=(3.0, 1.0), align_px=0.5)
    _, a = run(renderer, frame, "C4N2", rotation_prior_sigma_deg=0.0, refine=off, rotation_window=1)
    tracker, b = run(renderer, frame, "C4N2", rotation_prior_sigma_deg=0.0, refine=aligned, rotation_window=1)
    plain, _ = run(renderer, frame, "C4N2", rotation_prior_sigma_deg=0.0, refine=replace(aligned, align_px=0.0))
    for ra, rb in zip(a, b):
        np.testing.assert_array_equal(ra.position, rb.position)
        np.testing.assert_array_equal(ra.particles.pos, rb.particles.pos)
        np.testing.assert_array_equal(ra.particles.quat, rb.particles.quat)
        both = ParticleSet.from_poses(np.tile(rb.position, (2, 1)), np.stack([rb.quat, ra.quat]))
        assert tracker._refinement_score(both)[0] >= tracker._refinement_score(both)[1]
    poses = b[-1].particles
    assert np.all(tracker._refinement_score(poses) >= tracker._score(poses))
    assert np.any(tracker._refinement_score(poses) > tracker._score(poses))
    np.testing.assert_array_equal(plain._refinement_score(poses), plain._score(poses))


def test_mean_estimate_publishes_the_weighted_mean_and_leaves_the_particles_alone(renderer, frame):
    """``estimate: mean`` publishes the particles' weighted mean pose (rotation refined at the mean
    position); the particles are those of the thesis's best-particle output, frame after frame
    (without the rotation prior, which anchors on the refined rotation, and without the window)."""
    off = RotationRefinementConfig()
    _, best = run(renderer, frame, "C4N2", rotation_prior_sigma_deg=0.0, refine=off, estimate="best", rotation_window=1)
    _, mean = run(renderer, frame, "C4N2", rotation_prior_sigma_deg=0.0, refine=off, estimate="mean", rotation_window=1)
    tracker, refined = run(renderer, frame, "C4N2", rotation_prior_sigma_deg=0.0, refine=RotationRefinementConfig(candidates=32),
                           estimate="mean", rotation_window=1)
    for rb, rm, rr in zip(best, mean, refined):
        np.testing.assert_array_equal(rb.particles.pos, rm.particles.pos)
        np.testing.assert_array_equal(rb.particles.quat, rm.particles.quat)
        np.testing.assert_array_equal(rb.position, rb.particles.pos[0])
        w = rm.particles.weight / rm.particles.weight.sum()
        np.testing.assert_allclose(rm.position, w @ rm.particles.pos, rtol=1e-12)
        np.testing.assert_allclose(rm.quat, rm.particles.mean_pose()[1], rtol=1e-12)
        np.testing.assert_array_equal(rr.position, rm.position)  # the refinement keeps the position
        scores = tracker._score(ParticleSet.from_poses(np.tile(rm.position, (2, 1)), np.stack([rr.quat, rm.quat])))
        assert scores[0] >= scores[1]
    assert any(not np.array_equal(rb.position, rm.position) for rb, rm in zip(best, mean))
    assert np.linalg.norm(mean[-1].position - TRUE_POS) < 0.5
    assert np.degrees(geodesic_angle(mean[-1].quat, TRUE_QUAT)) < 12.0


def test_rotation_window_averages_the_published_rotation_and_nothing_else(renderer, frame):
    """``rotation_window: 2`` publishes the mean of this and the last frame's rotations (scipy's
    mean as the oracle); positions, particles and the rotation prior's anchor are those of the
    tracker without the window; a reset empties it."""
    _, plain = run(renderer, frame, "C4N2", rotation_window=1)
    tracker, windowed = run(renderer, frame, "C4N2", rotation_window=2)
    np.testing.assert_array_equal(windowed[0].quat, plain[0].quat)
    for k in range(1, len(plain)):
        np.testing.assert_array_equal(windowed[k].position, plain[k].position)
        np.testing.assert_array_equal(windowed[k].particles.quat, plain[k].particles.quat)
        expected = Rotation.from_quat([plain[k - 1].quat, plain[k].quat]).mean().as_quat()
        assert np.degrees(geodesic_angle(windowed[k].quat, expected)) < 1e-6
    np.testing.assert_array_equal(tracker._turn_anchor, plain[-1].quat)
    tracker.reset()
    assert len(tracker.window._recent) == 0
    with pytest.raises(ValueError, match="rotation_window"):
        TrackerConfig(rotation_window=0)


@pytest.mark.parametrize("kwargs", [{"acquire_likelihood": 0.2, "lost_likelihood": 0.2},
                                    {"acquire_frames": 0}, {"lost_frames": 0}])
def test_track_state_config_refuses(kwargs):
    """acquire_frames 0 would vouch for the first frame whatever it scores;
    lost_frames 0 would drop every track at its first frame."""
    with pytest.raises(ValueError):
        TrackStateConfig(**kwargs)


def test_lost_is_left_only_by_initialisation():
    """Scores alone never take a LOST monitor to ACQUIRING or TRACKING."""
    m = TrackMonitor(TrackStateConfig(acquire_likelihood=0.5, acquire_frames=2, lost_likelihood=0.1, lost_frames=3))
    assert [m.update(0.9) for _ in range(4)] == [TrackState.LOST] * 4
    assert m.update(0.05) == TrackState.LOST
    m.initialised()
    assert m.update(0.9) == TrackState.ACQUIRING


def small_tracker(renderer, variant="C4N0", **overrides) -> Tracker:
    """M = 40 particles, 10 boosted."""
    return Tracker(TrackerConfig.from_variant(variant, particles=40, boosted=10, **overrides), CAMERA, renderer)


@pytest.mark.parametrize("variant", ["C2N0", "C4N0"])
def test_a_frame_without_hypotheses_carries_all_m_particles(renderer, frame, variant):
    """Alg. 3 step 4 mixes M − M0 boosted poses with the best M0 carried ones; with no boosted
    poses the whole set of M is carried (predicted), none left out for absent hypotheses."""
    t = small_tracker(renderer, variant)
    for k in range(2):
        t.step(frame, k * DT_NS, hypotheses(10 + k))
    result = t.step(frame, 2 * DT_NS, None)
    assert result.has_pose and len(result.particles) == 40


@pytest.mark.parametrize("variant", ["C3N0", "C4N0", "C5N0"])
def test_the_weights_resampled_on_are_the_scores_of_the_filtered_poses(renderer, frame, variant):
    """§5.4.1 after §5.2.3: the carried particles are scored where their filters put them after the
    z_t update, so every published particle's weight is the objective at its own pose (no
    optimisation here, N = 0; the rotation prior, whose anchor moves at the end of a frame, off)."""
    t = small_tracker(renderer, variant, rotation_prior_sigma_deg=0.0)
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
    t = small_tracker(renderer, variant)
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
    t = small_tracker(renderer, "C4N2")
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
    t = small_tracker(renderer, "C4N2", refine=refine, rotation_window=1, rotation_prior_sigma_deg=0.0, estimate="mean")
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
        t = small_tracker(renderer, "C4N1", rotation_window=window)
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
        t = small_tracker(renderer, "C4N1", **overrides)
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


def test_tracker_config_bounds_as_documented():
    """Tile at most MAX_TILE, covariance terms within their bounds, strictly increasing depth bands,
    a depth prior floor in (0, 1]; a depth gate of 0 is allowed (it turns the gate off)."""
    from uav_landing_vision.render.renderer import MAX_TILE

    TrackerConfig(tile=MAX_TILE, depth_prior_gate=0.0, depth_prior_floor=1.0, covariance_floor_m=1e3)
    for bad in ({"tile": MAX_TILE + 1}, {"covariance_floor_m": 2e3}, {"covariance_floor_deg": (10.0, 200.0, 8.0)},
                {"covariance_coast_fraction": 1.5}, {"covariance_bands_m": (15.0, 15.0)},
                {"depth_prior_floor": 1.5}, {"rotation_prior_floor": 1.5}):
        with pytest.raises(ValueError):
            TrackerConfig(**bad)


def test_render_batch_is_the_largest_draw_and_at_least_512():
    """M particles or the refinement's candidates + 1, whichever is more, and never under 512."""
    from uav_landing_vision.tracking.upf import largest_draw, render_batch

    off = RotationRefinementConfig()
    assert render_batch(TrackerConfig(particles=100, refine=off)) == 512
    assert render_batch(TrackerConfig(particles=600, boosted=25, refine=off)) == 600
    big = TrackerConfig(particles=100, refine=RotationRefinementConfig(candidates=700))
    assert largest_draw(big) == 701 and render_batch(big) == 701


def _track_at(tracker, depths):
    """Give ``tracker`` a carried set (best first) at the given depths."""
    m = len(depths)
    tracker.particles = ParticleSet.from_poses(np.column_stack([np.zeros((m, 2)), depths]), np.tile(TRUE_QUAT, (m, 1)))


def _boosted_at(depth, count=10):
    return ParticleSet.from_poses(np.tile([0.0, 0.0, depth], (count, 1)), np.tile(TRUE_QUAT, (count, 1)))


def test_boosted_depth_gate_compares_with_the_best_carried_particle(renderer):
    """The gate compares z_b with the depth of the last frame's *best* particle (the set's first),
    not any other; with the gate at 0 there is no gate; a z_b on ``depth_prior_max_m`` is within it."""
    t = small_tracker(renderer, depth_prior_gate=0.25, depth_prior_max_m=30.0)
    _track_at(t, [6.0] + [12.0] * 39)
    assert t._boosted_depth(_boosted_at(6.5)) == pytest.approx(6.5)  # 8 % off the best: kept
    assert t._boosted_depth(_boosted_at(12.0)) is None  # 100 % off the best, although at the others' depth
    no_gate = small_tracker(renderer, depth_prior_gate=0.0)
    _track_at(no_gate, [6.0] * 40)
    assert no_gate._boosted_depth(_boosted_at(12.0)) == pytest.approx(12.0)
    edge = small_tracker(renderer, depth_prior_gate=0.0, depth_prior_max_m=6.5)
    assert edge._boosted_depth(_boosted_at(6.5)) == pytest.approx(6.5)
    assert edge._boosted_depth(_boosted_at(6.6)) is None


def test_priors_take_the_depth_z_and_the_rotation_in_radians(renderer):
    """The depth prior is of each particle's depth z (not its range): poses off the optical axis at
    the anchor depth score 1; the rotation prior's σ is in degrees in the configuration."""
    from uav_landing_vision.tracking.upf import depth_prior, rotation_prior

    t = small_tracker(renderer, depth_prior_sigma=0.1, depth_prior_floor=0.2, rotation_prior_sigma_deg=5.0,
                      rotation_prior_floor=0.3)
    t._anchor, t._turn_anchor = 6.0, TRUE_QUAT
    turned = rotate_body(np.tile(TRUE_QUAT, (3, 1)), np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0],
                                                               [np.radians(4.0), 0.0, 0.0]]))
    pos = np.array([[3.0, -2.0, 6.0], [0.0, 0.0, 6.6], [0.0, 0.0, 6.0]])
    prior = t._prior(ParticleSet.from_poses(pos, turned))
    expected = depth_prior(pos[:, 2], 6.0, 0.1, 0.2) * rotation_prior(turned, TRUE_QUAT, np.radians(5.0), 0.3)
    np.testing.assert_allclose(prior, expected, rtol=1e-12)
    np.testing.assert_allclose(prior, [1.0, 0.2 + 0.8 * np.exp(-0.5), 0.3 + 0.7 * np.exp(-0.5 * 0.8**2)], rtol=1e-9)


def test_rotation_prior_anchor_follows_the_estimate_depth_not_its_range(renderer):
    """Within ``rotation_prior_max_m`` of depth (z) the next anchor is the refined rotation, even
    far off the optical axis (range beyond the limit); beyond it in depth there is none."""
    t = small_tracker(renderer, rotation_prior_max_m=15.0)
    np.testing.assert_array_equal(t._next_turn_anchor(np.array([20.0, 0.0, 10.0]), TRUE_QUAT), TRUE_QUAT)
    assert t._next_turn_anchor(np.array([0.0, 0.0, 16.0]), TRUE_QUAT) is None


def test_measurement_is_the_best_scoring_pose_of_the_mix(renderer, frame, monkeypatch):
    """(5.2.3): the carried filters are updated with z_t, the pose of the mix that scores highest
    (the scores recomputed for the same mix before the step goes on). Poor hypotheses first, then
    close ones: the best pose of the mix is a new one, not the first carried particle."""
    t = small_tracker(renderer, "C4N0")
    t.step(frame, 0, hypotheses(70, trans_sigma=0.3, rot_sigma_deg=15.0))
    seen, updates = [], []
    inner_filter, inner_update = t._filter, t.filters.update

    def spy_filter(mixed, clock):
        seen.append((mixed, t._score(mixed)))
        return inner_filter(mixed, clock)

    def spy_update(z_pos, z_quat):
        updates.append((np.array(z_pos), np.array(z_quat)))
        return inner_update(z_pos, z_quat)

    monkeypatch.setattr(t, "_filter", spy_filter)
    monkeypatch.setattr(t.filters, "update", spy_update)
    t.step(frame, DT_NS, hypotheses(71, trans_sigma=0.01, rot_sigma_deg=0.5))
    (mixed, scores), = seen
    assert len(updates) == 1 and np.argmax(scores) != 0
    np.testing.assert_array_equal(updates[0][0], mixed.pos[np.argmax(scores)])
    np.testing.assert_array_equal(updates[0][1], mixed.quat[np.argmax(scores)])


def test_weighting_scores_only_the_poses_the_measurement_did_not(renderer, frame, monkeypatch):
    """One batched score of the mix picks z_t; the weighting then scores only the carried particles
    the filters moved (M0 = 30), the new boosted ones keep their scores (§5.4.1)."""
    t = small_tracker(renderer, "C4N0")
    t.step(frame, 0, hypotheses(72))
    batches, inner = [], t._score

    def spy(particles):
        batches.append(len(particles))
        return inner(particles)

    monkeypatch.setattr(t, "_score", spy)
    t.step(frame, DT_NS, hypotheses(73))
    assert batches[:2] == [40, 30]


def test_weighting_resamples_with_the_configured_scheme(renderer, frame, monkeypatch):
    """Step 3 resamples with ``TrackerConfig.resampling`` once per frame (N = 0: no PFO resampling)."""
    from uav_landing_vision.tracking import upf

    names, inner = [], upf.resample

    def spy(name, weights, rng, **options):
        names.append(name)
        return inner(name, weights, rng, **options)

    monkeypatch.setattr(upf, "resample", spy)
    t = small_tracker(renderer, "C4N0", resampling="multinomial")
    for k in range(2):
        t.step(frame, k * DT_NS, hypotheses(74 + k))
    assert names == ["multinomial", "multinomial"]


def test_empty_hypotheses_are_a_frame_without_hypotheses(renderer, frame):
    """Boosting that found nothing (zero poses) is as no hypotheses at all: the track coasts."""
    empty = Hyps(np.zeros((0, 4)), np.zeros((0, 3)))
    results = []
    for hyps in (None, empty):
        t = small_tracker(renderer, "C4N1")
        for k in range(2):
            t.step(frame, k * DT_NS, hypotheses(76 + k))
        results.append(t.step(frame, 2 * DT_NS, hyps))
        assert t._coasting == 1
    np.testing.assert_array_equal(results[0].position, results[1].position)
    np.testing.assert_array_equal(results[0].covariance, results[1].covariance)


def test_reset_forgets_the_last_picture_so_a_new_time_line_starts_without_a_repeat(renderer, frame):
    """With ``acquire_frames`` 1 and ``max_repeated_frames`` 1 a good frame is TRACKING unless it
    repeats the one before; after reset() the last picture before it is no repeat."""
    track = TrackStateConfig(acquire_likelihood=0.1, acquire_frames=1, lost_likelihood=0.01, max_repeated_frames=1)
    t = small_tracker(renderer, track=track)
    pictures = [shot(frame, k) for k in range(2)]
    assert [t.step(p, k * DT_NS, hypotheses(80 + k)).state for k, p in enumerate(pictures)] == [TrackState.TRACKING] * 2
    assert t.step(pictures[1], 2 * DT_NS, hypotheses(82)).state == TrackState.ACQUIRING  # a repeat
    t.reset()
    assert t.step(pictures[1], 0, hypotheses(83)).state == TrackState.TRACKING


def test_published_particles_name_their_recentred_filters_by_slot(renderer, frame):
    """C3–C5: after the output step each published particle's ``slot`` names the filter recentred on
    its pose (the filters reordered with the particles)."""
    t = small_tracker(renderer, "C4N1")
    for k in range(2):
        result = t.step(frame, k * DT_NS, hypotheses(84 + k))
        pos, _, quat, _ = t.filters.estimates()
        slot = result.particles.state["slot"]
        np.testing.assert_allclose(pos[slot], result.particles.pos, rtol=0, atol=1e-9)
        assert np.degrees(geodesic_angle(quat[slot], result.particles.quat)).max() < 1e-6


def test_a_lost_likelihood_of_zero_is_allowed_and_never_counts_a_frame_as_bad():
    """``0 <= lost_likelihood``: at 0 no score in [0, 1] lies below it, so scores alone never
    demote or lose the track; a negative threshold is refused."""
    m = TrackMonitor(TrackStateConfig(acquire_likelihood=0.5, acquire_frames=1, lost_likelihood=0.0, lost_frames=1))
    m.initialised()
    assert [m.update(v) for v in (0.9, 0.0, 0.0, 0.0)] == [TrackState.TRACKING] * 4
    with pytest.raises(ValueError, match="lost_likelihood"):
        TrackStateConfig(lost_likelihood=-0.01)
