"""Unit quaternions, scalar-last ``[x, y, z, w]``, Hamilton product, vectorised over ``(..., 4)``.

Rotations are active: ``p_cam = quat_to_matrix(q) @ p_body + t``. The thesis writes its
direction cosine matrix (3.2) in the passive form, which is the transpose of ours.
"""

import numpy as np

_EPS = 1e-12


def quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p ⊗ q`` (the composition of orientations in (3.4), (3.12))."""
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    px, py, pz, pw = np.moveaxis(p, -1, 0)
    qx, qy, qz, qw = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
            pw * qw - px * qx - py * qy - pz * qz,
        ],
        axis=-1,
    )


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """Conjugate ``q̄`` (the inverse of a unit quaternion)."""
    q = np.asarray(q, dtype=float)
    return q * np.array([-1.0, -1.0, -1.0, 1.0])


def quat_normalise(q: np.ndarray) -> np.ndarray:
    """Scale to unit norm; a zero quaternion is an error."""
    q = np.asarray(q, dtype=float)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(norm < _EPS) or not np.all(np.isfinite(norm)):
        raise ValueError("cannot normalise a zero or non-finite quaternion")
    return q / norm


def quat_canonical(q: np.ndarray) -> np.ndarray:
    """The representative of ``±q`` with ``w >= 0`` (DESIGN §3); at ``w == 0`` (a half turn) the one
    whose first non-zero component of ``(x, y, z)`` is positive, so the representative is unique."""
    q = np.asarray(q, dtype=float)
    lead = np.take_along_axis(q, np.argmax(q[..., :3] != 0.0, axis=-1)[..., None], axis=-1)
    flip = (q[..., 3:4] < 0.0) | ((q[..., 3:4] == 0.0) & (lead < 0.0))
    return np.where(flip, -q, q)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Active rotation matrix of a unit quaternion, ``(..., 3, 3)``; the transpose of the DCM (3.2)."""
    q = np.asarray(q, dtype=float)
    x, y, z, w = np.moveaxis(q, -1, 0)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    rows = [
        [w * w + xx - yy - zz, 2 * (xy - wz), 2 * (xz + wy)],
        [2 * (xy + wz), w * w - xx + yy - zz, 2 * (yz - wx)],
        [2 * (xz - wy), 2 * (yz + wx), w * w - xx - yy + zz],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Unit quaternion (``w >= 0``) of an active rotation matrix ``(..., 3, 3)``.

    Uses the largest of the four diagonal combinations for numerical stability.
    """
    m = np.asarray(m, dtype=float)
    shape = m.shape[:-2]
    m = m.reshape(-1, 3, 3)
    trace = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    # Candidates 4·x², 4·y², 4·z², 4·w² (each from the diagonal); pick the largest per matrix.
    cand = np.stack(
        [
            1 + 2 * m[:, 0, 0] - trace,
            1 + 2 * m[:, 1, 1] - trace,
            1 + 2 * m[:, 2, 2] - trace,
            1 + trace,
        ],
        axis=-1,
    )
    best = np.argmax(cand, axis=-1)
    s = np.sqrt(np.maximum(cand[np.arange(len(m)), best], _EPS))  # = 2·|component|
    q = np.empty((len(m), 4))
    off = {
        "x": (m[:, 2, 1] - m[:, 1, 2]),
        "y": (m[:, 0, 2] - m[:, 2, 0]),
        "z": (m[:, 1, 0] - m[:, 0, 1]),
        "xy": (m[:, 0, 1] + m[:, 1, 0]),
        "xz": (m[:, 0, 2] + m[:, 2, 0]),
        "yz": (m[:, 1, 2] + m[:, 2, 1]),
    }
    formulas = [
        (s / 2, off["xy"] / (2 * s), off["xz"] / (2 * s), off["x"] / (2 * s)),
        (off["xy"] / (2 * s), s / 2, off["yz"] / (2 * s), off["y"] / (2 * s)),
        (off["xz"] / (2 * s), off["yz"] / (2 * s), s / 2, off["z"] / (2 * s)),
        (off["x"] / (2 * s), off["y"] / (2 * s), off["z"] / (2 * s), s / 2),
    ]
    for k, comps in enumerate(formulas):
        sel = best == k
        q[sel] = np.stack([c[sel] for c in comps], axis=-1)
    return quat_canonical(quat_normalise(q)).reshape(shape + (4,))


def rotate_vectors(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Apply the active rotation of ``q (..., 4)`` to vectors ``v (..., 3)``."""
    return np.einsum("...ij,...j->...i", quat_to_matrix(q), np.asarray(v, dtype=float))


def omega_quat(b: np.ndarray, dt: float) -> np.ndarray:
    """Ω(b) (3.14): the rotation of a constant angular rate ``b (..., 3)`` over ``dt`` seconds.

    ``q ⊗ Ω(ω)`` advances ``q`` by the body-frame angular velocity ``ω`` (3.12), (3.13).
    A zero rate gives the identity.
    """
    b = np.asarray(b, dtype=float)
    rate = np.linalg.norm(b, axis=-1, keepdims=True)
    half = 0.5 * rate * dt
    # sin(|b|dt/2)/|b| → dt/2 as |b| → 0; np.sinc(x) = sin(πx)/(πx).
    scale = 0.5 * dt * np.sinc(half / np.pi)
    return np.concatenate([b * scale, np.cos(half)], axis=-1)
