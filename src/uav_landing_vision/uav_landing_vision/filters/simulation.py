"""A simulated orientation track with heavy-tailed measurement noise, and the filters' scores on it.

The truth follows the filters' own model (3.12): ``q_{t+1} = q_t ⊗ Ω(ω_t) ⊗ Φ_t`` with
Bingham ``Φ_t`` (``process_z``) and a random-walk angular velocity. Measurements are
``q_t ⊗ Λ_t`` with Bingham ``Λ_t`` (``measurement_z``), except that a fraction are outliers: a
random rotation of ``outlier_deg`` range, or a 180° turn about a body axis (the symmetric-pose
confusions of §6.5). The first measurement, from which the filters start, is never an outlier.
"""

from dataclasses import dataclass, replace

import numpy as np
from scipy import stats

from ..geometry import geodesic_angle, omega_quat, quat_conjugate, quat_multiply, quat_normalise, rodrigues_from_quat
from . import bingham
from .motion import KINDS, MotionFilterConfig, make_rotation_filter


@dataclass(frozen=True)
class Scenario:
    """Simulation settings; ``runs`` independent tracks of ``steps`` frames."""

    runs: int = 40
    steps: int = 150
    outlier_prob: float = 0.08  # random large rotation errors
    outlier_deg: tuple[float, float] = (30.0, 120.0)
    flip_prob: float = 0.04  # 180° turns about a body axis
    warm_up: int = 10  # frames left out of the statistics

    def __post_init__(self):
        if self.runs < 1 or not 0 <= self.warm_up < self.steps:
            raise ValueError("need runs >= 1 and 0 <= warm_up < steps")
        if not (0 <= self.outlier_prob and 0 <= self.flip_prob and self.outlier_prob + self.flip_prob < 1):
            raise ValueError("outlier_prob and flip_prob must be non-negative with a sum below 1")
        if not 0 <= self.outlier_deg[0] <= self.outlier_deg[1] <= 180:
            raise ValueError(f"outlier_deg must be an ordered range within [0, 180], got {self.outlier_deg}")


def simulate(cfg: MotionFilterConfig, sc: Scenario, rng: np.random.Generator):
    """Truth ``(T, R, 4)``, measurements ``(T, R, 4)`` and outlier flags ``(T, R)``."""
    n, shape = sc.runs * sc.steps, (sc.steps, sc.runs)
    phi = bingham.sample(np.eye(4), np.asarray(cfg.process_z), n, rng).reshape(shape + (4,))
    lam = bingham.sample(np.eye(4), np.asarray(cfg.measurement_z), n, rng).reshape(shape + (4,))
    q = quat_normalise(rng.standard_normal((sc.runs, 4)))
    w = rng.normal(0.0, cfg.initial_omega_std, (sc.runs, 3))
    truth = np.empty(shape + (4,))
    for t in range(sc.steps):
        truth[t] = q
        q = quat_multiply(quat_multiply(q, omega_quat(w, cfg.dt)), phi[t])
        w = w + rng.normal(0.0, cfg.omega_process_std, w.shape)
    kind = rng.choice(3, size=shape, p=[1 - sc.outlier_prob - sc.flip_prob, sc.outlier_prob, sc.flip_prob])
    kind[0] = 0  # the filters start from this measurement, as the tracker's start from a boosted pose
    axis = quat_normalise(np.concatenate([rng.standard_normal(shape + (3,)), np.zeros(shape + (1,))], -1))
    angle = np.radians(rng.uniform(*sc.outlier_deg, size=shape))[..., None]
    big = np.concatenate([axis[..., :3] * np.sin(angle / 2), np.cos(angle / 2)], -1)
    flip = np.eye(4)[rng.integers(0, 3, size=shape)]  # 180° about body x, y or z
    err = np.where((kind == 1)[..., None], big, np.where((kind == 2)[..., None], flip, lam))
    return truth, quat_multiply(truth, err), kind > 0


def run_filters(cfg: MotionFilterConfig, truth, meas, kinds=KINDS) -> dict[str, dict[str, np.ndarray]]:
    """Errors (rad, ``(T, R)``) and NEES ``(T, R)`` of each filter on the measurements."""
    out = {}
    for kind in kinds:
        filt = make_rotation_filter(replace(cfg, rotation_filter=kind))
        state = filt.init(meas[0], np.zeros(meas.shape[1:2] + (3,)))
        err, nees = np.zeros(meas.shape[:2]), np.zeros(meas.shape[:2])
        for t in range(meas.shape[0]):
            if t > 0:
                state = filt.update(filt.predict(state), meas[t])
            q_est, _ = filt.estimate(state)
            e = rodrigues_from_quat(quat_multiply(quat_conjugate(q_est), truth[t]))
            nees[t] = np.einsum("ri,ri->r", e, np.linalg.solve(filt.covariance(state), e[..., None])[..., 0])
            err[t] = geodesic_angle(q_est, truth[t])
        out[kind] = {"error": err, "nees": nees}
    return out


# Smooth motion (Φ: ~1.8° per axis and frame) seen through coarse measurements (thesis Λ).
SIM_CONFIG = MotionFilterConfig(process_z=(-2000.0,) * 3, omega_process_std=0.3, initial_omega_std=1.0)


def compare(seed: int = 0, cfg: MotionFilterConfig = SIM_CONFIG, sc: Scenario = Scenario()) -> dict:
    """Rotation RMSE (deg) and mean NEES of each rotation filter on one seeded scenario.

    ``heavy``: the scenario as given (outliers included). ``nominal``: the same seed with the
    outliers off, where the truth follows the filters' model and NEES consistency is judged.
    ``nees_band`` is the 95 % band of a frame's NEES averaged over the ``runs`` independent
    runs, χ²(3R)/R; frames are correlated in time, so the band is applied to the mean over
    frames rather than shrunk by their number.
    """
    table = {"nees_band": (stats.chi2.ppf(0.025, 3 * sc.runs) / sc.runs, stats.chi2.ppf(0.975, 3 * sc.runs) / sc.runs)}
    for name, scenario in (("heavy", sc), ("nominal", replace(sc, outlier_prob=0.0, flip_prob=0.0))):
        truth, meas, _ = simulate(cfg, scenario, np.random.default_rng(seed))
        for kind, r in run_filters(cfg, truth, meas).items():
            e = np.degrees(r["error"][sc.warm_up:])
            table.setdefault(kind, {})[name] = {
                "rmse_deg": float(np.sqrt(np.mean(e**2))),
                "median_deg": float(np.median(e)),
                "mean_nees": float(np.mean(r["nees"][sc.warm_up:])),
            }
    return table
