"""Generalised Rodrigues parameters of an error quaternion (A.5)–(A.7).

With ``a = 1`` and ``f = 2(a + 1) = 4`` the norm of ``d`` equals the rotation angle for
small angles (Crassidis & Markley), which is the thesis's choice.
"""

import numpy as np

DEFAULT_A = 1.0
DEFAULT_F = 2.0 * (DEFAULT_A + 1.0)


def rodrigues_from_quat(e: np.ndarray, a: float = DEFAULT_A, f: float = DEFAULT_F) -> np.ndarray:
    """``d = f·δρ / (a + δq4)`` (A.5) of a unit error quaternion ``e (..., 4)``.

    ``e`` and ``−e`` are the same rotation; the sign with ``δq4 >= 0`` is used so that the
    denominator never vanishes for rotations below 180°.
    """
    e = np.asarray(e, dtype=float)
    e = np.where(e[..., 3:4] < 0.0, -e, e)
    return f * e[..., :3] / (a + e[..., 3:4])


def quat_from_rodrigues(d: np.ndarray, a: float = DEFAULT_A, f: float = DEFAULT_F) -> np.ndarray:
    """The unit error quaternion ``R⁻¹(d)`` of Rodrigues parameters ``d (..., 3)`` (A.6)–(A.7)."""
    d = np.asarray(d, dtype=float)
    d2 = np.sum(d * d, axis=-1, keepdims=True)
    dq4 = (-a * d2 + f * np.sqrt(f * f + (1.0 - a * a) * d2)) / (f * f + d2)
    drho = (a + dq4) * d / f
    return np.concatenate([drho, dq4], axis=-1)
