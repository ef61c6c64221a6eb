"""Tracking core: the particle set, resampling (App. B) and pose optimisation (§5.5)."""

from .optimisation import (
    PFO,
    PSO,
    ConstrictedPSO,
    ConstrictedPSOConfig,
    GAbF,
    GAbFConfig,
    PFOConfig,
    PSOConfig,
    pfo_noise,
)
from .particles import ParticleSet
from .resampling import RESAMPLERS, Resampled, fixed_size, resample

__all__ = [
    "PFO",
    "PSO",
    "RESAMPLERS",
    "ConstrictedPSO",
    "ConstrictedPSOConfig",
    "GAbF",
    "GAbFConfig",
    "PFOConfig",
    "PSOConfig",
    "ParticleSet",
    "Resampled",
    "fixed_size",
    "pfo_noise",
    "resample",
]
