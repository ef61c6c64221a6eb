"""Build the lookup table of the Bingham normalisation constant F(Z) on S³ (§C.1.1).

``Z = diag(z1, z2, z3, 0)`` with ``z_i ≤ 0``. The table holds ``log F`` and the log of the
moments ``m_i = (∂F/∂z_i)/F`` (i = 1..3) on a full cube over ``v_i = log(1 + |z_i|)``,
``0 ≤ |z_i| ≤ Z_MAX``; both are nearly linear in ``v`` (``F ∝ Π|z_i|^(-1/2)`` and
``m_i ≈ 1/(2|z_i|)`` for large ``|z|``), so cubic splines interpolate them accurately.

Each value is a one-dimensional integral: on the Hopf coordinates of S³,
``q = (√u cos φ1, √u sin φ1, √(1-u) cos φ2, √(1-u) sin φ2)``, the angles integrate to
modified Bessel functions and

    F = 2π² ∫₀¹ e^{(a+c)/2·u} I0((a−c)/2·u) · e^{b/2·(1−u)} I0(b/2·(1−u)) du

for ``(z1, z2, z3) = (a, c, b)``; the derivatives add ``u/2·(1 ± I1/I0)`` factors. The
integral is done with Gauss–Legendre panels graded towards both ends (the integrand has
features of width ``1/|z|`` there), with exponentially scaled Bessel functions.

The shipped ``models/bingham_normalisation.npz`` was made by::

    python -m uav_landing_vision.filters.bingham_table \\
        src/uav_landing_vision/models/bingham_normalisation.npz
"""

import argparse
import itertools

import numpy as np
from scipy.special import ive

Z_MAX = 1.0e5
GRID_SIZE = 48
PAD = 6
_GL_NODES = 32


def _nodes() -> tuple[np.ndarray, np.ndarray]:
    """Quadrature nodes and weights on [0, 1], graded geometrically towards 0 and 1."""
    inner = 10.0 ** np.arange(-8, 0)  # 1e-8 … 1e-1
    breaks = np.unique(np.concatenate([[0.0], inner, [0.5], 1.0 - inner[::-1], [1.0]]))
    x, w = np.polynomial.legendre.leggauss(_GL_NODES)
    lo, hi = breaks[:-1, None], breaks[1:, None]
    return (lo + (hi - lo) * (x + 1) / 2).ravel(), ((hi - lo) * w / 2).ravel()


def normaliser_and_moments(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``F(Z)`` and the moments ``(∂F/∂z_i)/F`` (i = 1..3) by quadrature, ``z (N, 3)``.

    Accurate for ``z_i ≤ 0`` and for small positive ``z_i`` (the table's padding cells).
    """
    z = np.asarray(z, dtype=float)
    u, w = _nodes()
    a, c, b = z[:, 0:1], z[:, 1:2], z[:, 2:3]
    s, t = u[None, :], 1.0 - u[None, :]
    # e^{(a+c)/2·u} I0((a−c)/2·u) = e^{max(a,c)·u} ive(0, |a−c|/2·u); likewise for (b, 0).
    x1, x2 = 0.5 * np.abs(a - c) * s, 0.5 * np.abs(b) * t
    e1, e2 = np.exp(np.maximum(a, c) * s), np.exp(np.where(b < 0, 0.0, b) * t)
    i10, i11 = ive(0, x1), ive(1, x1)
    i20, i21 = ive(0, x2), ive(1, x2)
    base = e1 * e2 * i10 * i20
    # For a < c the ratio I1/I0 enters the z1-derivative with a minus sign (I1 is odd).
    sign1 = np.where(a <= c, -1.0, 1.0)
    d_a = 0.5 * s * (base + sign1 * e1 * e2 * i11 * i20)
    d_c = 0.5 * s * (base - sign1 * e1 * e2 * i11 * i20)
    d_b = 0.5 * t * (base + np.sign(b) * e1 * e2 * i10 * i21)
    f = 2.0 * np.pi**2 * base @ w
    df = 2.0 * np.pi**2 * np.stack([d_a @ w, d_c @ w, d_b @ w], axis=-1)
    return f, df / f[:, None]


def build(grid_size: int = GRID_SIZE, z_max: float = Z_MAX) -> dict[str, np.ndarray]:
    """The table arrays: axis ``v``, ``log_f (n, n, n)`` and ``log_m (n, n, n, 3)``.

    The axis runs ``PAD`` cells past both ends of ``[0, log(1 + z_max)]`` so that the spline's
    boundary condition only affects cells outside the valid range.
    """
    step = np.log1p(z_max) / (grid_size - 1)
    v = step * np.arange(-PAD, grid_size + PAD)
    grid_size += 2 * PAD
    zs = -np.expm1(v)
    # F is symmetric in (z1, z2, z3): compute each sorted triple once, then fill permutations.
    triples = np.array(list(itertools.combinations_with_replacement(range(grid_size), 3)))
    parts = [normaliser_and_moments(zs[chunk]) for chunk in np.array_split(triples, len(triples) // 1000 + 1)]
    f, m = np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
    log_f = np.empty((grid_size,) * 3)
    log_m = np.empty((grid_size,) * 3 + (3,))
    for perm in itertools.permutations(range(3)):
        idx = tuple(triples[:, p] for p in perm)
        log_f[idx] = np.log(f)
        log_m[idx] = np.log(m[:, list(perm)])
    return {"v": v, "log_f": log_f, "log_m": log_m, "z_max": np.array(z_max)}


def main(argv: list[str] | None = None) -> int:
    """Command line: build the table and write it to an ``.npz`` file."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("output", help="path of the .npz file to write")
    parser.add_argument("--grid-size", type=int, default=GRID_SIZE)
    parser.add_argument("--z-max", type=float, default=Z_MAX)
    args = parser.parse_args(argv)
    if args.grid_size < 8 or not 0 < args.z_max < np.inf:
        parser.error("need --grid-size >= 8 and a finite --z-max > 0")
    table = {k: np.asarray(a, dtype=np.float32) for k, a in build(args.grid_size, args.z_max).items()}
    made_by = "python -m uav_landing_vision.filters.bingham_table OUTPUT"
    made_by += f" --grid-size {args.grid_size} --z-max {args.z_max:g}"
    np.savez_compressed(args.output, made_by=np.array(made_by), **table)
    print(f"wrote {args.output}: {args.grid_size}³ grid, |z| ≤ {args.z_max:g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
