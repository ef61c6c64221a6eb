"""Pose errors and their statistics in the rows of the thesis's error tables (Tables 6.2–6.24).

Rows: 5/25/50/75/95 % percentiles, outlier % (outside 1.5 × IQR of the quartiles), MAE,
RMSE and SD. The thesis tables print an RMSE smaller than the MAE, which no data set can have;
``rmse`` here is the true root mean square (DESIGN §3). Percentiles are numpy's linear
interpolation; SD is the sample standard deviation (n − 1), undefined (NaN) for one value.
"""

import numpy as np

from ..geometry import euler_error, geodesic_angle

STAT_KEYS = ("p5", "p25", "median", "p75", "p95", "outlier_pct", "mae", "rmse", "sd")
ROW_NAMES = {
    "p5": "5% Percentile", "p25": "25% Percentile", "median": "Median", "p75": "75% Percentile",
    "p95": "95% Percentile", "outlier_pct": "Outlier %", "mae": "MAE", "rmse": "RMSE", "sd": "SD",
}
TRANSLATION_COLUMNS = ("euclidean", "x", "y", "z")
ROTATION_COLUMNS = ("geodesic", "alpha", "beta", "gamma")


def error_statistics(values) -> dict[str, float]:
    """The table rows of one error series (NaNs are dropped; all-NaN gives NaNs)."""
    v = np.asarray(values, dtype=float).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {k: float("nan") for k in STAT_KEYS}
    p5, p25, p50, p75, p95 = np.percentile(v, [5, 25, 50, 75, 95])
    iqr = p75 - p25
    outliers = (v < p25 - 1.5 * iqr) | (v > p75 + 1.5 * iqr)
    return {
        "p5": float(p5), "p25": float(p25), "median": float(p50), "p75": float(p75), "p95": float(p95),
        "outlier_pct": float(100.0 * outliers.mean()),
        "mae": float(np.mean(np.abs(v))),
        "rmse": float(np.sqrt(np.mean(v * v))),
        "sd": float(np.std(v, ddof=1)) if v.size > 1 else float("nan"),  # one value: no spread to estimate
    }


def pose_errors(t_true, q_true, t_est, q_est) -> dict[str, np.ndarray]:
    """Per-frame errors of estimated poses: translation in m, rotation in degrees.

    ``euclidean`` ‖t̂ − t‖; ``x, y, z`` the signed coordinate differences t̂ − t; ``geodesic``
    the angle (3.3)/(6.3); ``alpha, beta, gamma`` the Z-Y-X Euler angles of q_e (6.4).
    Rows where the estimate's position or orientation is not finite are NaN in every column
    (lost frames).
    """
    t_true, t_est = np.asarray(t_true, float), np.asarray(t_est, float)
    q_true, q_est = np.asarray(q_true, float), np.asarray(q_est, float)
    ok = np.all(np.isfinite(q_est), axis=-1) & np.all(np.isfinite(t_est), axis=-1)
    diff = np.where(ok[:, None], t_est - t_true, np.nan)
    geo = np.full(len(q_true), np.nan)
    eul = np.full((len(q_true), 3), np.nan)
    if np.any(ok):
        geo[ok] = np.degrees(geodesic_angle(q_true[ok], q_est[ok]))
        eul[ok] = np.degrees(euler_error(q_true[ok], q_est[ok]))
    return {
        "euclidean": np.linalg.norm(diff, axis=-1), "x": diff[:, 0], "y": diff[:, 1], "z": diff[:, 2],
        "geodesic": geo, "alpha": eul[:, 0], "beta": eul[:, 1], "gamma": eul[:, 2],
    }
