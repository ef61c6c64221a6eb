"""Pose optimisation on one frame (§5.5): PFO, PSO, modified (constricted) PSO and GAbF.

An objective is ``score(ParticleSet) -> (M,)`` non-negative likelihoods, higher is better,
evaluated for the whole batch in one call (one batched render). Every optimiser calls it
once per iteration (GAbF may end before the last one) and returns a set whose weights are the
scores of its poses; the particles GAbF leaves as they came (beyond its ``B`` best, or a set of
one) keep the weights they came with, scores when the caller's are (as the tracker's).
Only poses change; velocities and per-particle filter state stay with their particle.

Rotations stay on the unit sphere: a pose increment is a body-frame rotation vector ``r``
applied as ``q ⊗ exp(r)`` (right composition, as (3.12)), and the difference of two
orientations is ``log(q_a⁻¹ ⊗ q_b)``, the rotation whose angle is the distance (5.20).
Noise values called covariances in Tables 6.6–6.8 are in metres and degrees; they are read
here as standard deviations, which is also what makes the constant ("Noise") schedule agree
with §6.7.1 (2.62 rad/s × 0.034 s ≈ 5.1° against Table 6.7's 5°).
"""

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

from ..filters.motion import MAX_STD
from ..filters.ukf import MAX_DT
from ..geometry import (
    euler_zyx_to_quat,
    geodesic_angle,
    omega_quat,
    quat_multiply,
    quat_normalise,
    quat_to_euler_zyx,
)
from .particles import ParticleSet
from .resampling import RESAMPLERS, fixed_size, resample

Objective = Callable[[ParticleSet], np.ndarray]
Vec3 = tuple[float, float, float]


def evaluate(score: Objective, particles: ParticleSet) -> np.ndarray:
    """One batched call of ``score``, checked: shape ``(M,)``, finite, non-negative."""
    w = np.asarray(score(particles), dtype=float)
    if w.shape != (len(particles),):
        raise ValueError(f"objective returned shape {w.shape}, expected ({len(particles)},)")
    if not np.all(np.isfinite(w)) or np.any(w < 0.0):
        raise ValueError("objective must return finite, non-negative likelihoods")
    return w


def rotate_body(quat: np.ndarray, rotvec: np.ndarray) -> np.ndarray:
    """``q ⊗ exp(r)``: ``q`` turned by the body-frame rotation vector ``r`` (Ω of (3.14) over 1 s)."""
    return quat_normalise(quat_multiply(quat, omega_quat(rotvec, 1.0)))


def rotvec_between(q_from: np.ndarray, q_to: np.ndarray) -> np.ndarray:
    """Body-frame rotation vector ``log(q_from⁻¹ ⊗ q_to)``; its norm is the angle (5.20)."""
    rel = Rotation.from_quat(np.reshape(q_from, (-1, 4))).inv() * Rotation.from_quat(np.reshape(q_to, (-1, 4)))
    return rel.as_rotvec().reshape(np.shape(q_to)[:-1] + (3,))


def _jitter(particles: ParticleSet, trans_sigma, rot_sigma, rng: np.random.Generator) -> tuple:
    """Poses plus zero-mean Gaussian noise: per-axis σ in metres and, on rotation, in radians."""
    m = len(particles)
    pos = particles.pos + rng.normal(size=(m, 3)) * np.asarray(trans_sigma)
    quat = rotate_body(particles.quat, rng.normal(size=(m, 3)) * np.asarray(rot_sigma))
    return pos, quat


def _check_iterations(iterations: int) -> None:
    if int(iterations) < 1:
        raise ValueError("optimisation needs at least one iteration")


def _positive(name: str, values, high: float = np.inf) -> None:
    values = np.asarray(values, dtype=float)
    if not np.all((values > 0.0) & (values <= high)):
        raise ValueError(f"{name} must be positive" + (f" and at most {high:g}" if high < np.inf else ""))


# --- PFO (Algorithm 8, Tables 6.6-6.7) ------------------------------------------------------

THREE_PHASE_TRANS_M = ((0.05, 0.05, 0.01), (0.035, 0.035, 0.005), (0.0025, 0.0025, 0.0025))  # Table 6.6
THREE_PHASE_ROT_DEG = (15.0, 7.0, 4.0)  # Table 6.7
ITERATIVE_TRANS_M = (0.005, 0.005, 0.005)  # Table 6.6
ITERATIVE_ROT_START_DEG = 18.0  # Table 6.7: 18 − I at iteration I
ITERATIVE_ROT_MIN_DEG = 1.0  # the thesis gives no floor; never reached for N <= 17


@dataclass(frozen=True)
class PFOConfig:
    """PFO settings; the "noise" values default to the tracker's (§6.7.1).

    ``reference_depth_m`` (ours; 0 = thesis): the translation σ of every schedule is multiplied
    by each particle's depth / this. A fixed σ in metres is a fixed fraction of the range only at
    one range: at 80 m, 0.2 m in depth changes a 25 px UAV by 0.06 px, so the optimisation
    cannot correct a 5 % depth error, while near the ship the same σ is a large step.
    """

    schedule: Literal["noise", "3phase", "iterative"] = "noise"
    resampling: str = "reallocation"  # App. B scheme, the tracker's default (§6.7.1)
    dt: float = 0.034  # Δt over which the angular-rate noise is integrated
    noise_trans_sigma_m: Vec3 = (0.1, 0.1, 0.2)  # constant schedule, per axis X, Y, Z
    noise_rate_sigma: Vec3 = (2.62, 2.62, 2.62)  # constant schedule, rad/s per body axis
    phase_length: int = 3  # n of the 3Phase schedule (§6.6.1)
    reference_depth_m: float = 0.0  # ours, 0 = thesis: translation σ scaled by depth / this

    def __post_init__(self):
        if not (np.isfinite(self.reference_depth_m) and self.reference_depth_m >= 0.0):
            raise ValueError("pfo.reference_depth_m must be non-negative")
        if self.schedule not in ("noise", "3phase", "iterative"):
            raise ValueError(f"pfo.schedule: unknown {self.schedule!r}")
        if self.resampling not in RESAMPLERS:
            raise ValueError(f"pfo.resampling: unknown {self.resampling!r}; known: {sorted(RESAMPLERS)}")
        _positive("pfo.dt", self.dt, MAX_DT)
        _positive("pfo.noise_trans_sigma_m", self.noise_trans_sigma_m, MAX_STD)  # beyond, the draws overflow
        _positive("pfo.noise_rate_sigma", self.noise_rate_sigma, MAX_STD)
        if self.phase_length < 1:
            raise ValueError("pfo.phase_length must be at least 1")


SECTION_6_6_NOISE = PFOConfig(
    schedule="noise",
    noise_trans_sigma_m=(0.05, 0.05, 0.01),  # Table 6.6, "Noise"
    noise_rate_sigma=(np.radians(5.0) / 0.034,) * 3,  # Table 6.7, "Noise": 5° per iteration
)


def pfo_noise(config: PFOConfig, iteration: int) -> tuple[np.ndarray, np.ndarray]:
    """σ of the artificial noise ζ (5.18) at PFO iteration ``I`` (1-based): translation (3,) in
    metres and body angular rate (3,) in rad/s, the latter integrated over ``config.dt``.

    "noise": constant; "3phase": the three rows of Tables 6.6–6.7, ``n = phase_length``
    iterations each, the third for all remaining iterations (``N = 10``: 3 + 3 + 4);
    "iterative": 0.005 m and ``18 − I`` degrees (Table 6.7).
    """
    if config.schedule == "noise":
        return np.array(config.noise_trans_sigma_m), np.array(config.noise_rate_sigma)
    if config.schedule == "3phase":
        phase = min((iteration - 1) // config.phase_length, 2)
        trans, rot_deg = THREE_PHASE_TRANS_M[phase], THREE_PHASE_ROT_DEG[phase]
    else:
        trans, rot_deg = ITERATIVE_TRANS_M, max(ITERATIVE_ROT_START_DEG - iteration, ITERATIVE_ROT_MIN_DEG)
    return np.array(trans), np.full(3, np.radians(rot_deg) / config.dt)


class PFO:
    """Particle filter optimisation (Algorithm 8) iterated on one frame."""

    def __init__(self, config: PFOConfig = PFOConfig()):
        self.config = config

    def run(self, particles: ParticleSet, score: Objective, rng: np.random.Generator, iterations: int) -> ParticleSet:
        """Per iteration: add ζ (5.18), weight (one objective call), resample back to ``M``.

        The result holds the resampled copies, each weighted by its own score. If every score
        is zero the moved particles are kept, one copy each (there is nothing to resample on).
        """
        _check_iterations(iterations)
        cfg, m, current = self.config, len(particles), particles
        for k in range(1, iterations + 1):
            trans_sigma, rate_sigma = pfo_noise(cfg, k)
            if cfg.reference_depth_m > 0.0:
                trans_sigma = trans_sigma * np.abs(current.pos[:, 2:3]) / cfg.reference_depth_m
            pos = current.pos + rng.normal(size=(m, 3)) * trans_sigma
            quat = quat_multiply(current.quat, omega_quat(rng.normal(size=(m, 3)) * rate_sigma, cfg.dt))
            current = current.with_pose(pos, quat_normalise(quat))
            w = evaluate(score, current)
            if w.sum() > 0.0:
                idx = fixed_size(resample(cfg.resampling, w, rng), w, rng, m)
            else:
                idx = np.arange(m)
            current = current.take(idx, weight=w[idx])
        return current


# --- PSO (Algorithm 9, (5.19)-(5.20)) and modified PSO ((5.21)-(5.22)) -----------------------


def neighbourhood_distance(pos: np.ndarray, quat: np.ndarray, sensitivity: float) -> np.ndarray:
    """Pairwise ``d = δ/180·ς + v`` (5.19): δ the rotation distance (5.20) in degrees, v the
    translation distance in metres; ``(M, M)``."""
    delta = np.degrees(geodesic_angle(quat[:, None, :], quat[None, :, :]))
    v = np.linalg.norm(pos[:, None, :] - pos[None, :, :], axis=-1)
    return delta / 180.0 * sensitivity + v


@dataclass(frozen=True)
class PSOConfig:
    """Algorithm 9. The thesis gives ς = 5 (§6.6.1) only; the other defaults are ours:
    ϖ, c1, c2 of Clerc's standard PSO and a neighbourhood of the 10 nearest under (5.19)."""

    inertia: float = 0.7298  # ϖ
    c1: float = 1.49618  # towards the particle's own best
    c2: float = 1.49618  # towards its neighbourhood's best
    sensitivity: float = 5.0  # ς of (5.19)
    neighbours: int = 10  # neighbourhood size, the particle included

    def __post_init__(self):
        if not 0.0 <= self.inertia < 1.0:
            raise ValueError("pso.inertia must be in [0, 1)")
        _positive("pso.c1, pso.c2, pso.sensitivity", (self.c1, self.c2, self.sensitivity))
        if self.neighbours < 1:
            raise ValueError("pso.neighbours must be at least 1")


@dataclass(frozen=True)
class ConstrictedPSOConfig:
    """Modified PSO (§5.5.3): k = 1 (§6.6.1); c1 = c2 = 2.05 (φ = 4.1, Γ ≈ 0.7298) are ours."""

    c1: float = 2.05
    c2: float = 2.05
    k: float = 1.0
    sensitivity: float = 5.0
    neighbours: int = 10

    def __post_init__(self):
        if not 0.0 < self.k <= 1.0:
            raise ValueError("constricted_pso.k must be in (0, 1]")
        _positive("constricted_pso.c1, c2, sensitivity", (self.c1, self.c2, self.sensitivity))
        if self.c1 + self.c2 <= 4.0:
            raise ValueError("constricted_pso: (5.22) needs φ = c1 + c2 > 4")
        if self.neighbours < 1:
            raise ValueError("constricted_pso.neighbours must be at least 1")

    @property
    def gamma(self) -> float:
        """Constriction coefficient Γ (5.22)."""
        phi = self.c1 + self.c2
        return 2.0 * self.k / abs(2.0 - phi - np.sqrt(phi * (phi - 4.0)))


def _difference(pos, quat, target_pos, target_quat) -> np.ndarray:
    """``p_target − p`` in the 6-D tangent space: translation and body rotation vector."""
    return np.concatenate([target_pos - pos, rotvec_between(quat, target_quat)], axis=1)


class PSO:
    """Particle swarm optimisation (Algorithm 9) with the (5.19) neighbourhood.

    A particle's PSO velocity ``ϑ`` is 6-D: metres and a body-frame rotation vector, applied as
    ``u + ϑ_t`` and ``q ⊗ exp(ϑ_r)``. Since ``exp(ϑ_r)`` leaves ``ϑ_r`` unchanged, the inertia
    term is already expressed in the new body frame. The result is each particle's best pose
    so far, weighted by its score, so the best score never decreases.
    """

    def __init__(self, config: PSOConfig = PSOConfig()):
        self.config = config

    def _velocity(self, previous, to_best, to_neigh, rng) -> np.ndarray:
        c = self.config
        r1, r2 = rng.random(previous.shape), rng.random(previous.shape)
        return c.inertia * previous + c.c1 * r1 * to_best + c.c2 * r2 * to_neigh

    def run(self, particles: ParticleSet, score: Objective, rng: np.random.Generator, iterations: int) -> ParticleSet:
        _check_iterations(iterations)
        m = len(particles)
        k = min(self.config.neighbours, m)
        current, best = particles, None
        velocity = np.zeros((m, 6))
        for _ in range(iterations):
            w = evaluate(score, current)
            if best is None:
                best = current.with_weight(w)
            else:
                better = w > best.weight
                best = best.with_pose(
                    np.where(better[:, None], current.pos, best.pos), np.where(better[:, None], current.quat, best.quat)
                ).with_weight(np.where(better, w, best.weight))
            dist = neighbourhood_distance(current.pos, current.quat, self.config.sensitivity)
            near = np.argpartition(dist, k - 1, axis=1)[:, :k]
            neigh = near[np.arange(m), np.argmax(best.weight[near], axis=1)]
            to_best = _difference(current.pos, current.quat, best.pos, best.quat)
            to_neigh = _difference(current.pos, current.quat, best.pos[neigh], best.quat[neigh])
            velocity = self._velocity(velocity, to_best, to_neigh, rng)
            current = current.with_pose(current.pos + velocity[:, :3], rotate_body(current.quat, velocity[:, 3:]))
        return best


class ConstrictedPSO(PSO):
    """Modified PSO (§5.5.3): velocity (5.21) with constriction Γ (5.22).

    Where ``p_best − p`` and ``p_neigh − p`` have the same sign in all six dimensions, r1 and
    r2 are Gaussian "between zero and one" — read here as ``min(|N(0, 1)|, 1)``, larger on
    average than the uniform draw used otherwise, which gives the jumps the thesis wants.
    """

    def __init__(self, config: ConstrictedPSOConfig = ConstrictedPSOConfig()):
        self.config = config

    def _velocity(self, previous, to_best, to_neigh, rng) -> np.ndarray:
        c = self.config
        same = np.all(np.sign(to_best) == np.sign(to_neigh), axis=1, keepdims=True)
        gauss = np.minimum(np.abs(rng.normal(size=(2,) + previous.shape)), 1.0)
        r1, r2 = np.where(same, gauss, rng.random((2,) + previous.shape))
        return c.gamma * (previous + c.c1 * r1 * to_best + c.c2 * r2 * to_neigh)


# --- GAbF (Algorithm 10, Table 6.8) ----------------------------------------------------------

BOOTSTRAP, COARSE, FINE = "bootstrap", "coarse", "fine"


@dataclass(frozen=True)
class GAbFConfig:
    """Algorithm 10 with Table 6.8. δ, T_min and T_coarse are in the objective's units (the
    thesis's colour metric lies in [0, 1]). Σ_best_coarse / Σ_best_fine are not in the table;
    their defaults are ours. Step limits and restarts follow §5.5.4."""

    delta: float = 0.1  # δ: bootstrap replaces particles scoring below it
    top_a: int = 3  # A
    top_b: int = 100  # B: the B best input particles are optimised
    t_min: float = 0.2  # T_min
    t_coarse: float = 0.3  # T_coarse
    init_sigma_m: Vec3 = (0.1, 0.1, 0.1)
    init_sigma_deg: Vec3 = (8.0, 8.0, 8.0)
    bootstrap_sigma_m: Vec3 = (0.1, 0.1, 0.1)
    bootstrap_sigma_deg: Vec3 = (5.0, 5.0, 5.0)
    coarse_sigma_m: Vec3 = (0.25, 0.25, 0.25)
    coarse_sigma_deg: Vec3 = (25.0, 25.0, 25.0)
    fine_sigma_m: Vec3 = (0.15, 0.15, 0.15)
    fine_sigma_deg: Vec3 = (15.0, 15.0, 15.0)
    best_coarse_sigma_m: Vec3 = (0.1, 0.1, 0.1)
    best_coarse_sigma_deg: Vec3 = (5.0, 5.0, 5.0)
    best_fine_sigma_m: Vec3 = (0.05, 0.05, 0.05)
    best_fine_sigma_deg: Vec3 = (2.5, 2.5, 2.5)
    bootstrap_steps: int = 10  # then the bootstrap restarts
    coarse_steps: int = 10  # then back to bootstrap
    fine_steps: int = 5  # then done
    max_restarts: int = 3

    def __post_init__(self):
        if not (self.delta >= 0.0 and 0.0 <= self.t_min < self.t_coarse):
            raise ValueError("gabf: need delta >= 0 and 0 <= t_min < t_coarse")
        if self.top_a < 2 or self.top_b < 2:
            raise ValueError("gabf: top_a and top_b must be at least 2 (crossover needs two parents)")
        for name in ("init", "bootstrap", "coarse", "fine", "best_coarse", "best_fine"):
            _positive(f"gabf.{name}_sigma_m", getattr(self, f"{name}_sigma_m"))
            _positive(f"gabf.{name}_sigma_deg", getattr(self, f"{name}_sigma_deg"))
        if min(self.bootstrap_steps, self.coarse_steps, self.fine_steps) < 1 or self.max_restarts < 0:
            raise ValueError("gabf: step limits must be at least 1 and max_restarts non-negative")

    def sigmas(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(metres, radians) of the noise ``name`` (init, bootstrap, coarse, fine, best_*)."""
        return np.array(getattr(self, f"{name}_sigma_m")), np.radians(getattr(self, f"{name}_sigma_deg"))


def _top(particles: ParticleSet, count: int, distinct: bool = False) -> ParticleSet:
    """The ``count`` highest-weight particles, best first; with ``distinct`` each pose once
    (Top A must not hold one pose twice, or crossover would mate it with itself)."""
    candidates = np.arange(len(particles))
    if distinct:
        _, candidates = np.unique(np.hstack([particles.pos, particles.quat]), axis=0, return_index=True)
    return particles.take(candidates[np.argsort(-particles.weight[candidates], kind="stable")][:count])


def crossover(a_pos, a_quat, b_pos, b_quat, count: int, rng: np.random.Generator) -> tuple:
    """``count`` children taking each attribute X, Y, Z, α, β, γ (Z-Y-X Euler (3.1)) at random
    from parent ``a`` or parent ``b`` (§5.5.4)."""
    parents = np.stack(
        [np.concatenate([a_pos, quat_to_euler_zyx(a_quat)]), np.concatenate([b_pos, quat_to_euler_zyx(b_quat)])]
    )
    genes = parents[rng.integers(0, 2, size=(count, 6)), np.arange(6)]
    return genes[:, :3], euler_zyx_to_quat(genes[:, 3:])


class GAbF:
    """Genetic-algorithm-based framework (Algorithm 10): bootstrap → coarse → fine.

    One loop of Algorithm 10 per iteration: score the population (one objective call), update
    Top A, pick the phase from the two best of Top A against T_min / T_coarse, then move:
    bootstrap step 0 replaces particles scoring below δ by a Top A member plus Σ_init noise;
    later bootstrap steps add Σ_bootstrap noise to all; coarse and fine perturb the population's
    best (Σ_best_*) and replace the others by crossover of the two best of Top A, half of them
    mutated (Σ_coarse / Σ_fine). A bootstrap or coarse phase that overstays its step limit
    restarts the bootstrap with Top A rebuilt from the current population (up to
    ``max_restarts`` times); ``fine_steps`` fine moves end the run, as does the iteration budget.
    The result is the last population (the ``B`` best input particles) with its worst members
    replaced by the best ``A`` poses ever scored, weighted by their scores, followed by the input
    particles beyond the ``B`` best as they came (so the set keeps its size). A set of fewer than
    two particles, which crossover cannot work on, is returned as it came.
    """

    def __init__(self, config: GAbFConfig = GAbFConfig()):
        self.config = config

    def _phase(self, top: ParticleSet) -> str:
        if len(top) < 2:  # a single distinct pose so far: nothing to cross over yet
            return BOOTSTRAP
        second = top.weight[1]
        return FINE if second > self.config.t_coarse else COARSE if second > self.config.t_min else BOOTSTRAP

    def _limit(self, phase: str) -> int:
        return self.config.bootstrap_steps if phase == BOOTSTRAP else self.config.coarse_steps

    def run(self, particles: ParticleSet, score: Objective, rng: np.random.Generator, iterations: int) -> ParticleSet:
        _check_iterations(iterations)
        cfg = self.config
        if len(particles) < 2:
            return particles
        order = np.argsort(-particles.weight, kind="stable")
        pop, rest = particles.take(order[: cfg.top_b]), particles.take(order[cfg.top_b:])
        a = min(cfg.top_a, len(pop))
        top = elite = None
        phase, step, restarts = BOOTSTRAP, 0, 0
        for it in range(iterations):
            pop = pop.with_weight(evaluate(score, pop))
            elite = _top(pop if elite is None else ParticleSet.concat([elite, pop]), a, distinct=True)
            top = _top(pop if top is None else ParticleSet.concat([top, pop]), a, distinct=True)
            if self._phase(top) != phase:
                phase, step = self._phase(top), 0
            elif phase == FINE and step >= cfg.fine_steps:
                break
            elif phase != FINE and step >= self._limit(phase) and restarts < cfg.max_restarts:
                restarts, top = restarts + 1, _top(pop, a, distinct=True)
                phase, step = BOOTSTRAP, 0
            if it == iterations - 1:
                break
            pop = self._move(pop, top, phase, step, rng)
            step += 1
        keep = _top(pop, len(pop) - len(elite))
        return ParticleSet.concat([keep, elite, rest])

    def _move(self, pop: ParticleSet, top: ParticleSet, phase: str, step: int, rng) -> ParticleSet:
        cfg, m = self.config, len(pop)
        if phase == BOOTSTRAP and step == 0:
            low = pop.weight < cfg.delta
            pos, quat = _jitter(top.take(rng.integers(0, len(top), size=m)), *cfg.sigmas("init"), rng)
            return pop.with_pose(np.where(low[:, None], pos, pop.pos), np.where(low[:, None], quat, pop.quat))
        if phase == BOOTSTRAP:
            return pop.with_pose(*_jitter(pop, *cfg.sigmas("bootstrap"), rng))
        best = pop.best_index()
        pos, quat = crossover(top.pos[0], top.quat[0], top.pos[1], top.quat[1], m, rng)
        mutate = rng.permutation(m)[: m // 2]
        mpos, mquat = _jitter(pop.with_pose(pos, quat).take(mutate), *cfg.sigmas(phase), rng)
        pos[mutate], quat[mutate] = mpos, mquat
        bpos, bquat = _jitter(pop.take([best]), *cfg.sigmas(f"best_{phase}"), rng)
        pos[best], quat[best] = bpos[0], bquat[0]
        return pop.with_pose(pos, quat)


OPTIMISERS = {"pfo": PFO, "pso": PSO, "constricted_pso": ConstrictedPSO, "gabf": GAbF}  # §5.5


def make_optimiser(name: str, pfo: PFOConfig):
    """The optimiser ``name`` (a key of :data:`OPTIMISERS`): PFO with ``pfo``, the others with
    their own settings."""
    return PFO(pfo) if name == "pfo" else OPTIMISERS[name]()
