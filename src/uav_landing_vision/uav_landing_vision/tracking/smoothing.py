"""Ours (not in the thesis): the published rotation averaged over the last few frames.

From one frame to the next the tracker's rotation estimate moves by more than 5° in over half
of the frames of the simulated landings, while the airframe turns by about 1° (at most ~5°).
That jitter is estimation noise, and the mean of the last few estimates (four shipped) has a
lower error than the last one alone (docs/tracking.md, "Rotation window"). An estimate that
turns by more than ``max_turn_deg`` from the last one starts the window afresh: averaging across
such a jump (a whole-set flip, a re-acquired track) would publish a rotation that no frame
estimated. Positions are not averaged: their errors are biases that persist over many frames,
not jitter.
"""

from collections import deque

import numpy as np

from ..filters.bingham import mean_rotation
from ..geometry import geodesic_angle


class RotationWindow:
    """The mean rotation of the last ``frames`` estimates, back to the last gap of more than
    ``max_step_s`` or turn of more than ``max_turn_deg`` between consecutive estimates: the mode
    of the Bingham fitted to them (C.8)–(C.9), so ``q`` and ``−q`` count alike. ``frames = 1``
    passes every estimate through."""

    def __init__(self, frames: int, max_step_s: float, max_turn_deg: float = np.inf):
        if int(frames) != frames or frames < 1:
            raise ValueError(f"frames must be a positive integer, got {frames!r}")
        if not (np.isfinite(max_step_s) and max_step_s > 0):
            raise ValueError(f"max_step_s must be positive, got {max_step_s!r}")
        if not max_turn_deg > 0:
            raise ValueError(f"max_turn_deg must be positive, got {max_turn_deg!r}")
        self.frames = int(frames)
        self.max_step_ns = max_step_s * 1e9
        self.max_turn = np.radians(max_turn_deg)
        self._recent: deque[tuple[int, np.ndarray]] = deque(maxlen=self.frames)

    def reset(self) -> None:
        """Forget the past estimates (a lost track, or a frame without an estimate)."""
        self._recent.clear()

    def __call__(self, stamp_ns: int, quat: np.ndarray) -> np.ndarray:
        """Add the estimate of ``stamp_ns`` and return the published rotation."""
        quat = np.asarray(quat, float)
        if self._recent and stamp_ns <= self._recent[-1][0]:
            raise ValueError(f"stamp {stamp_ns} ns is not after the last one ({self._recent[-1][0]} ns)")
        if self._recent and (stamp_ns - self._recent[-1][0] > self.max_step_ns
                             or geodesic_angle(quat[None], self._recent[-1][1])[0] > self.max_turn):
            self._recent.clear()
        self._recent.append((int(stamp_ns), quat))
        if len(self._recent) == 1:
            return quat.copy()
        return mean_rotation(np.array([q for _, q in self._recent]))
