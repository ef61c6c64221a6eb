"""Parametric fixed-wing UAV with the thesis platform's dimensions (Table 1.1).

Length 1.2 m (nose at x=+0.45, tail at x=−0.75), wingspan 1.8 m, rectangular wing of
chord 0.24 m (area 0.432 m²) with a NACA 65-410-like section and 3° dihedral, a tailplane
and a fin. The body-frame origin is the centre of gravity, at 29 % of the wing chord.

Each part (fuselage, wing, tailplane, fin) is a closed, consistently wound solid; the parts
interpenetrate (no boolean union), so the whole mesh is closed — every edge is shared by
exactly two faces with opposite directions — and back-face culling cannot change its
silhouette. The 65-series section is approximated by the NACA 4-digit thickness law (10 %)
on the a=1.0 mean line with design lift coefficient 0.4.
"""

import numpy as np

from .mesh import Mesh, MeshError

LENGTH = 1.2
SPAN = 1.8
CHORD = 0.24

_NOSE_X = 0.45
_TAIL_X = _NOSE_X - LENGTH
_WING_LE_X = 0.07
_WING_Z = 0.03
_DIHEDRAL = np.radians(3.0)
_BODY_RADIUS = 0.065
_BOOM_RADIUS = 0.02

# level → (fuselage segments around, fuselage rings, wing chord stations, tail chord stations)
LEVELS = {"high": (32, 36, 41, 21), "low": (12, 18, 21, 9)}


def fixed_wing_mesh(level: str = "high") -> Mesh:
    """The UAV mesh: ``"high"`` (3 092 triangles) or ``"low"`` (788 triangles)."""
    if level not in LEVELS:
        raise MeshError(f"unknown level of detail {level!r}; choose one of {sorted(LEVELS)}")
    segments, rings, wing_n, tail_n = LEVELS[level]
    parts = [_fuselage(segments, rings), _wing(wing_n), _tailplane(tail_n), _fin(tail_n)]
    vertices, faces, offset = [], [], 0
    for v, f in parts:
        vertices.append(v)
        faces.append(f + offset)
        offset += len(v)
    return Mesh(np.concatenate(vertices), np.concatenate(faces))


def _airfoil(n: int, thickness: float, design_cl: float) -> np.ndarray:
    """Closed section loop ``(2n−2, 2)`` of (chordwise, normal) coordinates for unit chord.

    Loop order: trailing edge, upper surface to the leading edge, lower surface back.
    """
    x = 0.5 * (1.0 - np.cos(np.linspace(0.0, np.pi, n)))
    yt = 5 * thickness * (0.2969 * np.sqrt(x) - 0.1260 * x - 0.3516 * x**2 + 0.2843 * x**3 - 0.1036 * x**4)
    with np.errstate(divide="ignore", invalid="ignore"):
        xlx = np.where(x > 0, x * np.log(np.where(x > 0, x, 1.0)), 0.0)
        one = 1.0 - x
        olo = np.where(one > 0, one * np.log(np.where(one > 0, one, 1.0)), 0.0)
    yc = -design_cl / (4 * np.pi) * (olo + xlx)
    upper = np.stack([x, yc + yt], axis=1)[::-1]  # TE → LE
    lower = np.stack([x, yc - yt], axis=1)[1:-1]  # after LE → before TE
    return np.concatenate([upper, lower])


def _loft(sections: np.ndarray, start, end) -> tuple[np.ndarray, np.ndarray]:
    """Skin ``(S, P, 3)`` section loops and close both ends.

    A cap is either a pole point (3,) joined by a fan, or the string ``"airfoil"`` for a
    section loop laid out as by :func:`_airfoil`, closed by a strip between its surfaces.
    The result is wound outward (flipped if its signed volume is negative).
    """
    n_sec, p, _ = sections.shape
    vertices = [sections.reshape(-1, 3)]
    k = np.arange(p)
    k1 = (k + 1) % p
    faces = []
    for j in range(n_sec - 1):
        a, b = j * p + k, (j + 1) * p + k
        an, bn = j * p + k1, (j + 1) * p + k1
        faces += [np.stack([a, an, bn], 1), np.stack([a, bn, b], 1)]
    for cap, ring, flip in ((start, 0, False), (end, (n_sec - 1) * p, True)):
        if isinstance(cap, str):
            tris = _airfoil_cap(p) + ring
        else:
            pole = sum(len(v) for v in vertices)
            vertices.append(np.asarray(cap, dtype=float)[None])
            tris = np.stack([np.full(p, pole), ring + k1, ring + k], 1)
        faces.append(tris[:, ::-1] if flip else tris)
    vertices = np.concatenate(vertices)
    faces = np.concatenate(faces)
    v = vertices[faces]
    if np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() < 0:
        faces = faces[:, ::-1]
    return vertices, np.ascontiguousarray(faces)


def _airfoil_cap(p: int) -> np.ndarray:
    """Strip triangulation of an x-monotone airfoil loop of ``p = 2n−2`` points (loop-reversed)."""
    n = (p + 2) // 2
    i = np.arange(n)
    u = n - 1 - i  # upper surface, chordwise station i
    lo = (n - 1 + i) % p  # lower surface; shares the LE (i=0) and TE (i=n−1) with the upper
    tris = [[u[0], u[1], lo[1]]]
    for s in range(1, n - 2):
        tris += [[u[s], u[s + 1], lo[s + 1]], [u[s], lo[s + 1], lo[s]]]
    tris.append([u[n - 2], u[n - 1], lo[n - 2]])
    return np.array(tris)


def _fuselage(segments: int, rings: int):
    xi = 0.5 * (1.0 - np.cos(np.linspace(0.0, np.pi, rings + 2)[1:-1]))  # 0 nose … 1 tail
    radius = np.where(
        xi < 0.18,
        _BODY_RADIUS * np.sqrt(np.clip(1.0 - (1.0 - xi / 0.18) ** 2, 0.0, None)),
        _BODY_RADIUS,
    )
    taper = np.clip((xi - 0.45) / 0.25, 0.0, 1.0)
    smooth = taper * taper * (3 - 2 * taper)
    radius = np.where(xi >= 0.45, _BODY_RADIUS + (_BOOM_RADIUS - _BODY_RADIUS) * smooth, radius)
    end = np.clip((xi - 0.96) / 0.04, 0.0, 1.0)
    radius = np.where(xi > 0.96, _BOOM_RADIUS * np.sqrt(np.clip(1.0 - end**2, 0.0, None)), radius)
    phi = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    x = _NOSE_X - LENGTH * xi
    sections = np.stack(
        [
            np.broadcast_to(x[:, None], (rings, segments)),
            radius[:, None] * np.cos(phi),
            radius[:, None] * np.sin(phi),
        ],
        axis=-1,
    )
    return _loft(sections, [_NOSE_X, 0.0, 0.0], [_TAIL_X, 0.0, 0.0])


def _wing(n: int):
    loop = _airfoil(n, 0.10, 0.4)
    stations = np.array([-SPAN / 2, 0.0, SPAN / 2])
    sections = np.stack(
        [
            np.stack(
                [
                    _WING_LE_X - CHORD * loop[:, 0],
                    np.full(len(loop), y),
                    _WING_Z + abs(y) * np.tan(_DIHEDRAL) + CHORD * loop[:, 1],
                ],
                axis=1,
            )
            for y in stations
        ]
    )
    return _loft(sections, "airfoil", "airfoil")


def _tailplane(n: int):
    loop = _airfoil(n, 0.09, 0.0)
    chord, le_x = 0.12, -0.61
    sections = np.stack(
        [
            np.stack([le_x - chord * loop[:, 0], np.full(len(loop), y), chord * loop[:, 1]], axis=1)
            for y in (-0.25, 0.25)
        ]
    )
    return _loft(sections, "airfoil", "airfoil")


def _fin(n: int):
    loop = _airfoil(n, 0.09, 0.0)
    te_x = -0.73
    sections = []
    for z, chord in ((0.0, 0.14), (0.19, 0.08)):
        le_x = te_x + chord
        sections.append(np.stack([le_x - chord * loop[:, 0], chord * loop[:, 1], np.full(len(loop), z)], axis=1))
    return _loft(np.stack(sections), "airfoil", "airfoil")
