"""Pose optimisers of §5.5 on a synthetic objective with a known optimum."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from uav_landing_vision.config import ConfigError, from_mapping
from uav_landing_vision.geometry import geodesic_angle, quat_to_euler_zyx
from uav_landing_vision.tracking import (
    PFO,
    PSO,
    ConstrictedPSO,
    ConstrictedPSOConfig,
    GAbF,
    GAbFConfig,
    ParticleSet,
    PFOConfig,
    PSOConfig,
    pfo_noise,
)
from uav_landing_vision.tracking import optimisation as opt

M = 100
T_STAR = np.array([0.3, -0.2, 5.0])
Q_STAR = Rotation.from_euler("ZYX", [40.0, -20.0, 10.0], degrees=True).as_quat()
SIGMA, KAPPA = 0.5, 0.6


def pose_score(pos, quat) -> np.ndarray:
    """exp(−‖t − t*‖²/σ² − angle(q, q*)²/κ²): 1 at the optimum."""
    d2 = np.sum((pos - T_STAR) ** 2, axis=-1)
    return np.exp(-d2 / SIGMA**2 - geodesic_angle(quat, Q_STAR) ** 2 / KAPPA**2)


def objective(particles: ParticleSet) -> np.ndarray:
    return pose_score(particles.pos, particles.quat)


class Counting:
    """Wraps an objective and records the batch size of each call."""

    def __init__(self, score=objective):
        self.score, self.batches = score, []

    def __call__(self, particles):
        self.batches.append(len(particles))
        return self.score(particles)


def start(seed=0, spread_m=0.5, spread_rad=0.5, m=M) -> ParticleSet:
    rng = np.random.default_rng(seed)
    pos = T_STAR + rng.normal(size=(m, 3)) * spread_m
    quat = (Rotation.from_quat(Q_STAR) * Rotation.from_rotvec(rng.normal(size=(m, 3)) * spread_rad)).as_quat()
    return ParticleSet.from_poses(pos, quat, state={"id": np.arange(m)})


OPTIMISERS = {
    "pfo-noise": lambda: PFO(PFOConfig(schedule="noise")),
    "pfo-3phase": lambda: PFO(PFOConfig(schedule="3phase")),
    "pfo-iterative": lambda: PFO(PFOConfig(schedule="iterative")),
    "pfo-systematic": lambda: PFO(PFOConfig(schedule="iterative", resampling="systematic")),
    "pso": lambda: PSO(),
    "constricted-pso": lambda: ConstrictedPSO(),
    "gabf": lambda: GAbF(),
}


@pytest.fixture(scope="module")
def results():
    """Each optimiser's output after 20 iterations from the same start, and its call log."""
    out = {}
    for name, make in OPTIMISERS.items():
        counter = Counting()
        out[name] = (make().run(start(), counter, np.random.default_rng(1), 20), counter.batches)
    return out


@pytest.mark.parametrize("name", sorted(OPTIMISERS))
def test_improves_the_best_score_and_approaches_the_optimum(name, results):
    """The swarms and GAbF close most of the score gap; PFO with the tables' small translation
    noise (5 mm in the iterative schedule) mostly selects, so it must close less."""
    refined, _ = results[name]
    first = start().with_weight(objective(start())).best()
    initial, best = first.weight[0], refined.best()
    closed = 0.3 if name.startswith("pfo") else 0.9
    assert best.weight[0] > initial + closed * (1.0 - initial)
    assert np.linalg.norm(best.pos[0] - T_STAR) < np.linalg.norm(first.pos[0] - T_STAR)
    assert geodesic_angle(best.quat[0], Q_STAR) < geodesic_angle(first.quat[0], Q_STAR)


@pytest.mark.parametrize("name", sorted(OPTIMISERS))
def test_one_batched_objective_call_per_iteration(name, results):
    refined, batches = results[name]
    assert 1 <= len(batches) <= 20 and set(batches) == {M}
    if not name.startswith("gabf"):
        assert len(batches) == 20
    assert len(refined) == M


@pytest.mark.parametrize("name", sorted(OPTIMISERS))
def test_weights_are_the_scores_of_the_returned_poses(name, results):
    refined, _ = results[name]
    np.testing.assert_allclose(refined.weight, objective(refined), rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(refined.quat, axis=1), 1.0, atol=1e-12)


@pytest.mark.parametrize("name", sorted(OPTIMISERS))
def test_same_seed_same_result(name):
    a = OPTIMISERS[name]().run(start(), objective, np.random.default_rng(3), 5)
    b = OPTIMISERS[name]().run(start(), objective, np.random.default_rng(3), 5)
    np.testing.assert_array_equal(a.pos, b.pos)
    np.testing.assert_array_equal(a.quat, b.quat)


def test_pso_keeps_each_particle_in_its_slot_and_never_loses_the_best(results):
    for name in ("pso", "constricted-pso"):
        refined, _ = results[name]
        np.testing.assert_array_equal(refined.state["id"], np.arange(M))
        assert np.all(refined.weight >= objective(start()) - 1e-15)


def test_pfo_carries_velocities_and_state_with_the_ancestors():
    p = start()
    p = ParticleSet(p.pos, p.quat, np.arange(M)[:, None] * np.ones(3), p.vel, p.weight, p.state)
    refined = PFO(PFOConfig(schedule="iterative")).run(p, objective, np.random.default_rng(0), 3)
    np.testing.assert_array_equal(refined.vel[:, 0], refined.state["id"])
    assert len(set(refined.state["id"])) < M  # resampling replicated some ancestors


def test_3phase_schedule_follows_tables_6_6_and_6_7():
    cfg = PFOConfig(schedule="3phase", dt=0.034)
    rows = [((0.05, 0.05, 0.01), 15.0)] * 3 + [((0.035, 0.035, 0.005), 7.0)] * 3 + [((0.0025,) * 3, 4.0)] * 4
    for k, (trans, rot_deg) in enumerate(rows, start=1):
        t, rate = pfo_noise(cfg, k)
        np.testing.assert_allclose(t, trans)
        np.testing.assert_allclose(np.degrees(rate * cfg.dt), rot_deg)


def test_iterative_schedule_follows_tables_6_6_and_6_7():
    cfg = PFOConfig(schedule="iterative")
    for k in range(1, 11):
        t, rate = pfo_noise(cfg, k)
        np.testing.assert_allclose(t, 0.005)
        np.testing.assert_allclose(np.degrees(rate * cfg.dt), 18.0 - k)
    assert np.all(pfo_noise(cfg, 40)[1] > 0.0)


def test_noise_schedule_is_constant_section_6_7_1_by_default_and_table_6_6_on_request():
    for k in (1, 7):
        t, rate = pfo_noise(PFOConfig(), k)
        np.testing.assert_allclose(t, [0.1, 0.1, 0.2])
        np.testing.assert_allclose(rate, 2.62)
    t, rate = pfo_noise(opt.SECTION_6_6_NOISE, 1)
    np.testing.assert_allclose(t, [0.05, 0.05, 0.01])
    np.testing.assert_allclose(np.degrees(rate * opt.SECTION_6_6_NOISE.dt), 5.0)


def test_pfo_adds_the_scheduled_noise():
    """With a flat objective and deterministic resampling of uniform weights the particles only
    move by ζ: its sample standard deviations match the schedule."""
    m = 4000
    p = start(m=m)
    cfg = PFOConfig(schedule="noise", resampling="minimum_sampling", noise_rate_sigma=(1.0, 2.0, 3.0))
    moved = PFO(cfg).run(p, lambda s: np.ones(len(s)), np.random.default_rng(2), 1)
    np.testing.assert_allclose(np.std(moved.pos - p.pos, axis=0), [0.1, 0.1, 0.2], rtol=0.06)
    rates = opt.rotvec_between(p.quat, moved.quat) / cfg.dt
    np.testing.assert_allclose(np.std(rates, axis=0), [1.0, 2.0, 3.0], rtol=0.06)


def test_pfo_translation_noise_scales_with_depth():
    """With a reference depth the translation σ is the schedule's times depth / reference, per
    particle: a UAV twice as far moves twice as far; rotation noise is unchanged."""
    m = 4000
    p = start(m=m)
    depth = np.where(np.arange(m) < m // 2, 10.0, 80.0)
    p = p.with_pose(np.column_stack([p.pos[:, :2], depth]), p.quat)
    cfg = PFOConfig(schedule="noise", resampling="minimum_sampling", reference_depth_m=40.0)
    moved = PFO(cfg).run(p, lambda s: np.ones(len(s)), np.random.default_rng(3), 1)
    near, far = moved.pos[: m // 2] - p.pos[: m // 2], moved.pos[m // 2 :] - p.pos[m // 2 :]
    np.testing.assert_allclose(np.std(near, axis=0), np.array([0.1, 0.1, 0.2]) * 0.25, rtol=0.08)
    np.testing.assert_allclose(np.std(far, axis=0), np.array([0.1, 0.1, 0.2]) * 2.0, rtol=0.08)
    rates = opt.rotvec_between(p.quat, moved.quat) / cfg.dt
    np.testing.assert_allclose(np.std(rates, axis=0), [2.62] * 3, rtol=0.06)


def test_constriction_coefficient_is_5_22():
    assert ConstrictedPSOConfig().gamma == pytest.approx(0.729843788, rel=1e-9)  # Clerc & Kennedy
    assert ConstrictedPSOConfig(k=0.5).gamma == pytest.approx(0.5 * 0.729843788, rel=1e-9)


def test_constricted_pso_draws_gaussian_factors_only_where_both_pulls_agree():
    """§5.5.3: r1 and r2 are min(|N(0, 1)|, 1) (scipy's normal law: mean 2(φ(0) − φ(1)) + P(|Z| > 1),
    a third of them exactly 1) where p_best − p and p_neigh − p have the same sign in all six
    dimensions, uniform on [0, 1) otherwise. Without inertia and with a pull to the neighbourhood's
    best of ±1e-300 the velocity is Γ c1 r1 (p_best − p), which gives r1."""
    from scipy.stats import norm

    n, pso = 20000, ConstrictedPSO()
    c = pso.config
    to_best = np.ones((n, 6))
    agree, mixed = np.ones(6), np.array([1.0, 1.0, 1.0, 1.0, 1.0, -1.0])
    for sign, mean, at_one in ((agree, 2 * (norm.pdf(0) - norm.pdf(1)) + 2 * norm.sf(1), 2 * norm.sf(1)),
                               (-agree, 0.5, 0.0), (mixed, 0.5, 0.0)):
        velocity = pso._velocity(np.zeros((n, 6)), to_best, sign * 1e-300 * to_best, np.random.default_rng(4))
        r1 = velocity / (c.gamma * c.c1)
        assert 0.0 <= r1.min() and r1.max() <= 1.0 + 1e-12
        assert abs(r1.mean() - mean) < 5 * r1.std() / np.sqrt(r1.size), (sign, r1.mean(), mean)
        ones = np.mean(np.abs(r1 - 1.0) < 1e-12)
        assert abs(ones - at_one) < 5 * np.sqrt(at_one * (1 - at_one) / r1.size) + 1e-12, (sign, ones, at_one)


def test_neighbourhood_distance_is_5_19():
    pos = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    quat = np.array([[0.0, 0.0, 0.0, 1.0], Rotation.from_euler("z", 90, degrees=True).as_quat()])
    d = opt.neighbourhood_distance(pos, quat, sensitivity=5.0)
    np.testing.assert_allclose(d, [[0.0, 90 / 180 * 5 + 1.0], [3.5, 0.0]], atol=1e-12)


def test_crossover_takes_every_attribute_from_one_parent():
    rng = np.random.default_rng(0)
    qa = Rotation.from_euler("ZYX", [30, 10, -20], degrees=True).as_quat()
    qb = Rotation.from_euler("ZYX", [-50, 25, 60], degrees=True).as_quat()
    pa, pb = np.array([1.0, 2.0, 3.0]), np.array([-1.0, -2.0, -3.0])
    pos, quat = opt.crossover(pa, qa, pb, qb, 200, rng)
    genes = np.concatenate([pos, quat_to_euler_zyx(quat)], axis=1)
    a = np.concatenate([pa, quat_to_euler_zyx(qa)])
    b = np.concatenate([pb, quat_to_euler_zyx(qb)])
    from_a, from_b = np.isclose(genes, a), np.isclose(genes, b)
    assert np.all(from_a | from_b) and from_a.any(axis=0).all() and from_b.any(axis=0).all()


def test_gabf_bootstrap_replaces_only_the_particles_below_delta():
    """Algorithm 10's first bootstrap move: a particle scoring under δ becomes a Top A member plus
    Σ_init noise (σ 0.1 m: within 0.6 m of one); one scoring δ or more is kept as it is."""
    p = start(m=40)
    top = p.take([0, 1, 2])
    weight = np.where(np.arange(40) % 2 == 0, 0.09, 0.11)  # either side of δ = 0.1
    moved = GAbF()._move(p.with_weight(weight), top, "bootstrap", 0, np.random.default_rng(0))
    kept = weight >= GAbFConfig().delta
    np.testing.assert_array_equal(moved.pos[kept], p.pos[kept])
    np.testing.assert_array_equal(moved.quat[kept], p.quat[kept])
    to_top = np.linalg.norm(moved.pos[~kept, None] - top.pos[None], axis=2).min(axis=1)
    assert np.all(to_top < 0.6) and not np.any(np.all(moved.pos[~kept] == p.pos[~kept], axis=1))


def test_gabf_stops_after_the_fine_phase_on_an_easy_objective():
    counter = Counting()
    GAbF().run(start(spread_m=0.1, spread_rad=0.1), counter, np.random.default_rng(0), 60)
    assert len(counter.batches) < 60


def test_gabf_uses_the_whole_budget_when_no_pose_reaches_t_min():
    counter = Counting(lambda p: 0.1 * objective(p))
    refined = GAbF().run(start(), counter, np.random.default_rng(0), 40)
    assert len(counter.batches) == 40
    assert refined.weight.max() >= 0.1 * objective(start()).max()


def test_gabf_optimises_the_b_best_input_particles_and_carries_the_others():
    p = start().with_weight(np.arange(M, dtype=float))
    counter = Counting()
    refined = GAbF(GAbFConfig(top_b=30)).run(p, counter, np.random.default_rng(0), 1)
    assert len(refined) == M and set(counter.batches) == {30}
    assert set(refined.state["id"][:30]) <= set(range(70, 100))
    rest = refined.take(np.arange(30, M))  # the 70 others, as they came, best first
    np.testing.assert_array_equal(rest.state["id"], np.arange(69, -1, -1))
    np.testing.assert_array_equal(rest.pos, p.pos[69::-1])
    np.testing.assert_array_equal(rest.weight, p.weight[69::-1])


def test_gabf_returns_a_single_particle_as_it_came():
    one = start().take([0])
    refined = GAbF().run(one, objective, np.random.default_rng(0), 5)
    assert len(refined) == 1
    np.testing.assert_array_equal(refined.pos, one.pos)
    np.testing.assert_array_equal(refined.quat, one.quat)


@pytest.mark.parametrize(
    "make",
    [
        lambda: PFOConfig(schedule="linear"),
        lambda: PFOConfig(resampling="bogus"),
        lambda: PFOConfig(noise_trans_sigma_m=(0.1, -0.1, 0.2)),
        lambda: PFOConfig(reference_depth_m=-1.0),
        lambda: PSOConfig(inertia=1.5),
        lambda: PSOConfig(neighbours=0),
        lambda: ConstrictedPSOConfig(c1=1.0, c2=2.0),
        lambda: ConstrictedPSOConfig(k=0.0),
        lambda: GAbFConfig(t_min=0.5, t_coarse=0.3),
        lambda: GAbFConfig(top_a=1),
        lambda: GAbFConfig(fine_sigma_deg=(15.0, 0.0, 15.0)),
        lambda: PFOConfig(phase_length=0),
        lambda: PFOConfig(dt=opt.MAX_DT * 1.5),
        lambda: PFOConfig(noise_trans_sigma_m=(opt.MAX_STD * 2, 0.1, 0.1)),
        lambda: PFOConfig(noise_rate_sigma=(1.0, opt.MAX_STD * 2, 1.0)),
        lambda: PSOConfig(inertia=1.0),  # ϖ < 1
        lambda: ConstrictedPSOConfig(c1=2.0, c2=2.0),  # (5.22) needs φ > 4, strictly
        lambda: ConstrictedPSOConfig(k=1.5),  # k in (0, 1]
        lambda: GAbFConfig(top_b=1),
        lambda: GAbFConfig(t_min=0.3, t_coarse=0.3),  # T_min < T_coarse, strictly
        lambda: GAbFConfig(fine_steps=0),
        lambda: GAbFConfig(max_restarts=-1),
    ],
)
def test_invalid_configs_raise(make):
    with pytest.raises(ValueError):
        make()


@pytest.mark.parametrize(
    "bad", [lambda p: np.ones(len(p) + 1), lambda p: -np.ones(len(p)), lambda p: np.full(len(p), np.nan)]
)
def test_invalid_objective_output_raises(bad):
    with pytest.raises(ValueError, match="objective"):
        PSO().run(start(), bad, np.random.default_rng(0), 1)


def test_configs_load_from_yaml_mappings():
    cfg = from_mapping(GAbFConfig, {"t_min": 0.25, "fine_sigma_deg": [10, 10, 10]})
    assert cfg.t_min == 0.25 and cfg.fine_sigma_deg == (10.0, 10.0, 10.0)
    assert from_mapping(PFOConfig, {"schedule": "3phase", "resampling": "systematic"}).schedule == "3phase"
    with pytest.raises(ConfigError, match="schedule"):
        from_mapping(PFOConfig, {"schedule": "linear"})
    with pytest.raises(ConfigError, match="unknown key"):
        from_mapping(PSOConfig, {"inertial": 0.5})


def test_zero_iterations_is_an_error():
    with pytest.raises(ValueError, match="at least one iteration"):
        PFO().run(start(), objective, np.random.default_rng(0), 0)


unit_quats = arrays(np.float64, 4, elements=st.floats(-1.0, 1.0)).filter(lambda q: np.linalg.norm(q) > 0.1)
rotvecs = arrays(np.float64, 3, elements=st.floats(-10.0, 10.0))


@settings(max_examples=60, deadline=None)
@given(unit_quats, rotvecs)
def test_increments_keep_quaternions_unit(q, r):
    q = q / np.linalg.norm(q)
    np.testing.assert_allclose(np.linalg.norm(opt.rotate_body(q, r)), 1.0, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(unit_quats, unit_quats)
def test_tangent_difference_and_objective_are_sign_invariant(q, p):
    q, p = q / np.linalg.norm(q), p / np.linalg.norm(p)
    r = opt.rotvec_between(q, p)
    assert np.linalg.norm(r) == pytest.approx(geodesic_angle(q, p), abs=1e-9)  # (5.20)
    for a, b in ((q, p), (-q, p), (q, -p), (-q, -p)):
        assert np.linalg.norm(opt.rotvec_between(a, b)) == pytest.approx(np.linalg.norm(r), abs=1e-9)
        assert geodesic_angle(opt.rotate_body(a, opt.rotvec_between(a, b)), p) < 1e-7
    np.testing.assert_allclose(pose_score(T_STAR, q), pose_score(T_STAR, -q), atol=1e-12)


def test_gabf_copes_with_a_resampled_input_of_one_repeated_pose():
    one = start().take(np.zeros(M, dtype=int))
    counter = Counting()
    refined = GAbF().run(one, counter, np.random.default_rng(0), 30)
    assert len(refined) == M and set(counter.batches) == {M}
    assert refined.weight.max() > objective(one)[0]


def test_objective_output_of_the_wrong_shape_raises_even_with_m_values():
    """One likelihood per particle, shape (M,) exactly (not M values in another shape), none negative."""
    for optimiser in (PFO(), PSO(), GAbF()):
        with pytest.raises(ValueError, match="objective returned shape"):
            optimiser.run(start(), lambda p: np.ones((len(p), 1)), np.random.default_rng(0), 1)
    with pytest.raises(ValueError, match="non-negative"):
        PSO().run(start(), lambda p: np.full(len(p), -0.5), np.random.default_rng(0), 1)


def test_configs_on_the_edges_of_their_ranges_are_accepted():
    """The bounds are inclusive where documented so: Δt and σ at their limits, k = 1, ϖ = 0, one
    neighbour, top_a = top_b = 2, no restarts, δ = T_min = 0."""
    PFOConfig(dt=opt.MAX_DT, noise_trans_sigma_m=(opt.MAX_STD,) * 3, phase_length=1)
    PSOConfig(inertia=0.0, neighbours=1)
    ConstrictedPSOConfig(k=1.0, c1=2.0, c2=2.0 + 1e-9)
    GAbFConfig(top_a=2, top_b=2, max_restarts=0, delta=0.0, t_min=0.0)


def test_pfo_keeps_every_particle_once_when_every_score_is_zero():
    """Nothing to resample on: each particle is carried once (moved by ζ), weighted 0."""
    refined = PFO().run(start(), lambda p: np.zeros(len(p)), np.random.default_rng(0), 3)
    np.testing.assert_array_equal(refined.state["id"], np.arange(M))
    np.testing.assert_array_equal(refined.weight, np.zeros(M))


@pytest.mark.parametrize("schedule, trans, rot_deg", [("3phase", [0.05, 0.05, 0.01], 15.0),
                                                      ("iterative", [0.005] * 3, 17.0)])
def test_pfo_first_iteration_uses_the_first_row_of_its_schedule(schedule, trans, rot_deg):
    """Iterations count from I = 1: the first PFO move of the 3Phase schedule has the first row's
    σ (Tables 6.6–6.7), the iterative one 18 − 1 = 17°."""
    m = 4000
    p = start(m=m)
    cfg = PFOConfig(schedule=schedule, resampling="minimum_sampling", phase_length=1)
    moved = PFO(cfg).run(p, lambda s: np.ones(len(s)), np.random.default_rng(5), 1)
    np.testing.assert_allclose(np.std(moved.pos - p.pos, axis=0), trans, rtol=0.06)
    turns = opt.rotvec_between(p.quat, moved.quat)
    np.testing.assert_allclose(np.degrees(np.std(turns, axis=0)), [rot_deg] * 3, rtol=0.06)


def test_pfo_resamples_with_the_configured_scheme(monkeypatch):
    """Each PFO iteration resamples with ``PFOConfig.resampling`` (the scheme named in the call)."""
    from uav_landing_vision.tracking.resampling import resample

    names = []

    def spy(name, weights, rng, **options):
        names.append(name)
        return resample(name, weights, rng, **options)

    monkeypatch.setattr(opt, "resample", spy)
    PFO(PFOConfig(resampling="multinomial")).run(start(), objective, np.random.default_rng(0), 3)
    assert names == ["multinomial"] * 3


def test_make_optimiser_builds_the_named_optimiser_pfo_with_the_given_settings():
    """Each name gives its optimiser of §5.5: PFO with the settings given, the others with their own."""
    cfg = PFOConfig(schedule="iterative")
    pfo = opt.make_optimiser("pfo", cfg)
    assert type(pfo) is PFO and pfo.config == cfg
    for name, kind, config in (("pso", PSO, PSOConfig()), ("constricted_pso", ConstrictedPSO, ConstrictedPSOConfig()),
                               ("gabf", GAbF, GAbFConfig())):
        made = opt.make_optimiser(name, cfg)
        assert type(made) is kind and made.config == config
