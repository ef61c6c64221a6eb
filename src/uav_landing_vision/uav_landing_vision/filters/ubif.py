"""Unscented Bingham Filter (UBiF, §5.3.1), vectorised over a batch of M filters.

The orientation is Bingham distributed ``P_B(M, Z)``; the angular velocity is not a state but
is re-estimated from successive estimates (5.4)–(5.6).
"""

from dataclasses import dataclass

import numpy as np

from ..geometry import omega_quat, quat_canonical, quat_conjugate, quat_multiply
from . import bingham
from .ukf import spd_matrix, take_filters


@dataclass(frozen=True)
class UBiFState:
    """``m (M, 4, 4)``, ``z (M, 3)``, angular velocity ``omega (M, 3)``, previous estimate ``prev (M, 4)``."""

    m: np.ndarray
    z: np.ndarray
    omega: np.ndarray
    prev: np.ndarray

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


class UBiF:
    """Prediction (Algorithm 4) and update (Algorithm 5) with Bingham noises ``Φ`` and ``Λ``."""

    def __init__(self, dt: float, process_z, measurement_z, omega_process_cov):
        if not dt > 0:
            raise ValueError(f"dt must be positive, got {dt}")
        self.dt = dt
        self.process_z = bingham.check_concentration(process_z, "process_z")
        self.measurement_z = bingham.check_concentration(measurement_z, "measurement_z")
        self.process_cov = bingham.covariance(np.eye(4), self.process_z)  # C_Φ (C.6), M^Φ = I
        # δq^r = Ω(ξ^r) of (3.12): the angular-velocity disturbance integrated over Δt.
        omega_cov = spd_matrix(omega_process_cov, 3, "omega_process_cov")
        self.disturbance_cov = bingham.small_rotation_moment(dt**2 * omega_cov)

    def init(self, quat: np.ndarray, omega: np.ndarray, z0) -> UBiFState:
        """Filters with mode ``quat (M, 4)``, concentrations ``z0`` and angular velocity ``omega``."""
        quat = quat_canonical(np.asarray(quat, float))
        z = np.broadcast_to(bingham.check_concentration(z0, "z0"), quat.shape[:-1] + (3,)).copy()
        return UBiFState(bingham.frame(quat), z, np.asarray(omega, float).copy(), quat)

    def predict(self, s: UBiFState) -> UBiFState:
        """Algorithm 4: sigma points (App. D) through (3.12), composed with ``Φ`` (C.7), refit (C.9).

        The model (3.12) is ``q ⊗ Ω(ω) ⊗ Ω(ξ^r)``: the sigma points take ``Ω(ω)``; the random
        disturbance ``Ω(ξ^r)`` enters, like ``Φ``, by the composition (C.7).
        """
        pts, w = bingham.sigma_points(s.m, s.z)
        pts = quat_multiply(pts, omega_quat(s.omega, self.dt)[..., None, :])
        cov = bingham.compose_covariance(bingham.scatter(pts, w), self.disturbance_cov)
        cov = bingham.compose_covariance(cov, self.process_cov)
        m, z = bingham.fit(cov)
        return UBiFState(m, z, s.omega, bingham.mode(s.m))

    def update(self, s: UBiFState, meas: np.ndarray) -> UBiFState:
        """Algorithm 5: product (C.3) with the noise rotated onto the measurement (5.3)."""
        m_meas = bingham.noise_frame_at(np.asarray(meas, float), np.eye(4))
        m, z = bingham.product(m_meas, self.measurement_z, s.m, s.z)
        z = bingham.clamp_concentration(z)
        return UBiFState(m, z, angular_velocity(s.prev, bingham.mode(m), self.dt), s.prev)

    @staticmethod
    def estimate(s: UBiFState) -> tuple[np.ndarray, np.ndarray]:
        """The mode (canonical) and the angular velocity."""
        return bingham.mode(s.m), s.omega.copy()

    @staticmethod
    def covariance(s: UBiFState) -> np.ndarray:
        """Rotation-error covariance ``(M, 3, 3)`` about the mode, rad², from (C.6)."""
        return bingham.tangent_covariance(bingham.mode(s.m), bingham.covariance(s.m, s.z))
