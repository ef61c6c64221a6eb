"""Tracking core: the particle set, resampling (App. B) and pose optimisation (§5.5)."""

from .optimisation import (
    PFO,
    PSO,
    SECTION_6_6_NOISE,
    ConstrictedPSO,
    ConstrictedPSOConfig,
    GAbF,
    GAbFConfig,
    Objective,
    PFOConfig,
    PSOConfig,
    evaluate,
    pfo_noise,
)
from .particles import ParticleSet
from .resampling import RESAMPLERS, Resampled, fixed_size, resample

__all__ = [
    "PFO",
    "PSO",
    "RESAMPLERS",
    "SECTION_6_6_NOISE",
    "ConstrictedPSO",
    "ConstrictedPSOConfig",
    "GAbF",
    "GAbFConfig",
    "Objective",
    "PFOConfig",
    "PSOConfig",
    "ParticleSet",
    "Resampled",
    "evaluate",
    "fixed_size",
    "pfo_noise",
    "resample",
]
