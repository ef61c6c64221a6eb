"""Rotations and their errors: quaternions ``[x, y, z, w]``, Z-Y-X Euler angles, Rodrigues parameters."""

from .errors import euler_error, geodesic_angle
from .euler import euler_zyx_to_matrix, euler_zyx_to_quat, matrix_to_euler_zyx, quat_to_euler_zyx
from .quaternion import (
    matrix_to_quat,
    omega_quat,
    quat_canonical,
    quat_conjugate,
    quat_multiply,
    quat_normalise,
    quat_to_matrix,
    rotate_vectors,
)
from .rodrigues import quat_from_rodrigues, rodrigues_from_quat

__all__ = [
    "euler_error",
    "euler_zyx_to_matrix",
    "euler_zyx_to_quat",
    "geodesic_angle",
    "matrix_to_euler_zyx",
    "matrix_to_quat",
    "omega_quat",
    "quat_canonical",
    "quat_conjugate",
    "quat_from_rodrigues",
    "quat_multiply",
    "quat_normalise",
    "quat_to_euler_zyx",
    "quat_to_matrix",
    "rodrigues_from_quat",
    "rotate_vectors",
]
