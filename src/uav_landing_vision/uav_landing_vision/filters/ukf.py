"""Unscented Kalman filters of Appendix A, vectorised over a batch of M filters.

:class:`TranslationUKF` runs the constant-velocity model (A.1)–(A.2) on ``[position,
velocity]``; :class:`RotationUKF` the error-Rodrigues model (A.3)–(A.9) on ``[d, ω]`` about a
reference quaternion, reset after every update. Both use the sigma points, prediction and
update of (A.12)–(A.30). As (A.12) says, the process noise ``Q`` is added to ``P`` *before*
the sigma points are drawn and then goes through the model (so a linear model adds
``F Q Fᵀ``). Sums over sigma points run over ``i = 0..2n`` (A.23 prints ``1..2n``).
"""

from dataclasses import dataclass

import numpy as np

from ..geometry import (
    omega_quat,
    quat_canonical,
    quat_conjugate,
    quat_from_rodrigues,
    quat_multiply,
    rodrigues_from_quat,
)
from . import outliers

MAX_DT = 10.0  # s: the longest frame interval a motion model is stepped over
MAX_BETA_KAPPA = 100.0  # beyond, the sigma points' covariance weights overflow the filters (1e60: singular)


@dataclass(frozen=True)
class UnscentedParams:
    """Sigma-point parameters: ``alpha`` (0, 1], ``beta`` ≥ 0, ``kappa`` ≥ 0 (A.13), (A.21)."""

    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0

    def __post_init__(self):
        if not 0.0 < self.alpha <= 1.0:
            raise ValueError(f"alpha must be in (0, 1], got {self.alpha}")
        if not (0.0 <= self.beta <= MAX_BETA_KAPPA and 0.0 <= self.kappa <= MAX_BETA_KAPPA):
            raise ValueError(f"beta and kappa must be within 0 to {MAX_BETA_KAPPA:g}, got {self.beta}, {self.kappa}")

    def weights(self, n: int) -> tuple[np.ndarray, np.ndarray, float]:
        """Mean and covariance weights (A.17), (A.18), (A.21) and the scale ι (A.13)."""
        iota = self.alpha**2 * (n + self.kappa)
        lam = iota - n
        wm = np.full(2 * n + 1, 1.0 / (2.0 * iota))
        wm[0] = lam / iota
        wc = wm.copy()
        wc[0] += 1.0 - self.alpha**2 + self.beta
        return wm, wc, iota


def sigma_points(x: np.ndarray, p: np.ndarray, iota: float) -> np.ndarray:
    """Sigma points ``(..., 2n+1, n)``: ``x`` and ``x ± cols(√(ι P))`` (A.12), (A.14)."""
    root = np.linalg.cholesky(iota * p)
    offsets = np.swapaxes(root, -1, -2)
    return np.concatenate([x[..., None, :], x[..., None, :] + offsets, x[..., None, :] - offsets], axis=-2)


def unscented_moments(points: np.ndarray, wm: np.ndarray, wc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean (A.16) and covariance (A.19)–(A.20) of sigma points ``(..., k, n)``.

    The weights are ``(k,)`` or one set per filter, ``(..., k)``.
    """
    mean = (wm[..., None, :] @ points)[..., 0, :]
    return mean, _cross(points - mean[..., None, :], points - mean[..., None, :], wc)


def _cross(dx: np.ndarray, dz: np.ndarray, wc: np.ndarray) -> np.ndarray:
    """``Σ_k wc_k dx_k dz_kᵀ``."""
    return np.swapaxes(dx * wc[..., :, None], -1, -2) @ dz


def kalman_update(x_sig, x_mean, p_xx, z_sig, z, r, wm, wc):
    """Measurement update (A.23)–(A.30): the posterior mean and covariance, the innovation ``ν``
    (A.25) and its covariance (A.26).

    ``r`` is the measurement noise added to ``P_zz`` in (A.26), fixed or one per filter.
    """
    z_mean, p_zz = unscented_moments(z_sig, wm, wc)  # (A.23), (A.24)
    nu = z - z_mean  # (A.25)
    p_nn = p_zz + r  # (A.26)
    p_xz = _cross(x_sig - x_mean[..., None, :], z_sig - z_mean[..., None, :], wc)  # (A.27)
    gain = np.swapaxes(np.linalg.solve(p_nn, np.swapaxes(p_xz, -1, -2)), -1, -2)  # (A.28)
    x = x_mean + np.einsum("...ij,...j->...i", gain, nu)  # (A.29)
    p = p_xx - gain @ p_nn @ np.swapaxes(gain, -1, -2)  # (A.30)
    return x, 0.5 * (p + np.swapaxes(p, -1, -2)), nu, p_nn


def take_filters(state, idx):
    """The filters ``idx`` of a batched state dataclass (e.g. after resampling)."""
    return type(state)(**{k: (None if v is None else v[idx]) for k, v in vars(state).items()})


def concat_filters(states):
    """One batched state from several of the same type (e.g. kept and freshly boosted particles).

    Predicted sigma points are kept only when every part has them; otherwise the update
    draws them again from the covariance.
    """
    fields = vars(states[0]).keys()
    return type(states[0])(**{
        k: None if any(vars(s)[k] is None for s in states) else np.concatenate([vars(s)[k] for s in states])
        for k in fields
    })


@dataclass(frozen=True)
class UKFState:
    """Batched Gaussian state: mean ``x (M, n)``, covariance ``p (M, n, n)``, predicted sigmas."""

    x: np.ndarray
    p: np.ndarray
    sigmas: np.ndarray | None = None  # (M, 2n+1, n) after predict, consumed by update

    def take(self, idx) -> "UKFState":
        """The filters ``idx`` (e.g. after resampling)."""
        return take_filters(self, idx)


class TranslationUKF:
    """Constant-velocity UKF on ``t = [X, Y, Z, v_x, v_y, v_z]`` (A.1)–(A.2), observing the position."""

    def __init__(self, dt: float, process_cov, measurement_cov, params: UnscentedParams = UnscentedParams()):
        self.q = spd_matrix(process_cov, 6, "process_cov")
        self.r = spd_matrix(measurement_cov, 3, "measurement_cov")
        self.f = np.block([[np.eye(3), check_dt(dt) * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])  # (A.2)
        self.wm, self.wc, self.iota = params.weights(6)

    def init(self, pos: np.ndarray, vel: np.ndarray, cov) -> UKFState:
        """Filters at ``pos (M, 3)``, ``vel (M, 3)`` with initial covariance ``cov (6, 6)``."""
        x = np.concatenate([pos, vel], axis=-1).astype(float)
        return UKFState(x, np.broadcast_to(spd_matrix(cov, 6, "cov"), x.shape[:-1] + (6, 6)).copy())

    def predict(self, s: UKFState) -> UKFState:
        """Prediction (A.12)–(A.21) through the model (A.2)."""
        sig = sigma_points(s.x, s.p + self.q, self.iota) @ self.f.T  # (A.15)
        x, p = unscented_moments(sig, self.wm, self.wc)
        return UKFState(x, p, sig)

    def update(self, s: UKFState, z: np.ndarray, r: np.ndarray | None = None) -> UKFState:
        """Update (A.22)–(A.30) with measured positions ``z (M, 3)`` or ``(3,)``; ``r``: this
        measurement's covariance instead of the filter's R."""
        sig = s.sigmas if s.sigmas is not None else sigma_points(s.x, s.p, self.iota)
        r = self.r if r is None else r
        x, p, _, _ = kalman_update(sig, s.x, s.p, sig[..., :3], np.asarray(z, float), r, self.wm, self.wc)
        return UKFState(x, p)


@dataclass(frozen=True)
class RotationUKFState:
    """Reference quaternion ``q (M, 4)``, error state ``x = [d, ω] (M, 6)`` and ``p (M, 6, 6)``."""

    q: np.ndarray
    x: np.ndarray
    p: np.ndarray
    sigmas: np.ndarray | None = None

    def take(self, idx) -> "RotationUKFState":
        return take_filters(self, idx)


class RotationUKF:
    """UKF on error generalised Rodrigues parameters and angular velocity (A.3)–(A.9).

    ``outlier_prob`` > 0 makes the update outlier-aware (:mod:`.outliers`; 0 is the thesis's).
    """

    def __init__(self, dt: float, process_cov, measurement_cov, params: UnscentedParams = UnscentedParams(),
                 outlier_prob: float = 0.0):
        self.dt = check_dt(dt)
        self.outlier_prob = outliers.check_outlier_prob(outlier_prob)
        self.q = spd_matrix(process_cov, 6, "process_cov")  # Q^a = diag(Q^r, Q^ω) (A.9)
        self.r = spd_matrix(measurement_cov, 3, "measurement_cov")
        self.wm, self.wc, self.iota = params.weights(6)

    def init(self, quat: np.ndarray, omega: np.ndarray, cov) -> RotationUKFState:
        """Filters at ``quat (M, 4)``, ``omega (M, 3)`` with initial covariance ``cov (6, 6)``."""
        x = np.concatenate([np.zeros_like(omega, dtype=float), omega], axis=-1)
        p = np.broadcast_to(spd_matrix(cov, 6, "cov"), x.shape[:-1] + (6, 6)).copy()
        return RotationUKFState(quat_canonical(np.asarray(quat, float)), x, p)

    def propagate(self, q_ref: np.ndarray, sig: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Model (A.3), (A.8) on sigma points ``[d, ω]``: the new reference and the new points."""
        quats = quat_multiply(quat_multiply(q_ref[..., None, :], quat_from_rodrigues(sig[..., :3])),
                              omega_quat(sig[..., 3:], self.dt))
        ref = quats[..., 0, :]
        d = rodrigues_from_quat(quat_multiply(quat_conjugate(ref)[..., None, :], quats))
        return ref, np.concatenate([d, sig[..., 3:]], axis=-1)

    def predict(self, s: RotationUKFState) -> RotationUKFState:
        """Prediction (A.12)–(A.21); the reference moves with the central sigma point."""
        ref, sig = self.propagate(s.q, sigma_points(s.x, s.p + self.q, self.iota))
        x, p = unscented_moments(sig, self.wm, self.wc)
        return RotationUKFState(ref, x, p, sig)

    def update(self, s: RotationUKFState, z: np.ndarray) -> RotationUKFState:
        """Update (A.22)–(A.30) with measured quaternions ``z``, then reset ``d`` into ``q`` (A.9)."""
        sig = s.sigmas if s.sigmas is not None else sigma_points(s.x, s.p, self.iota)
        z_d = rodrigues_from_quat(quat_multiply(quat_conjugate(s.q), np.asarray(z, float)))  # (A.11)
        x, p, nu, p_nn = kalman_update(sig, s.x, s.p, sig[..., :3], z_d, self.r, self.wm, self.wc)
        x, p = outliers.gaussian_update(self.outlier_prob, nu, p_nn, x, p, s.x, s.p)
        q = quat_canonical(quat_multiply(s.q, quat_from_rodrigues(x[..., :3])))
        return RotationUKFState(q, np.concatenate([np.zeros_like(x[..., :3]), x[..., 3:]], axis=-1), p)

    @staticmethod
    def estimate(s: RotationUKFState) -> tuple[np.ndarray, np.ndarray]:
        """Orientation ``q ⊗ R⁻¹(d)`` (canonical) and angular velocity."""
        return quat_canonical(quat_multiply(s.q, quat_from_rodrigues(s.x[..., :3]))), s.x[..., 3:].copy()


def check_dt(dt: float) -> float:
    """The time step Δt: positive and at most :data:`MAX_DT` s."""
    if not 0 < dt <= MAX_DT:
        raise ValueError(f"dt must be positive and at most {MAX_DT:g} s, got {dt}")
    return dt


def spd_matrix(a, n: int, name: str) -> np.ndarray:
    """A symmetric positive-definite ``(n, n)`` matrix from a matrix or a diagonal."""
    a = np.asarray(a, dtype=float)
    if a.ndim == 1:
        a = np.diag(a)
    if a.shape != (n, n) or not np.all(np.isfinite(a)) or not np.allclose(a, a.T, 0.0, 1e-9 * np.abs(a).max()):
        raise ValueError(f"{name} must be a finite symmetric {n}x{n} matrix or a length-{n} diagonal")
    if np.any(np.linalg.eigvalsh(a) <= 0):
        raise ValueError(f"{name} must be positive definite")
    return a
