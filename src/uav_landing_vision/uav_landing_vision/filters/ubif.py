"""Unscented Bingham Filter (UBiF, §5.3.1), vectorised over a batch of M filters.

The orientation is Bingham distributed ``P_B(M, Z)``. The angular velocity is not part of the
Bingham state: it is measured from successive estimates (5.4)–(5.6), as in the thesis.

Ours (not in the thesis): those measurements are fused by a small Kalman filter on ω (random
walk of ``omega_process_cov`` per step; measurement noise from the two estimates' rotation
covariances (C.6)), and the ω uncertainty is composed into the prediction. Taking (5.4)–(5.6)
as exact made the filter over-confident (mean NEES 5.0 where 2.3–3.8 is consistent,
``simulation.compare``) and, in the tracker, let a drifting estimate feed its own drift back
as angular velocity until it was off by 165° (complex landing, seed 0, frames 302–321 without a
detection).
"""

from dataclasses import dataclass

import numpy as np

from ..geometry import omega_quat, quat_canonical, quat_conjugate, quat_multiply
from . import bingham, outliers
from .ukf import check_dt, spd_matrix, take_filters


@dataclass(frozen=True)
class UBiFState:
    """``m (M, 4, 4)``, ``z (M, 3)``; angular velocity ``omega (M, 3)`` with covariance
    ``omega_cov (M, 3, 3)``; the previous estimate ``prev (M, 4)`` with its rotation covariance
    ``prev_cov (M, 3, 3)`` (rad²), from which the update measures ω."""

    m: np.ndarray
    z: np.ndarray
    omega: np.ndarray
    omega_cov: np.ndarray
    prev: np.ndarray
    prev_cov: np.ndarray

    def take(self, idx) -> "UBiFState":
        return take_filters(self, idx)


def angular_velocity(q_prev: np.ndarray, q_now: np.ndarray, dt: float) -> np.ndarray:
    """Angular velocity from successive orientations (5.4)–(5.6).

    Uses the increment ``q_e = q̄_{t−1} ⊗ q_t`` of the motion model ``q_t = q_{t−1} ⊗ Ω(ω)``
    (3.12), taken with ``w ≥ 0`` so the angle is at most π; ``2·acos(q4)`` is evaluated as
    ``2·atan2(‖q_e,vec‖, q4)``, which is exact for small angles.
    """
    e = quat_canonical(quat_multiply(quat_conjugate(q_prev), q_now))
    norm = np.linalg.norm(e[..., :3], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(norm, e[..., 3:4])
    return np.where(norm > 1e-15, angle / dt * e[..., :3] / np.maximum(norm, 1e-300), 0.0)


def fuse_angular_velocity(omega, omega_cov, measured, measured_cov):
    """Kalman update of ``omega (M, 3)``, ``omega_cov (M, 3, 3)`` with a measured angular velocity
    of covariance ``measured_cov``: returns the fused ω and its covariance."""
    gain = np.swapaxes(np.linalg.solve(omega_cov + measured_cov, omega_cov), -1, -2)  # Σ (Σ + R)⁻¹
    fused = omega + (gain @ (measured - omega)[..., None])[..., 0]
    cov = omega_cov - gain @ omega_cov
    return fused, 0.5 * (cov + np.swapaxes(cov, -1, -2))


def rotation_covariance(m: np.ndarray, z: np.ndarray, mode: np.ndarray) -> np.ndarray:
    """Rotation-error covariance ``(M, 3, 3)`` of ``P_B(m, z)`` about its ``mode``, rad², from (C.6)."""
    return bingham.tangent_covariance(mode, bingham.covariance(m, z))


class UBiF:
    """Prediction (Algorithm 4) and update (Algorithm 5) with Bingham noises ``Φ`` and ``Λ``;
    ``outlier_prob`` > 0 makes the update outlier-aware (:mod:`.outliers`; 0 is the thesis's)."""

    def __init__(self, dt: float, process_z, measurement_z, omega_process_cov, outlier_prob: float = 0.0):
        self.dt = check_dt(dt)
        self.outlier_prob = outliers.check_outlier_prob(outlier_prob)
        self.process_z = bingham.check_concentration(process_z, "process_z")
        self.measurement_z = bingham.check_concentration(measurement_z, "measurement_z")
        self.process_cov = bingham.covariance(np.eye(4), self.process_z)  # C_Φ (C.6), M^Φ = I
        self.omega_process_cov = spd_matrix(omega_process_cov, 3, "omega_process_cov")  # ξ^r of (3.12)

    def init(self, quat: np.ndarray, omega: np.ndarray, z0, omega_cov) -> UBiFState:
        """Filters with mode ``quat (M, 4)``, concentrations ``z0``, angular velocity ``omega`` of
        covariance ``omega_cov (3, 3)``."""
        quat = quat_canonical(np.asarray(quat, float))
        shape = quat.shape[:-1]
        m = bingham.frame(quat)
        z = np.broadcast_to(bingham.check_concentration(z0, "z0"), shape + (3,)).copy()
        omega_cov = np.broadcast_to(spd_matrix(omega_cov, 3, "omega_cov"), shape + (3, 3)).copy()
        return UBiFState(m, z, np.asarray(omega, float).copy(), omega_cov, quat, rotation_covariance(m, z, quat))

    def predict(self, s: UBiFState) -> UBiFState:
        """Algorithm 4: sigma points (App. D) through (3.12), composed with ``Φ`` (C.7), refit (C.9).

        The model (3.12) is ``q ⊗ Ω(ω) ⊗ Ω(ξ^r)``: the sigma points take ``Ω(ω)``; the random
        disturbance ``Ω(ξ^r)`` and the uncertainty of ω, both integrated over Δt, enter like ``Φ``
        by the composition (C.7).
        """
        pts, w = bingham.sigma_points(s.m, s.z)
        pts = quat_multiply(pts, omega_quat(s.omega, self.dt)[..., None, :])
        omega_cov = s.omega_cov + self.omega_process_cov
        cov = bingham.compose_covariance(bingham.scatter(pts, w), bingham.small_rotation_moment(self.dt**2 * omega_cov))
        cov = bingham.compose_covariance(cov, self.process_cov)
        m, z = bingham.fit(cov)
        prev = bingham.mode(s.m)
        return UBiFState(m, z, s.omega, omega_cov, prev, rotation_covariance(s.m, s.z, prev))

    def update(self, s: UBiFState, meas: np.ndarray) -> UBiFState:
        """Algorithm 5: product (C.3) with the noise rotated onto the measurement (5.3); then ω
        measured from the previous and the new estimate (5.4)–(5.6) and fused (ours, see above).

        Outlier-aware (ε > 0): the updated and the predicted states are mixed by the inlier
        probability, from the product's evidence; the Bingham is refitted (C.8)–(C.9) to the
        mixture's scatter matrix.
        """
        m_meas = bingham.noise_frame_at(np.asarray(meas, float), np.eye(4))
        m, z = bingham.product(m_meas, self.measurement_z, s.m, s.z)
        z = bingham.clamp_concentration(z)
        mode = bingham.mode(m)
        measured = angular_velocity(s.prev, mode, self.dt)
        noise = (rotation_covariance(m, z, mode) + s.prev_cov) / self.dt**2
        omega, omega_cov = fuse_angular_velocity(s.omega, s.omega_cov, measured, noise)
        if self.outlier_prob > 0.0:
            # Densities on S³ count q and −q: per rad³ of rotation vector they are a quarter.
            evidence = bingham.product_log_evidence(m_meas, self.measurement_z, s.m, s.z) - np.log(4.0)
            w = outliers.inlier_probability(evidence, self.outlier_prob)
            # Below 1e-3 the prediction's share changes the moments less than the table's accuracy.
            mixed = w < 1.0 - 1e-3
            wq = w[mixed][..., None, None]
            cov = wq * bingham.covariance(m[mixed], z[mixed])
            cov += (1.0 - wq) * bingham.covariance(s.m[mixed], s.z[mixed])
            m, z = m.copy(), z.copy()
            m[mixed], z[mixed] = bingham.fit(cov)
            omega, omega_cov = outliers.mix_gaussians(w, omega, omega_cov, s.omega, s.omega_cov)
        return UBiFState(m, z, omega, omega_cov, s.prev, s.prev_cov)

    @staticmethod
    def estimate(s: UBiFState) -> tuple[np.ndarray, np.ndarray]:
        """The mode (canonical) and the angular velocity."""
        return bingham.mode(s.m), s.omega.copy()

    @staticmethod
    def covariance(s: UBiFState) -> np.ndarray:
        """Rotation-error covariance ``(M, 3, 3)`` about the mode, rad², from (C.6)."""
        return rotation_covariance(s.m, s.z, bingham.mode(s.m))
