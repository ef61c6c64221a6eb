"""Square image-space boxes around the projected model, one per pose (pure numpy).

Coordinates are OpenCV's continuous pixel coordinates: integer values are pixel centres, so
pixel (u, v) spans [u−½, u+½]×[v−½, v+½] and the image spans [−½, W−½]×[−½, H−½]. A box
``[x0, y0, x1, y1]`` gives its outer edges: tile pixel (row r, column c) of a T×T tile has
its centre at ``(x0 + (c+½)(x1−x0)/T, y0 + (r+½)(y1−y0)/T)``.
"""

import numpy as np

from ..geometry import quat_normalise, quat_to_matrix

NEAR = 0.05  # m: the near clipping plane; a pose with any hull point nearer is not visible


def pose_matrices(quats: np.ndarray, trans: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Validated ``(M,3,3)`` rotations and ``(M,3)`` translations (float64)."""
    quats = np.asarray(quats, dtype=float)
    trans = np.asarray(trans, dtype=float)
    if quats.ndim != 2 or quats.shape[1] != 4 or trans.shape != (len(quats), 3):
        raise ValueError(f"expected quats (M,4) and trans (M,3), got {quats.shape} and {trans.shape}")
    if not (np.all(np.isfinite(quats)) and np.all(np.isfinite(trans))):
        raise ValueError("poses must be finite")
    return quat_to_matrix(quat_normalise(quats)), trans


def project_points(K: np.ndarray, rot: np.ndarray, trans: np.ndarray, points: np.ndarray):
    """Camera-frame depth ``(M,N)`` and pixel coordinates ``(M,N,2)`` of body points ``(N,3)``.

    Elementwise arithmetic in a fixed order, so a pose's result does not depend on the batch.
    """
    p = [
        rot[:, None, i, 0] * points[None, :, 0]
        + rot[:, None, i, 1] * points[None, :, 1]
        + rot[:, None, i, 2] * points[None, :, 2]
        + trans[:, None, i]
        for i in range(3)
    ]
    z = p[2]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        u = (K[0, 0] * p[0] + K[0, 1] * p[1]) / z + K[0, 2]
        v = K[1, 1] * p[1] / z + K[1, 2]
    return z, np.stack([u, v], axis=-1)


def projected_roi(camera, vertices: np.ndarray, quat, trans):
    """ROI ``(x, y, w, h)`` of the model's vertices projected at one pose by ``camera`` (its
    ``K``, ``width`` and ``height``): pixels x … x+w−1 and y … y+h−1 are those the projected
    extent touches, clipped to the image; None when a vertex is behind the camera or the box is
    outside the image."""
    rot, t = pose_matrices(np.asarray(quat, float)[None], np.asarray(trans, float)[None])
    z, uv = project_points(camera.K, rot, t, np.asarray(vertices, float))
    if not (np.all(z > 0) and np.all(np.isfinite(uv))):
        return None
    size = [camera.width, camera.height]
    lo, hi = uv[0].min(axis=0) + 0.5, uv[0].max(axis=0) + 0.5  # pixel edges: pixel u spans [u, u+1)
    x0, y0 = np.floor(np.clip(lo, 0, size)).astype(int)
    x1, y1 = np.ceil(np.clip(hi, 0, size)).astype(int)
    return None if x1 <= x0 or y1 <= y0 else (int(x0), int(y0), int(x1 - x0), int(y1 - y0))


def tile_boxes(K, width: int, height: int, rot, trans, hull: np.ndarray, margin: float):
    """Square boxes ``(M,4)`` and visibility ``(M,)``.

    The box is centred on the projected bounding box of the hull points, its side the larger
    extent times ``1 + margin`` plus 2 px (so pixels whose centres lie on the extremes are
    inside). Not visible: a hull point nearer than :data:`NEAR` (box NaN), or the box outside
    the image.
    """
    z, uv = project_points(K, rot, trans, hull)
    in_front = z.min(axis=1) > NEAR
    lo = uv.min(axis=1)
    hi = uv.max(axis=1)
    centre = 0.5 * (lo + hi)
    half = 0.5 * (np.max(hi - lo, axis=1) * (1.0 + margin) + 2.0)
    boxes = np.concatenate([centre - half[:, None], centre + half[:, None]], axis=1)
    boxes[~in_front] = np.nan
    with np.errstate(invalid="ignore"):
        overlaps = (
            (boxes[:, 2] > -0.5) & (boxes[:, 0] < width - 0.5) & (boxes[:, 3] > -0.5) & (boxes[:, 1] < height - 0.5)
        )
    return boxes, in_front & overlaps
