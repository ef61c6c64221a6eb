"""Bingham distribution on S³ (Appendix C.1, D), vectorised over a batch of distributions.

A distribution is ``(M, z)``: ``M (..., 4, 4)`` orthogonal, ``z (..., 3)`` non-positive; the
concentration matrix is ``Z = diag(z1, z2, z3, 0)`` and the last column of ``M`` is the mode.
Quaternions are scalar-last ``[x, y, z, w]`` (DESIGN §3). ``F(Z)`` and its gradient come
from the shipped lookup table (:mod:`.bingham_table`), interpolated by cubic splines.
"""

from functools import lru_cache

import numpy as np
from scipy import ndimage

from ..geometry import quat_conjugate, quat_multiply
from ..resources import model_path

TABLE_FILE = "bingham_normalisation.npz"
_IDENTITY4 = np.eye(4)
# R_k with (q1 ⊗ q2) = Σ_k q2_k R_k q1 (the right-multiplication matrix is linear in q2), stacked (16, 4).
_RIGHT = np.concatenate([quat_multiply(_IDENTITY4, e).T for e in _IDENTITY4])


class _Table:
    """Cubic B-spline of ``[log F, log m_1, log m_2, log m_3]`` over ``v_i = log(1 + |z_i|)``."""

    def __init__(self, path):
        with np.load(path) as data:
            v = data["v"].astype(float)
            self.z_max = float(data["z_max"])
            self.v0, self.step = v[0], (v[-1] - v[0]) / (len(v) - 1)
            channels = [data["log_f"]] + [data["log_m"][..., i] for i in range(3)]
        coeffs = [ndimage.spline_filter(c.astype(float), order=3, mode="nearest") for c in channels]
        self.n = len(v)
        self.coeffs = np.stack(coeffs, axis=-1).reshape(-1, 4)  # (n³, 4 channels)

    def check(self, z: np.ndarray) -> np.ndarray:
        z = np.asarray(z, dtype=float)
        if np.any(z > 0) or np.any(z < -self.z_max * (1 + 1e-9)) or not np.all(np.isfinite(z)):
            raise ValueError(f"Bingham concentrations must lie in [-{self.z_max:g}, 0]")
        return z

    def lookup(self, z: np.ndarray) -> np.ndarray:
        """The four channels at ``z (..., 3)``, ``(..., 4)``."""
        z = self.check(z)
        return self.evaluate(np.log1p(-z).reshape(-1, 3))[0].reshape(z.shape[:-1] + (4,))

    def evaluate(self, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Channels ``(P, 4)`` and their gradients ``(P, 4, 3)`` with respect to ``v (P, 3)``."""
        x = np.clip((v - self.v0) / self.step, 1.0, self.n - 2.0 - 1e-9)
        i = np.floor(x).astype(np.intp)
        t = (x - i)[..., None]
        # Cubic B-spline weights of the nodes i-1 … i+2 and their derivatives, (P, 3, 4).
        b = np.concatenate([(1 - t) ** 3, 3 * t**3 - 6 * t**2 + 4, -3 * t**3 + 3 * t**2 + 3 * t + 1, t**3], -1) / 6
        db = np.concatenate([-((1 - t) ** 2), 3 * t**2 - 4 * t, -3 * t**2 + 2 * t + 1, t**2], -1) / 2
        k = i[..., None] - 1 + np.arange(4)  # (P, 3, 4)
        flat = (k[:, 0, :, None, None] * self.n + k[:, 1, None, :, None]) * self.n + k[:, 2, None, None, :]
        c = self.coeffs[flat.reshape(len(v), 64)]  # (P, 64 nodes, 4 channels)

        def outer(wx, wy, wz):
            return (wx[:, :, None, None] * wy[:, None, :, None] * wz[:, None, None, :]).reshape(-1, 64)

        (bx, by, bz), (dx, dy, dz) = np.moveaxis(b, 1, 0), np.moveaxis(db, 1, 0)
        weights = np.stack([outer(bx, by, bz), outer(dx, by, bz), outer(bx, dy, bz), outer(bx, by, dz)], 1)
        out = weights @ c  # (P, 1 + 3 derivatives, channels)
        value, grad = out[:, 0], np.swapaxes(out[:, 1:], 1, 2)
        return value, grad / self.step


@lru_cache(maxsize=1)
def _table() -> _Table:
    return _Table(model_path(TABLE_FILE))


def max_concentration() -> float:
    """The largest ``|z_i|`` the table covers."""
    return _table().z_max


def check_concentration(z, name: str) -> np.ndarray:
    """``(z1, z2, z3)`` of ``Z = diag(z1, z2, z3, 0)``: three finite values in [−z_max, 0)."""
    z = np.asarray(z, dtype=float)
    if z.shape == (4,):
        if z[3] != 0.0:
            raise ValueError(f"{name}: the last concentration must be 0, got {z[3]}")
        z = z[:3]
    if z.shape != (3,) or not np.all(np.isfinite(z)) or np.any(z >= 0) or np.any(z < -max_concentration()):
        raise ValueError(f"{name} must hold three values in [-{max_concentration():g}, 0), got {z}")
    return z


def clamp_concentration(z: np.ndarray) -> np.ndarray:
    """Concentrations limited to the table's range (a floor on the spread, ~0.26° at 1e5)."""
    return np.clip(z, -_table().z_max, 0.0)


def normaliser(z: np.ndarray) -> np.ndarray:
    """Normalisation constant ``F(Z)`` (C.2) from the lookup table (§C.1.1)."""
    return np.exp(log_normaliser(z))


def log_normaliser(z: np.ndarray) -> np.ndarray:
    """``log F(Z)``, straight from the table (no overflow for concentrated densities)."""
    return _table().lookup(z)[..., 0]


def moments(z: np.ndarray) -> np.ndarray:
    """``(∂F/∂z_i)/F`` for i = 1..4, ``(..., 4)``: the diagonal of (C.6); they sum to one."""
    m = np.exp(_table().lookup(z)[..., 1:])
    return np.concatenate([m, 1.0 - m.sum(axis=-1, keepdims=True)], axis=-1)


def normaliser_gradient(z: np.ndarray) -> np.ndarray:
    """``∇F`` with respect to ``(z1, z2, z3, z4)`` at ``z4 = 0``, ``(..., 4)`` (§C.1.1)."""
    return normaliser(z)[..., None] * moments(z)


def density(q: np.ndarray, m: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Bingham density (C.1) of unit quaternions ``q (..., 4)``."""
    proj = np.einsum("...i,...ij->...j", q, m)
    expo = np.sum(proj[..., :3] ** 2 * z, axis=-1)
    return np.exp(expo) / normaliser(z)


def mode(m: np.ndarray) -> np.ndarray:
    """Mode of the distribution: the last column of ``M`` (§C.1), sign-canonical (w ≥ 0)."""
    q = m[..., :, 3]
    return np.where(q[..., 3:4] < 0.0, -q, q)


def frame(q: np.ndarray) -> np.ndarray:
    """An orthogonal ``M`` whose last column is ``q``: columns ``q ⊗ e_x, q ⊗ e_y, q ⊗ e_z, q``."""
    return np.swapaxes(quat_multiply(np.asarray(q, dtype=float)[..., None, :], _IDENTITY4), -1, -2)


def _from_exponent(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(M, z)`` of ``exp(qᵀ C q)``: ascending eigenvectors, eigenvalues shifted to end at 0."""
    d, v = np.linalg.eigh(0.5 * (c + np.swapaxes(c, -1, -2)))
    return v, np.minimum(d[..., :3] - d[..., 3:], 0.0)


def _scaled_gram(m: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``M diag(d) Mᵀ`` for ``m (..., 4, k)``, ``d (..., k)``."""
    return (m * d[..., None, :]) @ np.swapaxes(m, -1, -2)


def product(m1: np.ndarray, z1: np.ndarray, m2: np.ndarray, z2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bingham product (C.3): eigen-decomposition of ``M1 Z1 M1ᵀ + M2 Z2 M2ᵀ``."""
    c = _scaled_gram(m1[..., :3], z1) + _scaled_gram(m2[..., :3], z2)
    return _from_exponent(c)


def product_log_evidence(m1: np.ndarray, z1: np.ndarray, m2: np.ndarray, z2: np.ndarray) -> np.ndarray:
    """``log ∫ P_B(x; M1, Z1) P_B(x; M2, Z2) dx`` over S³: how well two densities agree.

    The integrand is the unnormalised product (C.3), ``exp(xᵀCx)`` with ``C = Σ Mᵢ Zᵢ Mᵢᵀ``;
    its integral is ``exp(λ_max) F(λ − λ_max)`` over the eigenvalues ``λ`` of ``C``.
    """
    lam = np.linalg.eigvalsh(_scaled_gram(m1[..., :3], z1) + _scaled_gram(m2[..., :3], z2))
    z = clamp_concentration(lam[..., :3] - lam[..., 3:])
    return lam[..., 3] + log_normaliser(z) - log_normaliser(z1) - log_normaliser(z2)


def rotate(m: np.ndarray, g: np.ndarray, side: str = "right") -> np.ndarray:
    """Rotation by a quaternion (C.4): columns ``m_j ⊗ g`` (``side='right'``) or ``g ⊗ m_j``."""
    cols = np.swapaxes(m, -1, -2)
    g = np.asarray(g, dtype=float)[..., None, :]
    if side == "right":
        out = quat_multiply(cols, g)
    elif side == "left":
        out = quat_multiply(g, cols)
    else:
        raise ValueError(f"side must be 'right' or 'left', got {side!r}")
    return np.swapaxes(out, -1, -2)


def covariance(m: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Covariance ``E[q qᵀ] = M diag(∇F/F) Mᵀ`` (C.5)–(C.6)."""
    return _scaled_gram(m, moments(z))


def compose_covariance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Composition covariance ``E[(q1⊗q2)(q1⊗q2)ᵀ]`` by the method of moments (C.7).

    ``a = E[q1 q1ᵀ]``, ``b = E[q2 q2ᵀ]`` of independent ``q1, q2``. With ``q1 ⊗ q2 = R(q2) q1``
    and ``R`` linear in ``q2``, the result is ``Σ_kl b_kl R_k a R_lᵀ`` — the entries of (C.7)
    written for our component order.
    """
    a, b = np.broadcast_arrays(a, b)
    batch = a.shape[:-2]
    blocks = (_RIGHT @ a @ _RIGHT.T).reshape(batch + (4, 4, 4, 4))  # [k, i, l, n] = (R_k a R_lᵀ)_in
    blocks = np.moveaxis(blocks, (-4, -2), (-2, -1)).reshape(batch + (16, 16))  # [(i, n), (k, l)]
    return (blocks @ b.reshape(batch + (16, 1))).reshape(batch + (4, 4))


def scatter(q: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Inertia (scatter) matrix ``S = Σ w_i q_i q_iᵀ`` (C.8) of samples ``q (..., n, 4)``."""
    if weights is None:
        weights = np.full(q.shape[:-1], 1.0 / q.shape[-2])
    return weighted_outer(weights, q, q)


def mean_rotation(q: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Mean of the unit quaternions ``q (n, 4)``: the mode of the Bingham fitted to them
    (C.8)–(C.9), i.e. the principal eigenvector of their scatter matrix, sign-canonical (w ≥ 0);
    ``q`` and ``−q`` count alike."""
    mean = np.linalg.eigh(scatter(q, weights))[1][:, -1]
    return -mean if mean[3] < 0.0 else mean


def weighted_outer(w: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``Σ_n w_n x_n y_nᵀ`` over the second-to-last axis (a batched matrix product)."""
    return np.swapaxes(x * w[..., None], -1, -2) @ y


def fit(s: np.ndarray, iterations: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """Maximum-likelihood ``(M, z)`` from a scatter matrix (C.8)–(C.9).

    ``M`` holds the eigenvectors of ``S``; ``z`` solves ``(∂F/∂z_i)/F = κ_iᵀ S κ_i`` (C.9) by a
    batched Newton iteration on ``v = log(1 + |z|)`` over the table (instead of COBYLA).
    Concentrations beyond the table are clamped to its range.
    """
    d, m = np.linalg.eigh(0.5 * (s + np.swapaxes(s, -1, -2)))
    d = np.maximum(d, 1e-300)
    target = np.log(d[..., :3] / d.sum(axis=-1, keepdims=True)).reshape(-1, 3)
    return m, _solve_moments(target, iterations).reshape(d.shape[:-1] + (3,))


def _solve_moments(log_target: np.ndarray, iterations: int) -> np.ndarray:
    """``z (N, 3)`` with ``log m_i(z) = log_target`` (Newton on the spline's exact Jacobian)."""
    if not len(log_target):
        return np.empty((0, 3))
    table = _table()
    v_max = np.log1p(table.z_max)
    # Start from the concentrated-limit m_i ≈ 1/(4 + 2|z_i|).
    v = np.clip(np.log1p(np.maximum(0.5 / np.exp(log_target) - 2.0, 0.0)), 0.0, v_max)
    for _ in range(iterations):
        value, grad = table.evaluate(v)
        step = np.linalg.solve(grad[:, 1:] + 1e-12 * np.eye(3), (value[:, 1:] - log_target)[..., None])[..., 0]
        v_new = np.clip(v - np.clip(step, -2.0, 2.0), 0.0, v_max)
        done = np.max(np.abs(v_new - v)) < 1e-9
        v = v_new
        if done:
            break
    return np.maximum(-np.expm1(v), -table.z_max)


def sample(m: np.ndarray, z: np.ndarray, n: int, rng: np.random.Generator, burn_in: int = 30) -> np.ndarray:
    """``n`` samples ``(n, 4)`` by Metropolis–Hastings (§C.1.6).

    ``n`` independent chains run in parallel; the proposal is the projected zero-mean Gaussian
    with covariance ``S`` (C.6) (the angular central Gaussian, density ∝ (qᵀS⁻¹q)⁻²), the
    target the Bingham density (C.1); each chain's state after ``burn_in`` steps is returned.
    """
    s = covariance(m, z)
    chol = np.linalg.cholesky(s)
    s_inv = np.linalg.inv(s)
    c = np.einsum("ik,k,jk->ij", m[:, :3], z, m[:, :3])

    def propose():
        x = rng.standard_normal((n, 4)) @ chol.T
        x /= np.linalg.norm(x, axis=-1, keepdims=True)
        # log target − log proposal, up to constants
        return x, np.einsum("ni,ij,nj->n", x, c, x) + 2.0 * np.log(np.einsum("ni,ij,nj->n", x, s_inv, x))

    q, log_r = propose()
    for _ in range(burn_in):
        cand, cand_log_r = propose()
        accept = np.log(rng.uniform(size=n)) < cand_log_r - log_r
        q = np.where(accept[:, None], cand, q)
        log_r = np.where(accept, cand_log_r, log_r)
    return q


def sigma_points(m: np.ndarray, z: np.ndarray, n_total: int = 14) -> tuple[np.ndarray, np.ndarray]:
    """Deterministic sigma points ``(..., 7, 4)`` and weights ``(..., 7)`` (Appendix D).

    Canonical points (D.1)–(D.4) with angles (D.6) and weights (D.7)–(D.10), mapped by ``M``.
    Of each antipodal pair of the thesis's ``4d − 2 = 14`` points only the one in the mode's
    hemisphere is kept, carrying the pair's weight; the point at the mode, which has no pair
    there, keeps its own (the thesis's weights sum to ``1 + f₄/N``), so the weights sum to one
    and ``Σ w q qᵀ`` equals the covariance (C.6) exactly.
    """
    f = moments(z)
    w_b = f[..., :3] + (1.0 - 1.0 / n_total) * f[..., 3:4] / 3.0  # w_Bi of (D.6)–(D.9)
    alpha = np.arcsin(np.sqrt(np.clip(f[..., :3] / w_b, 0.0, 1.0)))  # (D.6)
    shape = f.shape[:-1]
    canon = np.zeros(shape + (7, 4))
    for i in range(3):
        canon[..., 2 * i, i] = np.sin(alpha[..., i])
        canon[..., 2 * i + 1, i] = -np.sin(alpha[..., i])
        canon[..., 2 * i : 2 * i + 2, 3] = np.cos(alpha[..., i])[..., None]
    canon[..., 6, 3] = 1.0  # (D.4)
    weights = np.concatenate([np.repeat(w_b / 2.0, 2, axis=-1), f[..., 3:4] / n_total], axis=-1)
    return canon @ np.swapaxes(m, -1, -2), weights


def tangent_covariance(q: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Covariance ``(..., 3, 3)`` of the small-angle error ``2·vec(q̄ ⊗ x)`` where ``E[xxᵀ] = s``.

    The components of ``vec(q̄ ⊗ x)`` are ``(q ⊗ e_k)·x``, so the result is ``4 Tᵀ S T`` with the
    tangent basis ``T = [q ⊗ e_x, q ⊗ e_y, q ⊗ e_z]``.
    """
    t = frame(q)[..., :3]
    return 4.0 * np.swapaxes(t, -1, -2) @ s @ t


def small_rotation_moment(sigma: np.ndarray) -> np.ndarray:
    """``E[e eᵀ]`` of ``e = [θ/2, √(1 − |θ|²/4)]``, ``θ`` a rotation vector of covariance ``sigma``.

    To second order: ``diag-block(Σ/4, 1 − tr Σ/4)``, the inverse of :func:`tangent_covariance`.
    """
    out = np.zeros(sigma.shape[:-2] + (4, 4))
    out[..., :3, :3] = sigma / 4.0
    out[..., 3, 3] = np.clip(1.0 - np.trace(sigma, axis1=-2, axis2=-1) / 4.0, 1e-6, 1.0)
    return out


def noise_frame_at(z_meas: np.ndarray, m_noise: np.ndarray) -> np.ndarray:
    """Measurement noise rotated onto the measurement (5.3): columns ``z ⊗ m̄_j``.

    For ``z = q ⊗ Λ``, ``m_jᵀ(q̄ ⊗ z) = (z ⊗ m̄_j)ᵀ q``, so the likelihood ``P_B(q̄ ⊗ z; M, Z)``
    is the Bingham ``P_B(q; M̌, Z)`` in ``q``.
    """
    cols = quat_conjugate(np.swapaxes(m_noise, -1, -2))
    return np.swapaxes(quat_multiply(np.asarray(z_meas, dtype=float)[..., None, :], cols), -1, -2)
