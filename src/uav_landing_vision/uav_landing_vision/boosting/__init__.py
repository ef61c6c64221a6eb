"""Pose boosting (§4.3): OBB of the UAV in a frame, pose database, pose hypotheses."""

from .database import (
    ASPECT_WEIGHT,
    FULL_SPHERE_DEG,
    NOMINAL_QUAT,
    DatabaseConfig,
    DatabaseError,
    PoseDatabase,
    build_database,
    mesh_fingerprint,
    obb_distance,
    sample_orientations,
)
from .hypotheses import (
    HypothesisConfig,
    Hypotheses,
    PoseHypothesisGenerator,
    hypotheses_from_obb,
    weak_perspective_depth,
    weak_perspective_position,
)
from .obb import FastConfig, Obb, aspect_ratio, obb_from_frame, obb_from_mask, obb_from_points

__all__ = [
    "ASPECT_WEIGHT",
    "FULL_SPHERE_DEG",
    "NOMINAL_QUAT",
    "DatabaseConfig",
    "DatabaseError",
    "FastConfig",
    "Hypotheses",
    "HypothesisConfig",
    "Obb",
    "PoseDatabase",
    "PoseHypothesisGenerator",
    "aspect_ratio",
    "build_database",
    "hypotheses_from_obb",
    "mesh_fingerprint",
    "obb_distance",
    "obb_from_frame",
    "obb_from_mask",
    "obb_from_points",
    "sample_orientations",
    "weak_perspective_depth",
    "weak_perspective_position",
]
