"""The motion filters behind one interface, chosen by configuration (§5.2.3–5.2.4, Table 6.11).

``make_rotation_filter(cfg)`` returns a :class:`RotationFilter` whose kind — ``"ukf"``
(App. A.2), ``"ubif"`` (§5.3.1) or ``"ubigaf"`` (§5.3.2) — is ``cfg.rotation_filter``; all
take and return batched states (one filter per particle) with a ``take(idx)`` for resampling.
The Gaussian noises of the UKF are the tangent-space equivalents (C.6) of the Bingham ones,
so the three filters model the same noise.
"""

from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np

from . import bingham, outliers
from .ubif import UBiF
from .ubigaf import UBiGaF
from .ukf import RotationUKF, TranslationUKF, UnscentedParams, check_dt

Vec3 = tuple[float, float, float]
KINDS = ("ukf", "ubif", "ubigaf")
MAX_STD = 1e3  # the largest noise σ taken (m, m/s or rad/s): far beyond any UAV's motion


@dataclass(frozen=True)
class MotionFilterConfig:
    """Motion filter parameters; thesis defaults (§6.7): Δt ≈ 0.034 s, Z^Φ = −250, Z^Λ = −800."""

    rotation_filter: Literal["ukf", "ubif", "ubigaf"] = "ubif"
    dt: float = 0.034  # s between frames
    process_z: Vec3 = (-250.0, -250.0, -250.0)  # Bingham process noise Z^Φ = diag(·, 0), M^Φ = I
    measurement_z: Vec3 = (-800.0, -800.0, -800.0)  # Bingham measurement noise Z^Λ, M^Λ = I
    initial_z: Vec3 = (-800.0, -800.0, -800.0)  # spread of a new filter about its orientation
    omega_process_std: float = 0.5  # rad/s added to ω per step (Q^ω, P^r)
    initial_omega_std: float = 2.0  # rad/s
    position_process_std: float = 0.05  # m per step (Q^l, position block)
    velocity_process_std: float = 0.5  # m/s per step (Q^l, velocity block)
    position_measurement_std: float = 0.5  # m (R^l)
    # Ours (0 = the thesis's fixed R^l): R^l's σ grows to this fraction of the measured depth.
    position_measurement_range_fraction: float = 0.0
    initial_position_std: float = 0.5  # m
    initial_velocity_std: float = 5.0  # m/s
    ukf_alpha: float = 1.0  # (A.13)
    ukf_beta: float = 2.0  # (A.21)
    ukf_kappa: float = 0.0  # (A.13)
    outlier_prob: float = 0.0  # prior probability of a uniform-rotation outlier (ours; 0 = thesis update)

    def __post_init__(self):
        if self.rotation_filter not in KINDS:
            raise ValueError(f"rotation_filter must be one of {KINDS}, got {self.rotation_filter!r}")
        check_dt(self.dt)
        for name in ("process_z", "measurement_z", "initial_z"):  # stored as (z1, z2, z3), also if given with the 0
            z = bingham.check_concentration(getattr(self, name), name)
            object.__setattr__(self, name, tuple(map(float, z)))
        stds = ("omega_process_std", "initial_omega_std", "position_process_std", "velocity_process_std",
                "position_measurement_std", "initial_position_std", "initial_velocity_std")
        for name in stds:  # bounded so that their squares, the filters' covariances, stay finite
            value = getattr(self, name)
            if not 0 < value <= MAX_STD:
                raise ValueError(f"{name} must be positive and at most {MAX_STD:g}, got {value}")
        fraction = self.position_measurement_range_fraction
        if not 0 <= fraction <= 1:
            raise ValueError(f"position_measurement_range_fraction must be within 0 to 1, got {fraction}")
        UnscentedParams(self.ukf_alpha, self.ukf_beta, self.ukf_kappa)
        outliers.check_outlier_prob(self.outlier_prob)

    @property
    def unscented(self) -> UnscentedParams:
        return UnscentedParams(self.ukf_alpha, self.ukf_beta, self.ukf_kappa)


def tangent_variance(z) -> np.ndarray:
    """Per-axis rotation-angle variances (rad²) of a Bingham ``diag(z, 0)`` about its mode (C.6)."""
    return 4.0 * bingham.moments(np.asarray(z, float))[:3]


class RotationFilter(Protocol):
    """What the tracker uses; states are batched over particles and have ``take(idx)``."""

    def init(self, quat: np.ndarray, omega: np.ndarray): ...
    def predict(self, state): ...
    def update(self, state, quat_meas: np.ndarray): ...
    def estimate(self, state) -> tuple[np.ndarray, np.ndarray]: ...
    def covariance(self, state) -> np.ndarray: ...


class _UKFRotation(RotationUKF):
    def __init__(self, cfg: MotionFilterConfig):
        q = np.concatenate([tangent_variance(cfg.process_z), np.full(3, cfg.omega_process_std**2)])  # Q^a (A.9)
        super().__init__(cfg.dt, q, tangent_variance(cfg.measurement_z), cfg.unscented, cfg.outlier_prob)
        self.p0 = np.concatenate([tangent_variance(cfg.initial_z), np.full(3, cfg.initial_omega_std**2)])

    def init(self, quat, omega):
        return super().init(quat, omega, self.p0)

    @staticmethod
    def covariance(state) -> np.ndarray:
        """Covariance of the error Rodrigues parameters ``d`` (≈ rotation vector), rad²."""
        return state.p[..., :3, :3].copy()


class _BinghamRotation:
    """A Bingham filter (UBiF or UBiGaF, the class it is mixed into) with the configured noises
    and start spreads."""

    def __init__(self, cfg: MotionFilterConfig):
        super().__init__(cfg.dt, cfg.process_z, cfg.measurement_z, np.full(3, cfg.omega_process_std**2),
                         cfg.outlier_prob)
        self.z0, self.omega_cov0 = cfg.initial_z, np.full(3, cfg.initial_omega_std**2)

    def init(self, quat, omega):
        return super().init(quat, omega, self.z0, self.omega_cov0)


class _UBiFRotation(_BinghamRotation, UBiF):
    pass


class _UBiGaFRotation(_BinghamRotation, UBiGaF):
    pass


def make_rotation_filter(cfg: MotionFilterConfig) -> RotationFilter:
    """The rotation filter named by ``cfg.rotation_filter``."""
    return {"ukf": _UKFRotation, "ubif": _UBiFRotation, "ubigaf": _UBiGaFRotation}[cfg.rotation_filter](cfg)


class TranslationFilter(TranslationUKF):
    """The translational UKF (A.1)–(A.2) with the configured noises; ``init(pos, vel)``."""

    def __init__(self, cfg: MotionFilterConfig):
        q = np.repeat([cfg.position_process_std**2, cfg.velocity_process_std**2], 3)
        super().__init__(cfg.dt, q, np.full(3, cfg.position_measurement_std**2), cfg.unscented)
        self.p0 = np.repeat([cfg.initial_position_std**2, cfg.initial_velocity_std**2], 3)
        self.std, self.range_fraction = cfg.position_measurement_std, cfg.position_measurement_range_fraction

    def init(self, pos, vel):
        return super().init(pos, vel, self.p0)

    def update(self, state, z):
        """(A.22)–(A.30) with R^l = σ²·I, σ = max(``position_measurement_std``, fraction · |depth of z|)
        (ours, ``position_measurement_range_fraction``): a pose measured from the image is off by
        a share of its range, not by a fixed distance."""
        if self.range_fraction == 0.0:
            return super().update(state, z)
        z = np.asarray(z, float)
        sigma = np.maximum(self.std, self.range_fraction * np.abs(z[..., 2]))
        return super().update(state, z, sigma[..., None, None] ** 2 * np.eye(3))

    @staticmethod
    def estimate(state) -> tuple[np.ndarray, np.ndarray]:
        return state.x[..., :3].copy(), state.x[..., 3:].copy()
