"""Loading a CAD model (OBJ/STL/PLY) through trimesh, with unit and sanity checks.

Decision on open meshes: a mesh that is not watertight (or not consistently wound) still
gives correct silhouettes when drawn without back-face culling, so it is accepted with a
``UserWarning``; ``Mesh.is_closed`` is then False and the renderer turns culling off.
"""

import warnings
from pathlib import Path

import numpy as np
import trimesh

from .mesh import Mesh, MeshError

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
SUFFIXES = {".obj", ".stl", ".ply"}
MIN_EXTENT_M, MAX_EXTENT_M = 0.1, 20.0
TYPICAL_EXTENT_M = 2.0


def load_mesh(path, unit: str = "m") -> Mesh:
    """Read a UAV mesh, already in the body frame (FLU, origin at the CG), in ``unit``."""
    path = Path(path)
    if unit not in UNITS:
        raise MeshError(f"unknown unit {unit!r}; choose one of {sorted(UNITS)}")
    if not path.is_file():
        raise MeshError(f"mesh file not found: {path}")
    if path.suffix.lower() not in SUFFIXES:
        raise MeshError(f"unsupported mesh format {path.suffix!r} ({path}); use OBJ, STL or PLY")
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise MeshError(f"cannot read mesh file {path}: {exc}") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0 or len(loaded.vertices) == 0:
        raise MeshError(f"mesh file {path} holds no triangles")
    if loaded.faces.min() < 0 or loaded.faces.max() >= len(loaded.vertices):  # PLY: no relative indices
        raise MeshError(f"mesh file {path} has a face index out of range of its {len(loaded.vertices)} vertices")
    vertices = np.asarray(loaded.vertices, dtype=float)
    if not np.all(np.isfinite(vertices)):
        raise MeshError(f"mesh file {path} has non-finite vertex coordinates")
    loaded.merge_vertices(merge_tex=True)  # by position: STL corners, OBJ texture seams
    f = loaded.faces
    loaded.update_faces((f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0]))  # collapsed: no area
    vertices = np.asarray(loaded.vertices, dtype=float)
    size = float(np.ptp(vertices, axis=0).max())  # in the file's unit, as the area
    extent = size * UNITS[unit]
    if size > 0 and not MIN_EXTENT_M <= extent <= MAX_EXTENT_M:  # first: size² may overflow
        raise MeshError(_size_message(path, unit, extent))
    if loaded.area <= 1e-12 * size**2:  # zero up to rounding
        raise MeshError(f"mesh file {path} has no surface: every triangle is degenerate (zero area)")
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    if np.any(low > 1e-9 * size) or np.any(high < -1e-9 * size):  # a CG lies within the body's box
        raise MeshError(
            f"mesh {path} does not hold its own origin (its box spans {_span(low, high, unit)}): "
            "it is not in the body frame, whose origin is the UAV's centre of gravity"
        )
    if loaded.is_watertight:
        trimesh.repair.fix_normals(loaded, multibody=True)  # consistent, outward winding of every body
    mesh = Mesh(np.asarray(loaded.vertices) * UNITS[unit], np.asarray(loaded.faces))
    if not mesh.is_closed:
        warnings.warn(
            f"mesh {path} is not closed (watertight and consistently wound); "
            "silhouettes will be rendered without back-face culling",
            stacklevel=2,
        )
    return mesh


def _span(low, high, unit: str) -> str:
    return " × ".join(f"[{a:.4g}, {b:.4g}]" for a, b in zip(low, high)) + f" {unit}"


def _size_message(path: Path, unit: str, extent: float) -> str:
    raw = extent / UNITS[unit]
    fitting = [u for u, s in UNITS.items() if MIN_EXTENT_M <= raw * s <= MAX_EXTENT_M]
    # The unit that makes the model closest (in ratio) to a typical small UAV's size.
    best = min(fitting, key=lambda u: abs(np.log(raw * UNITS[u] / TYPICAL_EXTENT_M)), default=None)
    hint = f"; the file was probably in {best!r}" if best else ""
    return (
        f"mesh {path} is {extent:.4g} m across in unit {unit!r}, implausible for a UAV "
        f"(expected {MIN_EXTENT_M}–{MAX_EXTENT_M} m){hint}"
    )
