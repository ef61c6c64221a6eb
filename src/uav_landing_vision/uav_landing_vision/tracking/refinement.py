"""Ours (not in the thesis): a rotation-only local search of the published estimate.

The colour metric's peak at the true pose is a few degrees wide, and the PFO's §6.7.1 noise
(≈ 5° per axis per iteration) rarely lands on it. After the optimisation, the published
estimate's rotation is searched once more at its position: per stage, one batch of candidates
drawn about the current best rotation with that stage's σ, scored in one call (the start in
the first); the best candidate replaces the rotation when it scores higher. The position is not
searched and nothing is fed back to the particles or their filters: with feedback, or with
depth in the search, the track drifts to too-far depths, where the metric prefers short wings
that miss the faint tips (docs/tracking.md).

Across the line of sight the colour metric is sharper still. At the true pose beyond 60 m
(held-out landings), moving the silhouette half a pixel costs 16–21 % of the score, as much as a
random 5° turn, and one pixel about half of it. So a candidate rotation a fraction of a pixel
off in the image loses to a worse rotation that happens to sit on the UAV. With ``align_px`` > 0
each candidate is scored at the best of a cross of image shifts of its silhouette
(:meth:`SilhouetteLikelihood.score_shifted`, no further render); the published position stays.
"""

from dataclasses import dataclass

import numpy as np

from .optimisation import Objective, evaluate, rotate_body
from .particles import ParticleSet


@dataclass(frozen=True)
class RotationRefinementConfig:
    """``candidates`` per stage (0 = off, the thesis); ``sigma_deg``: each stage's σ per body axis;
    ``align_px``: step of the image shifts each candidate is scored at (0 = unshifted only)."""

    candidates: int = 0
    sigma_deg: tuple[float, ...] = (3.0,)
    align_px: float = 0.0

    def __post_init__(self):
        if isinstance(self.candidates, bool) or not (isinstance(self.candidates, int) and self.candidates >= 0):
            raise ValueError(f"refinement candidates must be a non-negative integer, got {self.candidates!r}")
        if not self.sigma_deg or not all(0 < s <= 180 for s in self.sigma_deg):
            raise ValueError(f"refinement sigma_deg must be non-empty and within (0, 180], got {self.sigma_deg!r}")
        if not (np.isfinite(self.align_px) and self.align_px >= 0.0):
            raise ValueError(f"refinement align_px must be non-negative, got {self.align_px!r}")

    @property
    def shifts(self) -> np.ndarray:
        """The image shifts ``(S, 2)`` in pixels: none, then ± ``align_px`` along x and y."""
        a = self.align_px
        if a == 0.0:
            return np.zeros((1, 2))
        return np.array([[0.0, 0.0], [-a, 0.0], [a, 0.0], [0.0, -a], [0.0, a]])


class RotationRefinement:
    """The search; ``refine`` is a no-op when ``candidates`` is 0."""

    def __init__(self, config: RotationRefinementConfig):
        self.config = config

    def refine(self, score: Objective, pos: np.ndarray, quat: np.ndarray,
               rng: np.random.Generator) -> tuple[np.ndarray, float | None]:
        """The best rotation found at ``pos`` (``quat`` itself unless beaten) and its score
        (None when the search is off)."""
        n = self.config.candidates
        best, best_score = np.array(quat, dtype=float), None
        if n == 0:
            return best, best_score
        for sigma in self.config.sigma_deg:
            turns = rng.normal(0.0, np.radians(sigma), (n, 3))
            quats = rotate_body(np.tile(best, (n, 1)), turns)
            if best_score is None:
                quats = np.vstack([best[None], quats])
            candidates = ParticleSet.from_poses(np.tile(np.asarray(pos, float), (len(quats), 1)), quats)
            scores = evaluate(score, candidates)
            k = int(np.argmax(scores))
            if best_score is None or scores[k] > best_score:
                best, best_score = candidates.quat[k], float(scores[k])
        return best, best_score
