"""Orientation errors between estimated and true rotations."""

import numpy as np

from .euler import quat_to_euler_zyx
from .quaternion import quat_conjugate, quat_multiply, quat_normalise


def geodesic_angle(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Geodesic rotation error (3.3), in radians, of unit quaternions ``(..., 4)``.

    ``‖log(R1ᵀR2)‖_F / √2`` equals the angle of the relative rotation, ``2·acos|⟨q1, q2⟩|``;
    it is zero for antipodal quaternions (the same rotation). The arctan form keeps full
    precision for small angles.
    """
    rel = quat_multiply(quat_conjugate(quat_normalise(q1)), quat_normalise(q2))
    return 2.0 * np.arctan2(np.linalg.norm(rel[..., :3], axis=-1), np.abs(rel[..., 3]))


def euler_error(q_true: np.ndarray, q_est: np.ndarray) -> np.ndarray:
    """Per-axis error (6.4): Z-Y-X Euler angles ``[α, β, γ]`` of ``q_e = q_g ⊗ q̄_r``, radians."""
    q_e = quat_multiply(quat_normalise(q_true), quat_conjugate(quat_normalise(q_est)))
    return quat_to_euler_zyx(q_e)
