"""Triangle meshes of the UAV in its body frame (REP 103 FLU: x forward, y left, z up, metres)."""

from dataclasses import dataclass

import numpy as np


class MeshError(ValueError):
    """A mesh file or array that cannot serve as the UAV model."""


@dataclass(frozen=True)
class Mesh:
    """Vertices ``(V, 3)`` float32 and faces ``(F, 3)`` int32, counter-clockwise seen from outside."""

    vertices: np.ndarray
    faces: np.ndarray

    def __post_init__(self):
        vertices = np.ascontiguousarray(self.vertices, dtype=np.float32)
        faces = np.ascontiguousarray(self.faces, dtype=np.int32)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
            raise MeshError(f"expected vertices (V,3) and faces (F,3), got {vertices.shape} and {faces.shape}")
        if len(faces) and (faces.min() < 0 or faces.max() >= len(vertices)):
            raise MeshError("face indices out of range of the vertex array")
        if not np.all(np.isfinite(vertices)):
            raise MeshError("vertex coordinates must be finite")
        object.__setattr__(self, "vertices", vertices)
        object.__setattr__(self, "faces", faces)

    @property
    def triangle_count(self) -> int:
        return int(len(self.faces))

    @property
    def bounds(self) -> np.ndarray:
        """``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` in metres."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)]).astype(float)

    @property
    def extents(self) -> np.ndarray:
        """Size along x, y, z in metres."""
        b = self.bounds
        return b[1] - b[0]

    @property
    def is_closed(self) -> bool:
        """Every directed edge appears exactly once and its reverse exactly once.

        This means watertight (each edge shared by two faces) and consistently wound, which is
        what makes back-face culling leave the silhouette unchanged.
        """
        f = self.faces.astype(np.int64)
        directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        n = len(self.vertices)
        keys = directed[:, 0] * n + directed[:, 1]
        reverse = directed[:, 1] * n + directed[:, 0]
        unique, counts = np.unique(keys, return_counts=True)
        if len(unique) != len(keys) or np.any(counts != 1):
            return False
        return bool(np.all(np.isin(reverse, unique)))

    @property
    def signed_volume(self) -> float:
        """Enclosed volume in m³ (positive for outward normals on a closed mesh)."""
        v = self.vertices.astype(float)[self.faces]
        return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)
