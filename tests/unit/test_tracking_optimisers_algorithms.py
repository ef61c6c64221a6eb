"""Pose optimisers of §5.5 (tracking/optimisation.py): PSO against a plain-numpy Algorithm 9,
GAbF's phase/restart bookkeeping (Algorithm 10) observed through the poses it scores, and the
noise laws of PFO and GAbF."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision.geometry import quat_to_euler_zyx
from uav_landing_vision.tracking import PFO, PSO, ConstrictedPSO, ConstrictedPSOConfig, GAbF, GAbFConfig, ParticleSet
from uav_landing_vision.tracking import PFOConfig, PSOConfig
from uav_landing_vision.tracking import optimisation as opt

IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])
T_STAR = np.array([0.3, -0.2, 5.0])


class Recording:
    """An objective that records the positions and quaternions of every batch it scores."""

    def __init__(self, score):
        self.score, self.pos, self.quat, self.out = score, [], [], []

    def __call__(self, particles):
        self.pos.append(particles.pos.copy())
        self.quat.append(particles.quat.copy())
        self.out.append(np.asarray(self.score(particles), float))
        return self.out[-1]


def position_score(particles) -> np.ndarray:
    return np.exp(-np.sum((particles.pos - T_STAR) ** 2, axis=1) / 0.5**2)


def reference_swarm(pos0, score, rng, iterations, k, constricted, inertia=0.7298, c1=1.49618, c2=1.49618,
                    gamma=1.0):
    """Algorithm 9 / (5.21) in R³ for swarms whose rotations all stay the identity (so (5.19) is
    the Euclidean distance): personal bests, the best personal best among the k nearest (the
    particle included), and the velocity law, with the random factors drawn in the optimiser's
    order. Returns the positions scored at each iteration."""
    m = len(pos0)
    current, velocity = pos0.copy(), np.zeros((m, 6))
    best_pos, best_w, scored = None, None, []
    for _ in range(iterations):
        scored.append(current.copy())
        w = score(current)
        if best_pos is None:
            best_pos, best_w = current.copy(), w.copy()
        else:
            better = w > best_w
            best_pos[better], best_w[better] = current[better], w[better]
        dist = np.linalg.norm(current[:, None] - current[None], axis=2)
        neigh = np.empty(m, int)
        for i in range(m):
            near = np.argsort(dist[i], kind="stable")[:k]
            neigh[i] = near[np.argmax(best_w[near])]
        to_best = np.hstack([best_pos - current, np.zeros((m, 3))])
        to_neigh = np.hstack([best_pos[neigh] - current, np.zeros((m, 3))])
        if constricted:
            gauss = np.minimum(np.abs(rng.normal(size=(2, m, 6))), 1.0)
            uniform = rng.random((2, m, 6))
            same = np.all(np.sign(to_best) == np.sign(to_neigh), axis=1)[:, None]
            r1, r2 = np.where(same, gauss, uniform)
            velocity = gamma * (velocity + c1 * r1 * to_best + c2 * r2 * to_neigh)
        else:
            r1, r2 = rng.random((m, 6)), rng.random((m, 6))
            velocity = inertia * velocity + c1 * r1 * to_best + c2 * r2 * to_neigh
        current = current + velocity[:, :3]
    return scored


@pytest.mark.parametrize("constricted", [False, True])
def test_pso_moves_every_particle_by_algorithm_9_with_the_nearest_neighbours_best(constricted):
    """Personal best, the neighbourhood's best personal best (5.19) and the velocity law (Alg. 9,
    (5.21)–(5.22)): the positions the swarm scores agree with a plain numpy swarm step for step."""
    m, k, iterations = 30, 5, 6
    rng = np.random.default_rng(7)
    pos0 = T_STAR + rng.normal(size=(m, 3)) * 0.8
    start = ParticleSet.from_poses(pos0, np.tile(IDENTITY, (m, 1)))

    def score(pos):
        return np.exp(-np.sum((pos - T_STAR) ** 2, axis=1) / 0.5**2)

    if constricted:
        cfg = ConstrictedPSOConfig(neighbours=k)
        swarm, extra = ConstrictedPSO(cfg), {"c1": cfg.c1, "c2": cfg.c2, "gamma": cfg.gamma}
    else:
        swarm, extra = PSO(PSOConfig(neighbours=k)), {}
    record = Recording(lambda p: score(p.pos))
    result = swarm.run(start, record, np.random.default_rng(11), iterations)
    expected = reference_swarm(pos0, score, np.random.default_rng(11), iterations, k, constricted, **extra)
    assert len(record.pos) == iterations
    for got, want in zip(record.pos, expected):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    best_score = np.max([score(p) for p in expected], axis=0)  # each particle's best over the iterations
    np.testing.assert_allclose(result.weight, best_score, rtol=1e-12)


def test_pfo_translation_noise_scales_with_depth_not_range():
    """``reference_depth_m``: σ × depth / reference, the depth being z — a particle 30 m to the
    side at 10 m depth moves as one straight ahead at 10 m (range 31.6 m)."""
    m = 4000
    rng = np.random.default_rng(0)
    quat = Rotation.random(m, random_state=1).as_quat()
    p = ParticleSet.from_poses(np.tile([30.0, 0.0, 10.0], (m, 1)) + rng.normal(size=(m, 3)) * 1e-3, quat)
    cfg = PFOConfig(schedule="noise", resampling="minimum_sampling", reference_depth_m=10.0)
    moved = PFO(cfg).run(p, lambda s: np.ones(len(s)), np.random.default_rng(2), 1)
    np.testing.assert_allclose(np.std(moved.pos - p.pos, axis=0), [0.1, 0.1, 0.2], rtol=0.06)


def test_gabf_bootstrap_noise_has_its_configured_sigmas_in_metres_and_degrees():
    """Σ_bootstrap: 1 mm on translation, 10° on each body axis (not 1 mm read as radians)."""
    m = 4000
    quat = Rotation.random(random_state=3).as_quat()
    pop = ParticleSet.from_poses(np.tile([0.0, 0.0, 8.0], (m, 1)), np.tile(quat, (m, 1)), np.full(m, 0.15))
    cfg = GAbFConfig(bootstrap_sigma_m=(0.001, 0.002, 0.003), bootstrap_sigma_deg=(10.0, 5.0, 2.0))
    moved = GAbF(cfg)._move(pop, pop.take([0, 1, 2]), "bootstrap", 1, np.random.default_rng(4))
    np.testing.assert_allclose(np.std(moved.pos - pop.pos, axis=0), [0.001, 0.002, 0.003], rtol=0.06)
    turns = opt.rotvec_between(pop.quat, moved.quat)
    np.testing.assert_allclose(np.degrees(np.std(turns, axis=0)), [10.0, 5.0, 2.0], rtol=0.06)


def test_gabf_bootstrap_replacements_come_from_every_member_of_top_a():
    """A particle under δ becomes a *random* Top A member plus Σ_init noise: with three members
    10 m apart, each takes about a third of the replacements."""
    m = 600
    top = ParticleSet.from_poses([[0.0, 0.0, 20.0], [10.0, 0.0, 20.0], [20.0, 0.0, 20.0]], np.tile(IDENTITY, (3, 1)))
    pop = ParticleSet.from_poses(np.tile([5.0, 5.0, 20.0], (m, 1)), np.tile(IDENTITY, (m, 1)), np.zeros(m))
    moved = GAbF()._move(pop, top, "bootstrap", 0, np.random.default_rng(5))
    nearest = np.argmin(np.abs(moved.pos[:, :1] - top.pos[:, 0][None]), axis=1)
    assert np.all(np.abs(moved.pos[:, 0] - top.pos[nearest, 0]) < 1.0)
    counts = np.bincount(nearest, minlength=3)
    assert np.all(np.abs(counts - m / 3) < 5 * np.sqrt(m * (1 / 3) * (2 / 3))), counts


def flat_start(m=20, seed=0) -> ParticleSet:
    rng = np.random.default_rng(seed)
    quat = Rotation.random(m, random_state=seed).as_quat()
    return ParticleSet.from_poses(T_STAR + rng.normal(size=(m, 3)), quat)


def test_gabf_restarts_a_bootstrap_that_overstays_its_limit_at_most_max_restarts_times():
    """Every score between δ and T_min: the bootstrap never ends. Its first step (and the first
    after each restart) moves nothing (no particle under δ); the others jitter every particle.
    With ``bootstrap_steps`` 2 (``coarse_steps`` 50) and three restarts the population stays put
    across iterations 1→2, 3→4, 5→6 and 7→8 only."""
    cfg = GAbFConfig(bootstrap_steps=2, coarse_steps=50, max_restarts=3)
    record = Recording(lambda p: np.full(len(p), 0.15))
    GAbF(cfg).run(flat_start(), record, np.random.default_rng(0), 12)
    assert len(record.pos) == 12
    still = [k for k in range(11) if np.array_equal(record.pos[k], record.pos[k + 1])]
    assert still == [0, 2, 4, 6]


def crossover_children(pos: np.ndarray, a: np.ndarray, b: np.ndarray) -> int:
    """How many rows of ``pos`` take each coordinate exactly from ``a`` or ``b``."""
    return int(np.sum(np.all((pos == a) | (pos == b), axis=1)))


def test_gabf_restart_rebuilds_top_a_from_the_current_population():
    """Two poses score 0.25 (above T_min) at the first evaluation only, then everything 0.15: the
    coarse phase overstays (``coarse_steps`` 2) and restarts the bootstrap with Top A taken from
    the current population, which is under T_min; so no later move is a crossover of those two
    poses (a Top A that kept them would send the run straight back to the coarse phase)."""
    start = flat_start()
    high = [3, 11]

    def score(p):
        w = np.full(len(p), 0.15)
        if len(record.pos) == 1:  # the first evaluation (recorded before it is scored)
            w[high] = 0.25
        return w

    record = Recording(score)
    cfg = GAbFConfig(coarse_steps=2, bootstrap_steps=3, max_restarts=1)
    GAbF(cfg).run(start, record, np.random.default_rng(1), 10)
    a, b = start.pos[high[0]], start.pos[high[1]]
    assert crossover_children(record.pos[1], a, b) >= 5  # the coarse phase's crossovers
    assert [crossover_children(p, a, b) for p in record.pos[4:]] == [0] * (len(record.pos) - 4)


def test_gabf_top_a_keeps_the_best_poses_ever_scored_so_the_fine_phase_runs_its_course():
    """Two poses score 0.35 (above T_coarse) at the first evaluation, then nothing does: Top A
    holds the best ever scored, so the fine phase is not left and ends after its five moves."""
    start = flat_start()

    def score(p):
        w = np.full(len(p), 0.15)
        if len(record.pos) == 1:  # the first evaluation
            w[[2, 5]] = 0.35
        return w

    record = Recording(score)
    GAbF().run(start, record, np.random.default_rng(2), 30)
    assert len(record.pos) == 1 + GAbFConfig().fine_steps


def test_gabf_result_is_the_best_of_the_last_population_then_the_best_distinct_poses_ever_scored():
    """The result: the last population's best M − A, best first, then the A best *distinct* poses
    scored. An input of one pose resampled 18 times and two others once keeps all three."""
    rng = np.random.default_rng(3)
    quat = Rotation.random(3, random_state=3).as_quat()
    pos = T_STAR + rng.normal(size=(3, 3)) * 0.3
    idx = np.array([0] * 18 + [1, 2])
    inp = ParticleSet.from_poses(pos[idx], quat[idx])
    levels = {0: 0.9, 1: 0.8, 2: 0.7}

    def score(p):
        return np.array([max((v for i, v in levels.items() if np.array_equal(x, pos[i])), default=0.05)
                         for x in p.pos])

    refined = GAbF().run(inp, score, np.random.default_rng(4), 1)
    assert len(refined) == 20
    np.testing.assert_array_equal(refined.weight[:17], np.sort(score(inp))[::-1][:17])
    elite = {tuple(x) for x in refined.pos[17:]}
    assert elite == {tuple(x) for x in pos}


def test_gabf_result_keeps_the_best_of_the_last_population_after_moves():
    """After several moves (the budget ends the run, not the fine phase) the last population's
    best M − A come first, best first, weighted by the scores of the last evaluation: every
    returned weight is its pose's score (the run does not move the poses after scoring them)."""
    record = Recording(position_score)
    refined = GAbF().run(flat_start(seed=5), record, np.random.default_rng(5), 4)
    assert len(record.pos) == 4
    np.testing.assert_allclose(refined.weight, position_score(refined), rtol=1e-12)
    last = np.sort(record.out[-1])[::-1]
    keep = len(refined) - GAbFConfig().top_a
    np.testing.assert_array_equal(refined.weight[:keep], last[:keep])


def reference_swarm_with_rotations(pos0, quat0, score, rng, iterations, k, sensitivity, c1, c2, inertia=0.0,
                                   gamma=None):
    """Algorithm 9 (``gamma`` None) or (5.21) on full poses with scipy rotations: (5.19) with the
    geodesic angle of (5.20), differences ``[p_b − p, log(q⁻¹ ⊗ q_b)]``, moves ``p + ϑ_t`` and
    ``q ⊗ exp(ϑ_r)``. Returns the positions and quaternions scored at each iteration."""
    m = len(pos0)
    pos, rot, velocity = pos0.copy(), Rotation.from_quat(quat0), np.zeros((m, 6))
    best_pos, best_rot, best_w, scored = None, None, None, []
    for _ in range(iterations):
        scored.append((pos.copy(), rot.as_quat()))
        w = score(pos, rot.as_quat())
        if best_pos is None:
            best_pos, best_rot, best_w = pos.copy(), rot.as_quat(), w.copy()
        else:
            better = w > best_w
            best_pos[better], best_rot[better], best_w[better] = pos[better], rot.as_quat()[better], w[better]
        angle = np.array([(rot[i].inv() * rot).magnitude() for i in range(m)])
        dist = np.degrees(angle) / 180.0 * sensitivity + np.linalg.norm(pos[:, None] - pos[None], axis=2)
        neigh = np.array([near[np.argmax(best_w[near])] for near in np.argsort(dist, axis=1, kind="stable")[:, :k]])
        brot = Rotation.from_quat(best_rot)
        to_best = np.hstack([best_pos - pos, (rot.inv() * brot).as_rotvec()])
        to_neigh = np.hstack([best_pos[neigh] - pos, (rot.inv() * brot[neigh]).as_rotvec()])
        if gamma is None:
            r1, r2 = rng.random((m, 6)), rng.random((m, 6))
            velocity = inertia * velocity + c1 * r1 * to_best + c2 * r2 * to_neigh
        else:
            gauss = np.minimum(np.abs(rng.normal(size=(2, m, 6))), 1.0)
            uniform = rng.random((2, m, 6))
            same = np.all(np.sign(to_best) == np.sign(to_neigh), axis=1)[:, None]
            r1, r2 = np.where(same, gauss, uniform)
            velocity = gamma * (velocity + c1 * r1 * to_best + c2 * r2 * to_neigh)
        pos = pos + velocity[:, :3]
        rot = rot * Rotation.from_rotvec(velocity[:, 3:])
    return scored


@pytest.mark.parametrize("constricted", [False, True])
def test_pso_moves_rotations_by_the_body_frame_pulls_with_unequal_c1_and_c2(constricted):
    """Full 6-D swarms (rotations spread by ~15°, a score of position and angle): every pose scored
    agrees with a scipy swarm step for step, with c1 ≠ c2 so each coefficient must weigh its own
    pull (the own best's and the neighbourhood's)."""
    m, k, iterations, sens = 24, 4, 5, 5.0
    rng = np.random.default_rng(21)
    pos0 = T_STAR + rng.normal(size=(m, 3)) * 0.5
    centre = Rotation.from_euler("ZYX", [30.0, -10.0, 5.0], degrees=True)
    quat0 = (centre * Rotation.from_rotvec(rng.normal(size=(m, 3)) * np.radians(15.0))).as_quat()

    def score(pos, quat):
        angle = (Rotation.from_quat(quat) * centre.inv()).magnitude()
        return np.exp(-np.sum((pos - T_STAR) ** 2, axis=1) / 0.5**2 - angle**2 / 0.3**2)

    if constricted:
        cfg = ConstrictedPSOConfig(c1=1.6, c2=2.6, neighbours=k, sensitivity=sens)
        swarm, extra = ConstrictedPSO(cfg), {"c1": 1.6, "c2": 2.6, "gamma": cfg.gamma}
    else:
        swarm, extra = PSO(PSOConfig(c1=0.9, c2=1.9, inertia=0.5, neighbours=k, sensitivity=sens)), {
            "c1": 0.9, "c2": 1.9, "inertia": 0.5}
    record = Recording(lambda p: score(p.pos, p.quat))
    swarm.run(ParticleSet.from_poses(pos0, quat0), record, np.random.default_rng(12), iterations)
    expected = reference_swarm_with_rotations(pos0, quat0, score, np.random.default_rng(12), iterations, k, sens,
                                              **extra)
    assert len(record.pos) == iterations
    for got_pos, got_quat, (want_pos, want_quat) in zip(record.pos, record.quat, expected):
        np.testing.assert_allclose(got_pos, want_pos, rtol=0, atol=1e-9)
        np.testing.assert_allclose(np.abs(np.sum(got_quat * want_quat, axis=1)), 1.0, rtol=0, atol=1e-9)


def test_gabf_crossover_move_mutates_half_the_children_and_perturbs_the_population_best():
    """Coarse/fine move (Algorithm 10): every particle but the population's best becomes a child of
    the two best of Top A, taking each of X, Y, Z, α, β, γ from one parent or the other (both
    parents contribute); ⌊M/2⌋ children get the phase's noise Σ_coarse / Σ_fine, the others are
    exact crossovers; the best particle is its own pose plus Σ_best_* noise (tiny here)."""
    m, best = 2000, 7
    parents = ParticleSet.from_poses([[0.0, 0.0, 10.0], [5.0, -5.0, 20.0]],
                                     Rotation.from_euler("ZYX", [[10, 20, 30], [-40, -10, 60]], degrees=True).as_quat())
    rng = np.random.default_rng(8)
    weight = rng.uniform(0.0, 0.5, m)
    weight[best] = 0.9
    pop = ParticleSet.from_poses(100.0 + rng.normal(size=(m, 3)), Rotation.random(m, random_state=8).as_quat(), weight)
    cfg = GAbFConfig(coarse_sigma_m=(0.01, 0.01, 0.01), fine_sigma_m=(0.03, 0.03, 0.03),
                     best_coarse_sigma_m=(1e-7,) * 3, best_coarse_sigma_deg=(1e-5,) * 3,
                     best_fine_sigma_m=(1e-7,) * 3, best_fine_sigma_deg=(1e-5,) * 3)
    genes_a = np.concatenate([parents.pos[0], quat_to_euler_zyx(parents.quat[0])])
    genes_b = np.concatenate([parents.pos[1], quat_to_euler_zyx(parents.quat[1])])
    for phase, sigma in (("coarse", 0.01), ("fine", 0.03)):
        moved = GAbF(cfg)._move(pop, parents, phase, 0, np.random.default_rng(9))
        assert np.linalg.norm(moved.pos[best] - pop.pos[best]) < 1e-5
        assert np.degrees(np.linalg.norm(opt.rotvec_between(pop.quat[best], moved.quat[best]))) < 1e-3
        others = np.delete(np.arange(m), best)
        pos = moved.pos[others]
        exact = np.all((pos == parents.pos[0]) | (pos == parents.pos[1]), axis=1)
        assert m - m // 2 - 1 <= exact.sum() <= m - m // 2
        euler = quat_to_euler_zyx(moved.quat[others[exact]])
        assert np.all(np.isclose(euler, genes_a[3:], atol=1e-9) | np.isclose(euler, genes_b[3:], atol=1e-9))
        mixed = ~np.all(pos[exact] == parents.pos[0], axis=1) & ~np.all(pos[exact] == parents.pos[1], axis=1)
        assert mixed.mean() > 0.5  # 3 genes each: 6 of 8 position combinations take from both parents
        off = pos[~exact] - np.where(np.abs(pos[~exact] - parents.pos[0]) < np.abs(pos[~exact] - parents.pos[1]),
                                     parents.pos[0], parents.pos[1])
        np.testing.assert_allclose(np.std(off, axis=0), sigma, rtol=0.08)


@pytest.mark.parametrize("second, moves", [(0.15, False), (0.2, False), (0.3, True)])
def test_gabf_phase_follows_the_second_best_of_top_a_with_strict_thresholds(second, moves):
    """The phase is picked from the *second* best of Top A: one pose at 0.9 with the next at 0.15
    (under T_min) or exactly at T_min = 0.2 is still the bootstrap, whose first step moves nothing
    here (no score under δ); exactly at T_coarse = 0.3 is the coarse phase (crossovers move)."""
    def score(p):
        w = np.full(len(p), 0.15)
        w[4], w[9] = 0.9, second
        return w

    record = Recording(score)
    GAbF().run(flat_start(), record, np.random.default_rng(3), 2)
    assert (not np.array_equal(record.pos[0], record.pos[1])) == moves


def test_gabf_phase_exactly_at_t_coarse_is_coarse_and_runs_until_the_budget():
    """Two poses exactly at T_coarse: never the fine phase, which would end after ``fine_steps``
    moves; the coarse phase runs on to the iteration budget."""
    def score(p):
        w = np.full(len(p), 0.15)
        w[[4, 9]] = 0.3
        return w

    record = Recording(score)
    GAbF().run(flat_start(), record, np.random.default_rng(3), 12)
    assert len(record.pos) == 12


def test_gabf_result_keeps_the_best_pose_ever_scored_after_it_was_moved_away():
    """One pose scores 0.95 at the first evaluation only; the bootstrap then jitters every
    particle. The result still holds that pose, weighted 0.95, among its A best poses ever scored."""
    start = flat_start()

    def score(p):
        w = np.full(len(p), 0.15)
        if len(record.pos) == 1:
            w[2] = 0.95
        return w

    record = Recording(score)
    refined = GAbF().run(start, record, np.random.default_rng(6), 4)
    assert not np.any(np.all(record.pos[-1] == start.pos[2], axis=1))  # the last population moved off it
    hit = np.flatnonzero(np.all(refined.pos == start.pos[2], axis=1))
    assert len(hit) == 1 and refined.weight[hit[0]] == 0.95
    assert len(refined) == len(start)


def test_gabf_top_a_tells_poses_apart_by_rotation_as_well_as_position():
    """Two poses at one position but turned apart are distinct: both best ones are kept in the
    result's A best poses (a Top A that compared positions alone would drop one)."""
    start = flat_start()
    pos = start.pos.copy()
    pos[1] = pos[0]
    inp = ParticleSet.from_poses(pos, start.quat)
    levels = np.full(len(inp), 0.1)
    levels[[0, 1, 2]] = 0.9, 0.8, 0.7

    refined = GAbF().run(inp, lambda p: levels.copy(), np.random.default_rng(0), 1)
    elite = refined.take(np.arange(len(refined) - 3, len(refined)))
    np.testing.assert_array_equal(elite.weight, [0.9, 0.8, 0.7])
    np.testing.assert_array_equal(elite.pos[:2], inp.pos[:2])
    np.testing.assert_array_equal(elite.quat[:2], inp.quat[:2])


def test_gabf_first_bootstrap_replaces_only_scores_strictly_below_delta_with_init_noise():
    """A particle scoring exactly δ stays; those under it become the Top A member plus Σ_init noise
    (its own σ in metres and degrees, not Σ_bootstrap's)."""
    m = 4000
    quat = Rotation.random(random_state=5).as_quat()
    top = ParticleSet.from_poses([[1.0, 2.0, 30.0]], [quat])
    weight = np.full(m, 0.05)
    weight[0] = 0.1  # δ
    pop = ParticleSet.from_poses(np.tile([0.0, 0.0, 8.0], (m, 1)), np.tile(IDENTITY, (m, 1)), weight)
    cfg = GAbFConfig(init_sigma_m=(0.01, 0.02, 0.03), init_sigma_deg=(3.0, 6.0, 9.0))
    moved = GAbF(cfg)._move(pop, top, "bootstrap", 0, np.random.default_rng(6))
    np.testing.assert_array_equal(moved.pos[0], pop.pos[0])
    np.testing.assert_allclose(np.std(moved.pos[1:] - top.pos[0], axis=0), [0.01, 0.02, 0.03], rtol=0.06)
    turns = opt.rotvec_between(np.tile(quat, (m - 1, 1)), moved.quat[1:])
    np.testing.assert_allclose(np.degrees(np.std(turns, axis=0)), [3.0, 6.0, 9.0], rtol=0.06)


def test_gabf_keeps_the_set_size_when_fewer_than_a_distinct_poses_were_scored():
    """One pose resampled 20 times, one iteration: a single distinct pose is among the best ever
    scored, so the result is the last population's 19 best and that pose (20, as it came)."""
    one = flat_start().take(np.zeros(20, dtype=int))
    refined = GAbF().run(one, lambda p: np.full(len(p), 0.5), np.random.default_rng(0), 1)
    assert len(refined) == 20
    np.testing.assert_array_equal(refined.pos, one.pos)


def test_gabf_fine_phase_counts_its_steps_from_its_own_start():
    """Three bootstrap evaluations, then two poses above T_coarse: the fine phase starts at the
    fourth evaluation and ends after its own ``fine_steps`` moves (the bootstrap's steps do not count)."""
    def score(p):
        w = np.full(len(p), 0.15)
        if len(record.pos) > 3:
            w[[2, 5]] = 0.35
        return w

    record = Recording(score)
    GAbF().run(flat_start(), record, np.random.default_rng(4), 30)
    assert len(record.pos) == 3 + 1 + GAbFConfig().fine_steps
