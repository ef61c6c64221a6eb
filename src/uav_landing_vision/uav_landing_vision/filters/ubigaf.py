"""Unscented Bingham–Gauss Filter (UBiGaF, §5.3.2), vectorised over a batch of M filters.

The state ``r = [q, ω]`` is Bingham–Gauss distributed (C.11) with parameters ``m_ω`` (C.13),
``P_ω`` (C.14), ``P_q`` (C.15), ``P_qω`` (C.16). Antipodal symmetry (C.17) is handled by taking
every quaternion in the hemisphere of the distribution's mode, where ``P_qω`` keeps its sign.
"""

from dataclasses import dataclass

import numpy as np

from ..geometry import omega_quat, quat_canonical, quat_conjugate, quat_multiply
from . import bingham, outliers
from .ukf import check_dt, kalman_update, spd_matrix, take_filters, unscented_moments

N_SIGMA = 13  # 2r + 2s + 1 with r = s = 3 (Appendix E)


@dataclass(frozen=True)
class UBiGaFState:
    """Mode ``q (M, 4)``, ``m_w (M, 3)``, ``p_w (M, 3, 3)``, ``p_q (M, 4, 4)``, ``p_qw (M, 4, 3)``.

    After a prediction ``sig_q (M, 13, 4)``, ``sig_w (M, 13, 3)`` and ``weights (M, 13)`` hold
    the propagated sigma points for the update.
    """

    q: np.ndarray
    m_w: np.ndarray
    p_w: np.ndarray
    p_q: np.ndarray
    p_qw: np.ndarray
    sig_q: np.ndarray | None = None
    sig_w: np.ndarray | None = None
    weights: np.ndarray | None = None

    def take(self, idx) -> "UBiGaFState":
        return take_filters(self, idx)


def _align(q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """``q`` or ``−q``, whichever lies in the hemisphere of ``ref`` (C.17)."""
    return np.where(np.sum(q * ref, axis=-1, keepdims=True) < 0.0, -q, q)


def canonical_sigma_points(f: np.ndarray):
    """Canonical points (E.1)–(E.7): quaternion part ``(..., 13, 4)``, unit Euclidean part ``(13, 3)``,
    weights ``(..., 13)`` and the scale ``δ (..., 1)``.

    ``f (..., 4)`` are the Bingham moments, ascending with the mode last. One point of each
    antipodal pair is kept with the pair's weight, so (E.10), (E.12)–(E.15) double and the
    weights sum to one; ``δ`` (E.9) makes the Euclidean part unit-covariance.
    """
    r = s = 3
    f4 = f[..., 3:4]
    w_g = f4 / N_SIGMA  # each of the six ω points (E.10)
    w_b = f[..., :3] + (1.0 - 1.0 / N_SIGMA - 2.0 * r / N_SIGMA) * f4 / s  # (E.12)–(E.14)
    alpha = np.arcsin(np.sqrt(np.clip(f[..., :3] / w_b, 0.0, 1.0)))  # (E.8)
    delta = np.sqrt(N_SIGMA / (2.0 * f4))  # (E.9) with w_G = 2r·f4/N
    quat = np.zeros(f.shape[:-1] + (N_SIGMA, 4))
    quat[..., :6, 3] = 1.0
    for i in range(3):
        quat[..., 6 + 2 * i, i] = np.sin(alpha[..., i])
        quat[..., 7 + 2 * i, i] = -np.sin(alpha[..., i])
        quat[..., 6 + 2 * i : 8 + 2 * i, 3] = np.cos(alpha[..., i])[..., None]
    quat[..., 12, 3] = 1.0  # (E.7)
    eucl = np.zeros((N_SIGMA, 3))
    eucl[:6] = np.repeat(np.eye(3), 2, axis=0) * np.tile([1.0, -1.0], 3)[:, None]
    weights = np.concatenate(
        [np.repeat(w_g, 6, axis=-1), np.repeat(w_b / 2.0, 2, axis=-1), f4 / N_SIGMA], axis=-1
    )  # (E.10), (E.12)–(E.15)
    return quat, eucl, weights, delta


def tangent_coordinates(q_ref: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``2·vec(q̄_ref ⊗ x)`` with ``x`` in the hemisphere of ``q_ref``: the rotation vector for small angles."""
    return 2.0 * quat_multiply(quat_conjugate(q_ref), _align(x, q_ref))[..., :3]


def bingham_gauss_moments(q, w, weights):
    """``m_ω`` (E.19), ``P_ω`` (E.20), ``P_q`` (E.21), ``P_qω`` (E.22) of weighted sigma points."""
    m_w, p_w = unscented_moments(w, weights, weights)
    dw = w - m_w[..., None, :]
    p_q = bingham.weighted_outer(weights, q, q)
    p_qw = bingham.weighted_outer(weights, q, dw)
    return m_w, p_w, p_q, p_qw


class UBiGaF:
    """Prediction (Algorithm 6) and UKF-like update (Algorithm 7); ``outlier_prob`` > 0 makes
    the update outlier-aware (:mod:`.outliers`; 0 is the thesis's)."""

    def __init__(self, dt: float, process_z, measurement_z, omega_process_cov, outlier_prob: float = 0.0):
        self.dt = check_dt(dt)
        self.outlier_prob = outliers.check_outlier_prob(outlier_prob)
        process_z = bingham.check_concentration(process_z, "process_z")
        measurement_z = bingham.check_concentration(measurement_z, "measurement_z")
        self.process_cov = bingham.covariance(np.eye(4), process_z)  # C_Φ (C.6)
        self.measurement_cov = bingham.covariance(np.eye(4), measurement_z)  # C_Λ (C.6)
        self.omega_process_cov = spd_matrix(omega_process_cov, 3, "omega_process_cov")  # P^r

    def init(self, quat: np.ndarray, omega: np.ndarray, z0, omega_cov) -> UBiGaFState:
        """Filters at ``quat (M, 4)``, ``omega (M, 3)``; Bingham spread ``z0``, ``omega_cov (3, 3)``."""
        quat = quat_canonical(np.asarray(quat, float))
        p_q = bingham.covariance(bingham.frame(quat), bingham.check_concentration(z0, "z0"))
        shape = quat.shape[:-1]
        p_w = np.broadcast_to(spd_matrix(omega_cov, 3, "omega_cov"), shape + (3, 3)).copy()
        return UBiGaFState(quat, np.asarray(omega, float).copy(), p_w, p_q, np.zeros(shape + (4, 3)))

    def sigma_points(self, q_ref, m_w, p_w, p_q, p_qw):
        """Sigma points (E.16)–(E.17) of the Bingham–Gauss state, in the hemisphere of ``q_ref``.

        The Euclidean part is scaled by the root of the conditional covariance of (C.11)
        (E.17 prints ``+``, which would not reproduce ``P_ω``). The points' quaternions lie in one
        hemisphere, so their mean ``q̄`` is not the zero of the antipodal density: the conditional
        mean is taken about ``q̄`` (``G (q_i − q̄)``, and ``P_ω − G (P_q − q̄q̄ᵀ) Gᵀ``), which keeps
        the points' ω mean at ``m_ω`` and their covariance at ``P_ω``. About zero, as (E.17), they
        moved ``m_ω`` by ``G q̄`` at every prediction after the first without an update (0.26 rad/s
        after 20, 8 rad/s after 60); right after an update ``G q̄`` is zero and nothing differs.
        The points' cross-moment is ``P_qω − q̄ (G q̄)ᵀ``, so across predictions without an update
        ``P_qω`` loses ``q̄ (G q̄)ᵀ`` each step (default settings: 0.1 % after 4 steps, 1.4 % after
        10, 31 % after 20). Regressing on ``P_q − q̄q̄ᵀ`` instead would keep it; not done, since
        the tracker updates every filter at every frame and predicts a few steps at most between.
        """
        f, m = np.linalg.eigh(p_q)
        f = np.maximum(f, 1e-15)
        m = m * np.where(np.sum(m[..., :, 3] * q_ref, axis=-1) < 0, -1.0, 1.0)[..., None, None]
        canon_q, canon_w, weights, delta = canonical_sigma_points(f / f.sum(axis=-1, keepdims=True))
        q = canon_q @ np.swapaxes(m, -1, -2)  # (E.16)
        q_mean = (weights[..., None, :] @ q)[..., 0, :]
        gain = np.swapaxes(np.linalg.solve(p_q, p_qw), -1, -2)  # P_qωᵀ P_q⁻¹
        spread = p_q - q_mean[..., :, None] * q_mean[..., None, :]
        cond = p_w - gain @ spread @ np.swapaxes(gain, -1, -2)  # conditional covariance of (C.11)
        cond = 0.5 * (cond + np.swapaxes(cond, -1, -2))
        try:
            root = np.linalg.cholesky(cond + 1e-12 * np.eye(3))
        except np.linalg.LinAlgError:
            # Step 4 of the prediction widens P_q but leaves P_qω: with process noise far from
            # isotropic the joint covariance, and so this one, can lose definiteness. Its negative
            # part is dropped (only in such a step, so every other step keeps its sigma points).
            root = np.linalg.cholesky(_without_negative_variance(cond) + 1e-12 * np.eye(3))
        w = (delta[..., None] * (canon_w @ np.swapaxes(root, -1, -2))
             + (q - q_mean[..., None, :]) @ np.swapaxes(gain, -1, -2) + m_w[..., None, :])  # (E.17)
        return q, w, weights

    def predict(self, s: UBiGaFState) -> UBiGaFState:
        """Algorithm 6: noise added (steps 3–5), sigma points through (3.12), moments (E.19)–(E.22)."""
        p_w = s.p_w + self.omega_process_cov  # step 3
        p_q = bingham.compose_covariance(s.p_q, self.process_cov)  # step 4 (C.7)
        q, w, weights = self.sigma_points(s.q, s.m_w, p_w, p_q, s.p_qw)  # step 5
        q = quat_multiply(q, omega_quat(w, self.dt))  # step 6, (5.9)–(5.12)
        q = _align(q, q[..., 12:13, :])
        m_w, p_w, p_q, p_qw = bingham_gauss_moments(q, w, weights)  # step 7
        mode = _align(np.linalg.eigh(p_q)[1][..., :, 3], q[..., 12, :])
        return UBiGaFState(mode, m_w, p_w, p_q, p_qw, q, w, weights)

    def update(self, s: UBiGaFState, meas: np.ndarray) -> UBiGaFState:
        """Algorithm 7, linear in the embedding R⁴ of the quaternions.

        Quaternions ``x`` (taken in the hemisphere of the predicted mode ``q̄``, C.17) enter
        through their tangent coordinates ``2·vec(q̄⁻¹ ⊗ x) = 2Tᵀx`` at ``q̄`` (see
        :func:`bingham.tangent_covariance`), so ``z − z̄`` (A.25) is the projected R⁴
        difference and a far outlier moves the estimate by at most a bounded amount.
        """
        if s.sig_q is None:
            sig_q, sig_w, weights = self.sigma_points(s.q, s.m_w, s.p_w, s.p_q, s.p_qw)
        else:
            sig_q, sig_w, weights = s.sig_q, s.sig_w, s.weights
        d = tangent_coordinates(s.q[..., None, :], sig_q)
        r_sig = np.concatenate([d, sig_w], axis=-1)
        r_mean, p_rr = unscented_moments(r_sig, weights, weights)
        # Step 4: Cov(ν ⊗ Λ) (C.7) is P_zz plus the spread the composition with Λ adds.
        noise = _without_negative_variance(
            bingham.tangent_covariance(s.q, bingham.compose_covariance(s.p_q, self.measurement_cov) - s.p_q))
        z = tangent_coordinates(s.q, np.asarray(meas, float))
        r, p_r, nu, p_nn = kalman_update(r_sig, r_mean, p_rr, d, z, noise, weights, weights)  # steps 1–7
        r, p_r = outliers.gaussian_update(self.outlier_prob, nu, p_nn, r, p_r, r_mean, p_rr)
        half = r[..., :3] / 2.0
        scale = np.maximum(1.0, np.linalg.norm(half, axis=-1, keepdims=True))
        vec = half / scale
        err = np.concatenate([vec, np.sqrt(np.maximum(0.0, 1.0 - np.sum(vec**2, -1, keepdims=True)))], -1)
        q = quat_canonical(quat_multiply(s.q, err))
        return UBiGaFState(q, r[..., 3:], p_r[..., 3:, 3:], *self.quaternion_moments(q, p_r))  # step 8

    @staticmethod
    def quaternion_moments(q: np.ndarray, p_r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``P_q`` (C.15) and ``P_qω`` (C.16) about mode ``q`` from the error-state covariance ``p_r``.

        With ``q_true = q ⊗ e``, ``e = [d/2, √(1 − |d|²/4)]``: ``E[e eᵀ]`` is
        :func:`bingham.small_rotation_moment` and ``E[e (ω − m)ᵀ] = [P_dω/2; 0]``, both mapped by
        the left multiplication ``L(q)``.
        """
        e = bingham.small_rotation_moment(p_r[..., :3, :3])
        e_w = np.zeros(p_r.shape[:-2] + (4, 3))
        e_w[..., :3, :] = p_r[..., :3, 3:] / 2.0
        left = bingham.frame(q)
        return left @ e @ np.swapaxes(left, -1, -2), left @ e_w

    @staticmethod
    def estimate(s: UBiGaFState) -> tuple[np.ndarray, np.ndarray]:
        """The mode (canonical) and the mean angular velocity."""
        return quat_canonical(s.q), s.m_w.copy()

    @staticmethod
    def covariance(s: UBiGaFState) -> np.ndarray:
        """Rotation-error covariance ``(M, 3, 3)`` about the mode, rad²."""
        return bingham.tangent_covariance(s.q, s.p_q)


def _without_negative_variance(cov: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` covariances with negative eigenvalues set to zero, the others untouched.

    The composition difference of step 4 is not positive semi-definite for every prior: with a
    prior much wider about one axis than the measurement noise it has a negative eigenvalue,
    and the update would then report a negative variance."""
    values, vectors = np.linalg.eigh(cov)
    bad = values.min(axis=-1) < 0.0
    if not np.any(bad):
        return cov
    out = np.array(cov, float, copy=True)
    v = vectors[bad]
    out[bad] = v @ (np.maximum(values[bad], 0.0)[..., None] * np.swapaxes(v, -1, -2))
    return out
