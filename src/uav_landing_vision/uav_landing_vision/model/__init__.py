"""The UAV model: a parametric fixed-wing mesh (Table 1.1) and CAD-file loading."""

from .fixed_wing import CHORD, LENGTH, LEVELS, SPAN, fixed_wing_mesh
from .loader import load_mesh
from .mesh import Mesh, MeshError

__all__ = ["CHORD", "LENGTH", "LEVELS", "SPAN", "Mesh", "MeshError", "fixed_wing_mesh", "load_mesh"]
