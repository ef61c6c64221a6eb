"""Track health: ACQUIRING → TRACKING → LOST from the best likelihood of each frame.

The thesis runs the filter blind; a landing UAV needs to know when the estimate is worthless.
Rules, checked once per frame on the best particle's likelihood ``b``:

- after (re)initialisation from pose boosting the track is ACQUIRING;
- ACQUIRING → TRACKING after ``acquire_frames`` consecutive frames with ``b ≥ acquire_likelihood``;
- TRACKING → ACQUIRING once the track has coasted ``max_coast_frames`` frame intervals (Δt)
  without boosted hypotheses (0: never), and no frame counts toward TRACKING until hypotheses
  return: a scene without the UAV can score high (a horizon edge under the colour metric), so
  without fresh evidence from the detector and boosting the estimate is not vouched for;
- likewise once the tracked frames have been pixel for pixel the frame before them over
  ``max_repeated_frames`` frame intervals (0: never), until the picture changes: a live camera's
  sensor noise never repeats a frame, but a frozen camera or driver re-sending its last picture
  with new stamps does, and the track would hold the UAV still, and say TRACKING, while the
  aircraft flies on;
- TRACKING → ACQUIRING at the first frame with ``b < lost_likelihood``: the tracker's own score
  says that frame's pose is not the UAV, and the GCS bridge takes only TRACKING poses (it went
  on sending them for ``lost_frames − 1`` such frames);
- any state → LOST after ``lost_frames`` consecutive frames with ``b < lost_likelihood``, or at
  once when there is nothing to track (no particles and no hypotheses). LOST drops the
  particles; the next frame with hypotheses re-initialises the filter (ACQUIRING again).

State numbers are those of ``uav_landing_msgs/TrackerStatus``.
"""

from dataclasses import dataclass
from enum import IntEnum


class TrackState(IntEnum):
    LOST = 0
    ACQUIRING = 1
    TRACKING = 2


@dataclass(frozen=True)
class TrackStateConfig:
    """Thresholds on the colour metric (5.14) in [0, 1] by default (see ``config/tracker.yaml``)."""

    acquire_likelihood: float = 0.25
    acquire_frames: int = 3
    lost_likelihood: float = 0.08
    lost_frames: int = 5
    max_coast_frames: int = 15
    max_repeated_frames: int = 3

    def __post_init__(self):
        if not 0.0 <= self.lost_likelihood < self.acquire_likelihood:
            raise ValueError("track_state: need 0 <= lost_likelihood < acquire_likelihood")
        if self.acquire_frames < 1 or self.lost_frames < 1:
            raise ValueError("track_state: acquire_frames and lost_frames must be at least 1")
        for name in ("max_coast_frames", "max_repeated_frames"):
            if getattr(self, name) < 0:
                raise ValueError(f"track_state: {name} must be non-negative, got {getattr(self, name)}")


class TrackMonitor:
    """The state machine above; :meth:`update` once per tracked frame."""

    def __init__(self, config: TrackStateConfig = TrackStateConfig()):
        self.config = config
        self.state = TrackState.LOST
        self._good = self._bad = 0

    def initialised(self) -> None:
        """The filter was (re)initialised from pose boosting."""
        self.state, self._good, self._bad = TrackState.ACQUIRING, 0, 0

    def lost(self) -> TrackState:
        """Nothing left to track."""
        self.state, self._good, self._bad = TrackState.LOST, 0, 0
        return self.state

    def update(self, best_likelihood: float, coasting: int = 0, repeated: int = 0) -> TrackState:
        """The state after a frame whose best particle scored ``best_likelihood``, the track
        having coasted ``coasting`` frame intervals without boosted hypotheses, and the tracked
        frames having repeated the one before them over ``repeated`` frame intervals."""
        cfg = self.config
        unconfirmed = 0 < cfg.max_coast_frames <= coasting or 0 < cfg.max_repeated_frames <= repeated
        self._bad = self._bad + 1 if best_likelihood < cfg.lost_likelihood else 0
        self._good = self._good + 1 if best_likelihood >= cfg.acquire_likelihood and not unconfirmed else 0
        if self._bad >= cfg.lost_frames:
            return self.lost()
        if (unconfirmed or self._bad) and self.state == TrackState.TRACKING:
            self.state = TrackState.ACQUIRING
        if self.state == TrackState.ACQUIRING and self._good >= cfg.acquire_frames:
            self.state = TrackState.TRACKING
        return self.state
