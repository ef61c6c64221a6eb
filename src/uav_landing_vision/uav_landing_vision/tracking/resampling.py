"""The ten resampling schemes of Appendix B (§5.4.2), vectorised over particles.

Every scheme takes non-negative ``weights (M,)`` (normalised here) and a seeded
``numpy.random.Generator`` and returns :class:`Resampled`: ancestor ``indices (M_out,)``
and the weight each copy carries. Most schemes give ``M_out = M`` copies of weight ``1/M``;
the exceptions are documented per scheme. ``N`` in App. B is the particle number ``M``.

Unbiased in copy counts (``E[#copies of m] = M·w_m``): multinomial, stratified, systematic,
residual, residual-systematic, branch-kill. Reallocation and optimal are unbiased in carried
weight (``E[Σ weights of the copies of m] = w_m``) but not in counts; Metropolis is biased for
a finite chain length; minimum sampling is a deterministic rounding and so biased.
"""

from typing import NamedTuple

import numpy as np


class Resampled(NamedTuple):
    indices: np.ndarray  # (M_out,) ancestor indices, ascending except for Metropolis
    weights: np.ndarray  # (M_out,) weight carried by each copy


def _normalise(weights) -> np.ndarray:
    w = np.asarray(weights, dtype=float)
    if w.ndim != 1 or w.size == 0:
        raise ValueError(f"resampling: weights must be a non-empty 1-D array, got shape {w.shape}")
    if not np.all(np.isfinite(w)) or np.any(w < 0.0):
        raise ValueError("resampling: weights must be finite and non-negative")
    with np.errstate(over="ignore"):  # handled below
        total = w.sum()
    if not np.isfinite(total):  # each weight finite, their sum beyond float range
        w = w / w.max()
        total = w.sum()
    if not total > 0.0:
        raise ValueError("resampling: weights sum to zero")
    return w / total


def _uniform(indices: np.ndarray) -> Resampled:
    return Resampled(indices, np.full(len(indices), 1.0 / max(len(indices), 1)))


def _from_counts(counts: np.ndarray, weights=None) -> Resampled:
    idx = np.repeat(np.arange(len(counts)), counts)
    return _uniform(idx) if weights is None else Resampled(idx, np.repeat(weights, counts))


def _floor_copies(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``M·w`` and ``⌊M·w⌋``, the floor forgiving round-off: in floating point 49·(1/49) is just
    below 1, and a plain floor would take a copy from every such particle."""
    scaled = len(w) * w
    return scaled, np.floor(scaled + 1e-9)


def _invert_cdf(w: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Index m with ``Σ_{n<m} w_n < u ≤ Σ_{n≤m} w_n`` for each ``u`` in (0, 1] (App. B.1)."""
    cdf = np.cumsum(w)
    cdf[np.flatnonzero(w)[-1]:] = 1.0  # round-off must not push u past the last particle of weight > 0
    return np.searchsorted(cdf, u, side="left")


def _open_closed(rng, size) -> np.ndarray:
    """Standard uniforms on (0, 1]."""
    return 1.0 - rng.random(size)


def multinomial(weights, rng: np.random.Generator) -> Resampled:
    """Multinomial resampling (App. B.1): ``M`` independent uniforms through the weight CDF."""
    w = _normalise(weights)
    return _uniform(np.sort(_invert_cdf(w, _open_closed(rng, len(w)))))


def stratified(weights, rng: np.random.Generator) -> Resampled:
    """Stratified resampling (App. B.1): one uniform in each stratum ``((j−1)/M, j/M]``."""
    w = _normalise(weights)
    m = len(w)
    return _uniform(_invert_cdf(w, (np.arange(m) + _open_closed(rng, m)) / m))


def systematic(weights, rng: np.random.Generator) -> Resampled:
    """Systematic resampling (App. B.1): ``u_j = u_1 + (j−1)/M`` with one ``u_1 ~ U(0, 1/M]``."""
    w = _normalise(weights)
    m = len(w)
    return _uniform(_invert_cdf(w, (np.arange(m) + _open_closed(rng, 1)) / m))


def residual(weights, rng: np.random.Generator) -> Resampled:
    """Residual resampling (App. B.1): ``⌊M w_m⌋`` copies, then ``R = M − Σ⌊M w⌋`` multinomial
    draws with probabilities proportional to the residuals ``M w_m − ⌊M w_m⌋``."""
    w = _normalise(weights)
    m = len(w)
    scaled, base = _floor_copies(w)
    base = base.astype(np.intp)
    rest = m - base.sum()
    if rest > 0:
        residuals = _normalise(np.maximum(scaled - base, 0.0))
        extra = np.bincount(_invert_cdf(residuals, _open_closed(rng, rest)), minlength=m)
        base = base + extra
    return _from_counts(base)


def residual_systematic(weights, rng: np.random.Generator) -> Resampled:
    """Residual-systematic resampling (App. B.2, Bolić et al. 2003).

    The sequential scheme carries the fractional part ``Δu`` from particle to particle,
    ``n_m = ⌊M (w_m − Δu_{m−1})⌋ + 1``, ``Δu_m = Δu_{m−1} + n_m/M − w_m``, from one
    ``Δu_0 ~ U[0, 1/M)``. Unrolled, ``n_m`` is the number of points ``Δu_0 + k/M`` in
    ``[C_{m−1}, C_m)`` (``C`` the cumulative weights), which is evaluated here in closed form.
    """
    w = _normalise(weights)
    m = len(w)
    u0 = rng.random() / m
    cdf = np.concatenate([[0.0], np.cumsum(w)])
    cdf[-1] = 1.0
    points_below = np.clip(np.ceil(m * (cdf - u0)), 0, m).astype(np.intp)  # #{k: u0 + k/M < C}
    return _from_counts(np.diff(points_below))


def branch_kill(weights, rng: np.random.Generator) -> Resampled:
    """Branch-kill (branching) resampling (App. B.2): ``⌊M w_m⌋ + 1`` copies with probability
    ``p = M w_m − ⌊M w_m⌋``, else ``⌊M w_m⌋``, independently per particle.

    The number of copies ``M_out`` is random (expected value ``M``); each weighs ``1/M_out``.
    """
    w = _normalise(weights)
    scaled, base = _floor_copies(w)
    counts = (base + (rng.random(len(w)) < scaled - base)).astype(np.intp)
    return _from_counts(counts)


def optimal(weights, rng: np.random.Generator, size: int | None = None) -> Resampled:
    """Optimal resampling (App. B.2, Fearnhead & Clifford 2003) down to ``size`` particles.

    The threshold ``ℵ = 1/c`` solves ``Σ min(c w_m, 1) = size``; particles with ``w_m ≥ ℵ`` are
    kept once with their own weight, the others survive with probability ``c w_m`` (systematic
    draw, at most once each) and carry ``ℵ``. No particle is replicated, so with
    ``size >= #{w_m > 0}`` (the default ``size = M`` included) every particle with positive
    weight is kept as it is. Weights are returned unnormalised (their sum is 1 in expectation).
    """
    w = _normalise(weights)
    size = len(w) if size is None else int(size)
    if size < 1:
        raise ValueError("optimal resampling: size must be at least 1")
    positive = np.flatnonzero(w > 0.0)
    if size >= len(positive):
        return Resampled(positive, w[positive])
    # Solve for c: with weights sorted descending, keep the k largest whole and spread the rest.
    desc = np.sort(w)[::-1]
    tail = np.cumsum(desc[::-1])[::-1]  # tail[k] = Σ_{j≥k} desc_j
    k = np.arange(size)
    c = (size - k) / tail[k]  # c if exactly the k largest are kept whole
    # The first k whose next weight is not kept whole (then the k before it are: c·desc[k−1] ≥ 1).
    # Tested alone, with a round-off allowance: with tied weights both tests could fail at every
    # k by an ulp, and argmax of all-False took k = 0 (fewer particles than size came back). At
    # k = size − 1 the test holds, c·desc[k] = desc[k] / tail[k] ≤ 1.
    c = c[np.argmax(c * desc[k] <= 1.0 + 1e-12)]
    keep = c * w >= 1.0
    probs = np.where(keep, 0.0, c * w)
    cdf = np.concatenate([[0.0], np.cumsum(probs)])
    drawn = np.diff(np.floor(cdf - rng.random()).astype(np.intp)) > 0  # at most once: probs < 1
    chosen = np.flatnonzero(keep | drawn)
    carried = np.where(keep, w, 1.0 / c)[chosen]
    return Resampled(chosen, carried)


def reallocation(weights, rng: np.random.Generator) -> Resampled:
    """Reallocation resampling (App. B.2) with the fixed threshold ``ℵ = 1/M``.

    A particle with ``w_m ≥ ℵ`` gets ``⌊M w_m⌋`` copies of weight ``w_m / ⌊M w_m⌋``; a particle
    below ``ℵ`` survives once with probability ``M w_m`` and then carries ``ℵ``. The number of
    copies ``M_out`` is random and can exceed ``M`` (:func:`fixed_size` trims it); weights are
    returned unnormalised (their sum is 1 in expectation).
    """
    w = _normalise(weights)
    m = len(w)
    scaled, base = _floor_copies(w)
    big = base >= 1.0
    counts = np.where(big, base, rng.random(m) < scaled).astype(np.intp)
    carried = np.where(big, w / np.maximum(base, 1.0), 1.0 / m)
    return _from_counts(counts, carried)


def metropolis(weights, rng: np.random.Generator, steps: int = 32) -> Resampled:
    """Metropolis resampling (App. B.2, Murray 2016): for every particle at once, ``steps``
    (the search depth S) Metropolis–Hastings moves with a uniform proposal ``j`` accepted when
    ``u ≤ w_j / w_k``. Only ratios are used (no sum over weights); the copy counts are biased
    for finite ``steps``, the bias vanishing as ``(1 − 1/(M·max w))^steps``.
    """
    w = _normalise(weights)
    if steps < 1:
        raise ValueError("metropolis resampling: steps must be at least 1")
    m = len(w)
    k = np.arange(m)
    positive = np.flatnonzero(w > 0.0)
    k = np.where(w > 0.0, k, positive[k % len(positive)])  # no chain starts on a zero weight
    for _ in range(steps):
        j = rng.integers(0, m, size=m)
        accept = (rng.random(m) * w[k] <= w[j]) & (w[j] > 0.0)  # a zero-weight particle is never taken
        k = np.where(accept, j, k)
    return _uniform(k)


def minimum_sampling(weights, rng: np.random.Generator) -> Resampled:
    """Minimum sampling (App. B.2): ``⌊M w_m⌋`` copies each, then one more copy for each of the
    ``M − Σ⌊M w⌋`` largest residuals ``M w_m − ⌊M w_m⌋`` (ties to the lower index).

    Deterministic: ``rng`` is not used, and counts are ``M w_m`` rounded to a neighbouring integer.
    """
    del rng
    w = _normalise(weights)
    m = len(w)
    scaled, counts = _floor_copies(w)
    counts = counts.astype(np.intp)
    rest = m - counts.sum()
    counts[np.argsort(-(scaled - counts), kind="stable")[:rest]] += 1
    return _from_counts(counts)


RESAMPLERS = {
    "multinomial": multinomial,
    "stratified": stratified,
    "systematic": systematic,
    "residual": residual,
    "residual_systematic": residual_systematic,
    "branch_kill": branch_kill,
    "optimal": optimal,
    "reallocation": reallocation,
    "metropolis": metropolis,
    "minimum_sampling": minimum_sampling,
}


def resample(name: str, weights, rng: np.random.Generator, **options) -> Resampled:
    """Run the scheme ``name`` of :data:`RESAMPLERS`; ``options`` go to the scheme."""
    try:
        scheme = RESAMPLERS[name]
    except KeyError:
        raise ValueError(f"unknown resampling scheme {name!r}; known: {sorted(RESAMPLERS)}") from None
    return scheme(weights, rng, **options)


def fixed_size(result: Resampled, weights, rng: np.random.Generator, size: int) -> np.ndarray:
    """Ancestor indices of exactly ``size`` copies from a scheme whose count may differ.

    App. B does not say how the thesis kept ``M`` fixed under branch-kill, optimal and
    reallocation; here surplus copies are dropped uniformly at random and a shortfall is
    filled by systematic draws on ``weights``. The result is sorted.

    The copies' carried weights are not used, so two schemes are not unbiased in counts here:
    reallocation's shortfall (the fractions ``M w − ⌊M w⌋`` its heavy particles lose) is drawn
    from all the weights, so a particle of ``M w = 1.78`` gets 1.35 copies in expectation and
    light ones more than ``M w``; optimal resampling back to ``M`` keeps every particle of
    positive weight once, i.e. it does not resample (it reduces a set only when asked for fewer).
    Drawing the copies by their carried weight instead (unbiased) was measured in the tracker
    and not adopted (docs/tracking.md, "Reallocation's copy counts").
    """
    idx = result.indices
    if len(idx) > size:
        idx = idx[np.sort(rng.choice(len(idx), size=size, replace=False))]
    elif len(idx) < size:
        w = _normalise(weights)
        extra = _invert_cdf(w, (np.arange(size - len(idx)) + _open_closed(rng, 1)) / (size - len(idx)))
        idx = np.concatenate([idx, extra])
    return np.sort(idx)
