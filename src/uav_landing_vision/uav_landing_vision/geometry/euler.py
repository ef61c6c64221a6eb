"""Z-Y-X Euler angles (3.1): γ about Z, then β about Y, then α about X (body axes).

Angles are ``[α, β, γ]`` = roll, pitch, yaw in radians, shape ``(..., 3)``. The thesis's
DCM (3.1) is passive; the matrices here are active (its transpose), i.e.
``Rz(γ) @ Ry(β) @ Rx(α)`` — scipy's ``Rotation.from_euler("ZYX", [γ, β, α])``.
"""

import numpy as np

from .quaternion import matrix_to_quat, quat_to_matrix


def euler_zyx_to_matrix(angles: np.ndarray) -> np.ndarray:
    """Active rotation matrix of Z-Y-X Euler angles ``[α, β, γ]`` (transpose of (3.1))."""
    angles = np.asarray(angles, dtype=float)
    ca, cb, cg = np.cos(angles[..., 0]), np.cos(angles[..., 1]), np.cos(angles[..., 2])
    sa, sb, sg = np.sin(angles[..., 0]), np.sin(angles[..., 1]), np.sin(angles[..., 2])
    rows = [
        [cg * cb, cg * sb * sa - sg * ca, cg * sb * ca + sg * sa],
        [sg * cb, sg * sb * sa + cg * ca, sg * sb * ca - cg * sa],
        [-sb, cb * sa, cb * ca],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def matrix_to_euler_zyx(m: np.ndarray) -> np.ndarray:
    """Z-Y-X Euler angles ``[α, β, γ]`` of an active rotation matrix; β in [−π/2, π/2].

    At gimbal lock (|β| = π/2) α is set to 0 and the whole rotation about Z goes to γ.
    """
    m = np.asarray(m, dtype=float)
    beta = np.arcsin(np.clip(-m[..., 2, 0], -1.0, 1.0))
    locked = np.abs(m[..., 2, 0]) > 1.0 - 1e-12
    alpha = np.where(locked, 0.0, np.arctan2(m[..., 2, 1], m[..., 2, 2]))
    gamma = np.where(
        locked,
        np.arctan2(-m[..., 0, 1], m[..., 1, 1]),
        np.arctan2(m[..., 1, 0], m[..., 0, 0]),
    )
    return np.stack([alpha, beta, gamma], axis=-1)


def euler_zyx_to_quat(angles: np.ndarray) -> np.ndarray:
    """Unit quaternion (``w >= 0``) of Z-Y-X Euler angles ``[α, β, γ]``."""
    return matrix_to_quat(euler_zyx_to_matrix(angles))


def quat_to_euler_zyx(q: np.ndarray) -> np.ndarray:
    """Z-Y-X Euler angles ``[α, β, γ]`` of a unit quaternion."""
    return matrix_to_euler_zyx(quat_to_matrix(q))
