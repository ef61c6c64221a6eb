"""Resampling schemes of App. B: unbiasedness where it holds, defining properties elsewhere."""

import numpy as np
import pytest

from uav_landing_vision.tracking import RESAMPLERS, fixed_size, resample
from uav_landing_vision.tracking import resampling as rs

M = 20
REPS = 3000
COUNT_UNBIASED = ["multinomial", "stratified", "systematic", "residual", "residual_systematic", "branch_kill"]
LOW_VARIANCE = ["stratified", "systematic", "residual", "residual_systematic", "branch_kill"]


@pytest.fixture(scope="module")
def weights():
    w = np.random.default_rng(7).gamma(0.7, size=M) + 0.05  # every M·w above ~0.05: seen often
    w[4] *= 6.0  # one dominant particle, several copies
    return w / w.sum()


def copy_counts(name, w, reps=REPS, seed=0, **options):
    rng = np.random.default_rng(seed)
    return np.array([np.bincount(resample(name, w, rng, **options).indices, minlength=len(w)) for _ in range(reps)])


def carried_weight(name, w, reps=REPS, seed=0, **options):
    rng = np.random.default_rng(seed)
    out = np.zeros((reps, len(w)))
    for r in range(reps):
        res = resample(name, w, rng, **options)
        np.add.at(out[r], res.indices, res.weights)
    return out


def assert_mean(samples, expected, slack=0.0, integer=False):
    """Monte-Carlo mean within 5 standard errors (plus a proven bias bound ``slack``).

    For integer counts the variance is at least ``f(1 − f)``, ``f`` the fractional part of the
    mean, which guards the standard error against an all-equal sample."""
    mean = samples.mean(axis=0)
    var = samples.var(axis=0, ddof=1)
    if integer:
        frac = expected - np.floor(expected)
        var = np.maximum(var, frac * (1.0 - frac))
    se = np.sqrt(var / len(samples))
    assert np.all(np.abs(mean - expected) <= 5.0 * se + slack + 1e-12), np.abs(mean - expected) / (se + 1e-12)


def test_registry_holds_the_ten_schemes():
    assert len(RESAMPLERS) == 10


@pytest.mark.parametrize("name", COUNT_UNBIASED)
def test_expected_copies_are_m_times_w(name, weights):
    assert_mean(copy_counts(name, weights), M * weights, integer=True)


@pytest.mark.parametrize("name", ["reallocation", "optimal"])
def test_weight_carrying_schemes_are_unbiased_in_carried_weight(name, weights):
    options = {"size": 8} if name == "optimal" else {}
    assert_mean(carried_weight(name, weights, **options), weights)


def test_reallocation_counts_are_floor_above_threshold_and_at_most_one_below(weights):
    counts = copy_counts("reallocation", weights, reps=500)
    big = M * weights >= 1.0
    assert np.all(counts[:, big] == np.floor(M * weights[big]))
    assert counts[:, ~big].max() == 1
    assert_mean(counts[:, ~big], M * weights[~big], integer=True)  # survival probability M·w below ℵ
    res = resample("reallocation", weights, np.random.default_rng(3))
    np.testing.assert_allclose(res.weights[res.indices == 4], weights[4] / np.floor(M * weights[4]))


def test_optimal_keeps_heavy_particles_once_and_never_replicates(weights):
    counts = copy_counts("optimal", weights, reps=500, size=8)
    assert counts.max() == 1 and np.all(counts.sum(axis=1) == 8)
    assert np.all(counts[:, 4] == 1)  # the dominant particle is above the threshold
    res = resample("optimal", weights, np.random.default_rng(0), size=8)
    assert res.weights[res.indices == 4][0] == pytest.approx(weights[4])


def _exact_threshold(weights, size):
    """Optimal resampling's c in exact arithmetic: the first k (weights descending) at which
    keeping the k largest whole leaves the next one below 1/c."""
    from fractions import Fraction

    desc = sorted((Fraction(int(v)) for v in weights), reverse=True)
    for k in range(size):
        c = (size - k) / sum(desc[k:])
        if c * desc[k] <= 1:
            return c
    raise AssertionError("no threshold")


def test_optimal_returns_size_particles_and_keeps_those_above_the_exact_threshold():
    """Integer weights with ties: in floating point c·desc[k] came out 1 + 2⁻⁵² at one k and
    1 − 2⁻⁵³ at the next, no k passed both tests, and c = size was taken: 8 or 9 particles of
    (7, 5, 0, 4, 3, 6, 3, 1, 6, 5, 1, 7, 1) came back for 10."""
    rng = np.random.default_rng(0)
    cases = [(np.array([7, 5, 0, 4, 3, 6, 3, 1, 6, 5, 1, 7, 1]), 10)]
    for _ in range(300):
        weights = rng.integers(0, 9, size=int(rng.integers(3, 16)))
        if np.count_nonzero(weights) > 1:
            cases.append((weights, int(rng.integers(1, np.count_nonzero(weights)))))
    for weights, size in cases:
        c = _exact_threshold(weights, size)
        above = {m for m, v in enumerate(weights) if c * int(v) > 1}
        for seed in range(3):
            res = resample("optimal", weights.astype(float), np.random.default_rng(seed), size=size)
            assert len(res.indices) == size and above <= set(res.indices.tolist()), (weights, size)


def test_optimal_at_full_size_keeps_every_positive_particle():
    w = np.array([0.5, 0.0, 0.2, 0.3])
    res = resample("optimal", w, np.random.default_rng(0))
    np.testing.assert_array_equal(res.indices, [0, 2, 3])
    np.testing.assert_allclose(res.weights, [0.5, 0.2, 0.3])


def test_metropolis_is_unbiased_up_to_its_proven_chain_bias(weights):
    # Independent MH with a uniform proposal: per-ancestor TV distance <= (1 - 1/(M max w))^S.
    steps = 80
    bias = M * (1.0 - 1.0 / (M * weights.max())) ** steps
    assert bias < 1e-3
    assert_mean(copy_counts("metropolis", weights, steps=steps), M * weights, slack=bias, integer=True)


def test_metropolis_with_a_short_chain_is_biased(weights):
    counts = copy_counts("metropolis", weights, steps=1)
    se = counts[:, 4].std(ddof=1) / np.sqrt(REPS)
    assert M * weights[4] - counts[:, 4].mean() > 10 * se


def test_minimum_sampling_is_deterministic_rounding(weights):
    a = resample("minimum_sampling", weights, np.random.default_rng(0)).indices
    b = resample("minimum_sampling", weights, np.random.default_rng(99)).indices
    np.testing.assert_array_equal(a, b)
    counts = np.bincount(a, minlength=M)
    assert counts.sum() == M and np.all(np.abs(counts - M * weights) < 1.0)
    residuals = M * weights - np.floor(M * weights)
    extra = counts - np.floor(M * weights)
    assert residuals[extra == 1].min() >= residuals[extra == 0].max()


@pytest.mark.parametrize("name", ["residual", "branch_kill", "reallocation", "minimum_sampling"])
def test_integer_copy_numbers_survive_round_off(name):
    """``M·w_m`` that is an integer in exact arithmetic gives exactly that many copies, though in
    floating point 49·(1/49) and 47·(3/47) fall just below 1 and 3."""
    w47 = np.concatenate([[3.0], np.ones(44), [0.0, 0.0]])  # M·w = 3, 1, ..., 1, 0, 0
    for w in (np.ones(49), w47):
        for seed in range(5):
            counts = np.bincount(resample(name, w, np.random.default_rng(seed)).indices, minlength=len(w))
            np.testing.assert_array_equal(counts, w)


def test_residual_systematic_matches_the_sequential_recursion(weights):
    for seed in range(20):
        u = np.random.default_rng(seed).random() / M
        counts = []
        for w in weights:  # Bolić et al. (2003), one pass with the fractional carry Δu
            n = int(np.floor((w - u) * M)) + 1
            u += n / M - w
            counts.append(n)
        got = np.bincount(rs.residual_systematic(weights, np.random.default_rng(seed)).indices, minlength=M)
        np.testing.assert_array_equal(got, counts)


def test_systematic_counts_are_floor_or_floor_plus_one_and_stratified_ones_are_not(weights):
    """Equally spaced points give ⌊M·w⌋ or ⌊M·w⌋ + 1 copies; one independent point per stratum
    can give a particle further from M·w."""
    floor = np.floor(M * weights)
    for name in ("systematic", "residual_systematic"):
        counts = copy_counts(name, weights, reps=500)
        assert np.all((counts == floor) | (counts == floor + 1))
    counts = copy_counts("stratified", weights, reps=500)
    assert np.any((counts < floor) | (counts > floor + 1))


def test_cdf_inversion_at_the_cumulative_weights():
    """``u`` equal to a cumulative weight takes the particle that ends there, never a zero weight."""
    w = np.array([0.25, 0.25, 0.0, 0.5])
    np.testing.assert_array_equal(rs._invert_cdf(w, np.array([0.25, 0.5, 0.75, 1.0])), [0, 1, 3, 3])


def test_branch_kill_counts_are_floor_or_floor_plus_one(weights):
    counts = copy_counts("branch_kill", weights, reps=500)
    assert np.all((counts == np.floor(M * weights)) | (counts == np.floor(M * weights) + 1))
    assert len(set(counts.sum(axis=1))) > 1  # the particle number changes


@pytest.mark.parametrize("name", LOW_VARIANCE)
def test_copy_count_variance_is_below_multinomial(name, weights):
    multinomial = copy_counts("multinomial", weights, seed=1).var(axis=0).sum()
    assert copy_counts(name, weights, seed=1).var(axis=0).sum() < 0.6 * multinomial


@pytest.mark.parametrize("name", sorted(RESAMPLERS))
def test_same_seed_same_indices(name, weights):
    a = resample(name, weights, np.random.default_rng(5))
    b = resample(name, weights, np.random.default_rng(5))
    np.testing.assert_array_equal(a.indices, b.indices)
    np.testing.assert_array_equal(a.weights, b.weights)


@pytest.mark.parametrize("name", sorted(RESAMPLERS))
def test_zero_weight_particles_are_never_drawn_and_output_is_in_range(name):
    w = np.array([0.0, 0.3, 0.1, 0.0, 0.25, 0.35, 0.0, 1e-3])
    for seed in range(50):
        idx = resample(name, w, np.random.default_rng(seed)).indices
        assert idx.min() >= 0 and idx.max() < len(w)
        assert not np.isin(idx, [0, 3, 6]).any()


@pytest.mark.parametrize("name", ["multinomial", "stratified", "systematic", "residual", "minimum_sampling"])
def test_a_single_heavy_particle_takes_every_copy(name):
    res = resample(name, np.eye(6)[2] * 3.0, np.random.default_rng(0))
    np.testing.assert_array_equal(res.indices, np.full(6, 2))
    np.testing.assert_allclose(res.weights, 1.0 / 6.0)


@pytest.mark.parametrize("bad", [np.array([0.5, -0.1]), np.array([np.nan, 1.0]), np.zeros(3), np.ones((2, 2)), []])
def test_invalid_weights_raise(bad):
    with pytest.raises(ValueError, match="resampling"):
        resample("systematic", bad, np.random.default_rng(0))


def test_unknown_scheme_names_the_known_ones():
    with pytest.raises(ValueError, match="unknown resampling scheme 'bogus'.*systematic"):
        resample("bogus", np.ones(3), np.random.default_rng(0))


@pytest.mark.parametrize("name", ["branch_kill", "reallocation", "optimal"])
def test_fixed_size_restores_the_particle_number(name, weights):
    rng = np.random.default_rng(11)
    for _ in range(50):
        res = resample(name, weights, rng, **({"size": 12} if name == "optimal" else {}))
        idx = fixed_size(res, weights, rng, M)
        assert len(idx) == M and np.all(np.diff(idx) >= 0)
        if len(res.indices) >= M:  # only dropping: a sub-multiset of the scheme's copies
            assert np.all(np.bincount(idx, minlength=M) <= np.bincount(res.indices, minlength=M))


def test_fixed_size_drops_copies_uniformly_and_fills_systematically():
    rng = np.random.default_rng(12)
    many = rs.Resampled(np.arange(10), np.full(10, 0.1))
    kept = np.array([np.bincount(fixed_size(many, np.ones(10), rng, 5), minlength=10) for _ in range(REPS)])
    assert_mean(kept, np.full(10, 0.5), integer=True)
    few = rs.Resampled(np.array([0]), np.ones(1))
    w = np.array([0.25, 0.25, 0.5])  # four systematic points on it: one, one and two copies
    np.testing.assert_array_equal(fixed_size(few, w, rng, 5), [0, 0, 1, 2, 2])


@pytest.mark.filterwarnings("error")  # the overflow is handled, not warned about
def test_weights_whose_sum_overflows_still_resample():
    idx = resample("systematic", np.full(3, 1e308), np.random.default_rng(0)).indices
    np.testing.assert_array_equal(idx, [0, 1, 2])


def test_metropolis_never_keeps_a_zero_weight_particle():
    w = np.eye(100)[37]  # one particle holds all the weight: no chain may stay on another
    np.testing.assert_array_equal(resample("metropolis", w, np.random.default_rng(0)).indices, np.full(100, 37))


def test_multinomial_indices_are_ascending():
    """As documented for every scheme but Metropolis."""
    w = np.random.default_rng(1).random(50)
    for seed in range(5):
        idx = resample("multinomial", w, np.random.default_rng(seed)).indices
        assert np.all(np.diff(idx) >= 0)


def test_residual_draws_a_single_residual_copy():
    """M·w = 1.2, 1.2, 0.6: one copy each from the floor, one more drawn."""
    for seed in range(10):
        assert len(resample("residual", [0.4, 0.4, 0.2], np.random.default_rng(seed)).indices) == 3


def test_residual_draws_its_remainder_independently_so_a_particle_can_get_two_extra_copies():
    """M·w = (1.2, 1.2, 0.8, 0.8): one copy each for the first two, then R = 2 multinomial draws
    with probabilities (0.1, 0.1, 0.4, 0.4) from the residuals; both land on particle 2 with
    probability 0.16, which one point in each half of the residual CDF never gives."""
    counts = copy_counts("residual", np.array([0.3, 0.3, 0.2, 0.2]), reps=400)
    assert np.all(counts[:, :2] >= 1) and np.all(counts.sum(axis=1) == 4)
    assert 0.10 < np.mean(counts[:, 2] == 2) < 0.23


def test_metropolis_needs_at_least_one_step():
    """Zero steps would return every particle once: no resampling at all."""
    with pytest.raises(ValueError, match="steps must be at least 1"):
        resample("metropolis", np.ones(4), np.random.default_rng(0), steps=0)


def test_optimal_refuses_size_zero_by_name():
    with pytest.raises(ValueError, match="size must be at least 1"):
        resample("optimal", np.ones(4), np.random.default_rng(0), size=0)


def test_minimum_sampling_breaks_residual_ties_to_the_lower_index():
    """64 particles, M·w in pairs (0.25, 1.75), (0.5, 1.5), (0.75, 1.25): 30 extra copies
    go to the twenty residuals of 0.75 and the ten lowest-indexed of 0.5 (exact in binary)."""
    pairs = np.random.default_rng(0).permutation(np.repeat([0, 1, 2], [11, 11, 10]))
    mw = np.array([[0.25, 1.75], [0.5, 1.5], [0.75, 1.25]])[pairs].ravel()
    counts = np.bincount(resample("minimum_sampling", mw, None).indices, minlength=64)
    base = np.floor(mw)
    extra = counts - base
    frac = mw - base
    half = np.flatnonzero(frac == 0.5)
    assert counts.sum() == 64
    assert np.all(extra[frac == 0.75] == 1) and np.all(extra[frac == 0.25] == 0)
    np.testing.assert_array_equal(extra[half], (np.arange(len(half)) < 64 - base.sum() - np.sum(frac == 0.75)))


def test_fixed_size_fills_with_equally_spaced_points():
    """Four systematic points on (0.3, 0.3, 0.4) give each particle ⌊4w⌋ or ⌊4w⌋ + 1 copies
    whatever the offset (particle 1 at least one); stratified points give it none one time in eight."""
    few = rs.Resampled(np.array([0]), np.ones(1))
    for seed in range(100):
        idx = fixed_size(few, np.array([0.3, 0.3, 0.4]), np.random.default_rng(seed), 5)
        extra = np.bincount(idx, minlength=3) - [1, 0, 0]
        assert extra.sum() == 4 and np.all((extra >= [1, 1, 1]) & (extra <= [2, 2, 2])), extra


def _systematic_copies(w, n, u):
    """Copies of each particle from the ``n`` points ``(j + u)/n`` through the weight CDF, by a loop."""
    cdf = np.cumsum(w) / np.sum(w)
    counts = np.zeros(len(w), int)
    for j in range(n):
        counts[next(m for m in range(len(w)) if (j + u) / n <= cdf[m] + 1e-15)] += 1
    return counts


def test_fixed_size_fills_a_shortfall_with_points_spread_over_the_whole_cdf():
    """Eight points on four equal weights give exactly two more copies of each, whatever the offset;
    on (0.1, 0.35, 0.05, 0.5) seven points give the copies of a loop over (j + u)/7, u the
    generator's first uniform taken on (0, 1]."""
    w = np.array([0.1, 0.35, 0.05, 0.5])
    for seed in range(20):
        idx = fixed_size(rs.Resampled(np.array([3]), np.ones(1)), np.ones(4), np.random.default_rng(seed), 9)
        assert len(idx) == 9 and np.all(np.diff(idx) >= 0)
        np.testing.assert_array_equal(np.bincount(idx, minlength=4), [2, 2, 2, 3])
        idx = fixed_size(rs.Resampled(np.array([0, 0]), np.ones(2)), w, np.random.default_rng(seed), 9)
        u = 1.0 - np.random.default_rng(seed).random()
        np.testing.assert_array_equal(np.bincount(idx, minlength=4) - [2, 0, 0, 0], _systematic_copies(w, 7, u))


def test_optimal_threshold_at_a_tied_weight():
    """Weights (2, 2, 1, 2, 2, 0, 3, 3, 4, 4)/23 down to 7: c = 23/3 exactly (ℵ = 3/23, on
    the two 3s): the 4s and 3s are kept, three of the others drawn, each carrying 3/23."""
    w = np.array([2, 2, 1, 2, 2, 0, 3, 3, 4, 4], float)
    for seed in range(20):
        res = resample("optimal", w, np.random.default_rng(seed), size=7)
        assert len(res.indices) == 7 and set(res.indices) >= {6, 7, 8, 9}
        light = ~np.isin(res.indices, [6, 7, 8, 9])
        np.testing.assert_allclose(res.weights[light], 3 / 23)
        np.testing.assert_allclose(res.weights[~light], w[res.indices[~light]] / 23)


def test_optimal_keeps_both_heavy_particles_when_a_negligible_weight_hides_in_the_round_off():
    """(0.9, 0.1, 1e-30) down to 2: ℵ = 0.1 exactly (Σ min(10 w, 1) = 2), so both heavy particles
    are kept with their own weights. The tail sum 0.1 + 1e-30 rounds to 0.1, so c·w is 1 there to
    the last bit: a strict test found no k, fell back to k = 0 and drew particle 1 one time in five."""
    for seed in range(10):
        res = resample("optimal", np.array([0.9, 0.1, 1e-30]), np.random.default_rng(seed), size=2)
        np.testing.assert_array_equal(res.indices, [0, 1])
        np.testing.assert_allclose(res.weights, [0.9, 0.1], rtol=1e-12)


def test_optimal_down_to_the_positive_count_keeps_every_positive_particle():
    """``size`` equal to the number of positive weights keeps each once with its weight;
    the general path, which it must not take, lost two of them to round-off with tied weights."""
    w = np.array([3.0, 0.0, 3.0, 0.0, 3.0, 9.0, 10.0, 7.0, 0.0, 0.0, 8.0, 0.0, 6.0])
    res = resample("optimal", w, np.random.default_rng(0), size=8)
    np.testing.assert_array_equal(res.indices, np.flatnonzero(w))
    np.testing.assert_allclose(res.weights, w[w > 0] / w.sum())


class _ZeroRandom:
    """A generator whose uniforms are all 0.0, the edge of [0, 1)."""

    def random(self, size=None):
        return 0.0 if size is None else np.zeros(size)


@pytest.mark.parametrize("name", ["multinomial", "stratified", "systematic"])
def test_a_uniform_of_zero_never_draws_a_zero_weight_particle(name):
    """The CDF is inverted at u in (0, 1]: u = 0 would fall on particle 0 of weight 0, and u = 1
    past a cumulative sum that rounds below 1 (ten weights of 0.1) on a trailing zero weight."""
    np.testing.assert_array_equal(resample(name, [0.0, 1.0], _ZeroRandom()).indices, [1, 1])
    assert resample(name, [0.1] * 10 + [0.0], _ZeroRandom()).indices.max() == 9
