"""The tracker: Algorithm 3's tracking stage (the modified UPF) with the proposals C1–C5 of §5.2.

Per frame (:meth:`Tracker.step`), with M particles of which M0 = M − boosted are carried over:

1. **Mix** (Alg. 3, pose boosting step 4): the best M0 particles of t−1 and M − M0 boosted
   hypotheses of frame t (all M from boosting at the first frame, after a loss, and always in C1).
2. **Proposal** (§5.2): C1 uses the mix as is (5.2.1); C2 moves the carried particles by the
   constant-velocity model (3.12) with random process noise (5.2.2); C3–C5 run one filter per
   particle — UKF on translation and UKF (C3), UBiF (C4) or UBiGaF (C5) on rotation — predicted
   from t−1, then updated with the measurement z_t, the pose of the mix's best-likelihood
   particle (5.2.3–5.2.4). The carried filters are predicted before z_t is chosen, so z_t is
   picked among poses of time t. The prediction spans the frames' stamps, in whole Δt
   (:func:`prediction_steps`).
3. **Weighting and resampling** (§5.4): one batched render + score, then the configured
   App. B scheme back to M particles. Ours: every score (weighting, z_t, optimisation,
   refinement) is the likelihood times a depth prior about the boosted depth (:func:`depth_prior`)
   when that depth is within ``depth_prior_max_m`` and within ``depth_prior_gate`` of the last best
   particle's, and times a rotation prior about the last refined rotation
   (:func:`rotation_prior`) while that estimate is within ``rotation_prior_max_m`` (ours: held
   while the track coasts, ``rotation_prior_hold``); the track state and ``best_likelihood`` use
   the likelihood alone.
4. **Pose optimisation** (§5.5): N iterations of the configured optimiser (PFO by default, with
   the §6.7.1 noise, its translation part scaled by depth / ``pfo.reference_depth_m``: ours).
   Filters are then recentred on the optimised poses.
5. **Output**: the best particle (§6.7.1.2) or, ours (``estimate: mean``), the particles'
   weighted mean (:meth:`ParticleSet.mean_pose`), with, ours, its rotation refined by a
   rotation-only local search (:mod:`.refinement`, ``refine.candidates`` > 0, each candidate
   scored at its best sub-pixel image shift with ``refine.align_px`` > 0; the particles are
   not changed, but within ``rotation_prior_max_m`` the refined rotation anchors the next
   frame's rotation prior), and, ours, that rotation averaged with the last frame's
   (``rotation_window``, :mod:`.smoothing`),
   a 6×6 covariance from the weighted particle cloud (:func:`particle_covariance`) with a
   range-proportional σ added along the line of sight and a σ floor on each rotation axis, both
   set per band of the estimate's depth (ours: the cloud's spread alone covers too little of the
   error, and least near the ship and far out), growing on every axis with each frame in a row
   without boosted hypotheses (ours, :func:`coasting_covariance`), the track state
   (:mod:`.track_state`) and per-stage times.

Everything is batched over particles; each likelihood evaluation is one ``Renderer.silhouettes``
call. Random draws come from a Generator seeded by ``TrackerConfig.seed``; the refinement has its
own, spawned from the same seed, so turning it on leaves the particles' draws unchanged.
"""

import re
import time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation

from ..config import check_seed
from ..filters.motion import MotionFilterConfig
from ..geometry import geodesic_angle, omega_quat, quat_multiply, quat_normalise
from ..render.renderer import MAX_TILE
from .likelihood import LIKELIHOODS, ColourConfig, make_likelihood
from .motion_bank import MotionBank
from .optimisation import OPTIMISERS, PFOConfig, evaluate, make_optimiser
from .particles import ParticleSet
from .refinement import RotationRefinement, RotationRefinementConfig
from .resampling import RESAMPLERS, fixed_size, resample
from .smoothing import RotationWindow
from .track_state import TrackMonitor, TrackState, TrackStateConfig

ROTATION_FILTER = {"C3": "ukf", "C4": "ubif", "C5": "ubigaf"}  # Table 6.11
COMBINATIONS = ("C1", "C2", "C3", "C4", "C5")
ESTIMATES = ("best", "mean")  # published pose: the best particle (thesis) or the weighted mean (ours)
_VARIANT = re.compile(r"^C([1-5])N(\d+)$")


def parse_variant(text: str) -> tuple[str, int]:
    """``"C4N2"`` → ``("C4", 2)``: combination of Table 6.11 and PFO iterations N (§6.7.1.3)."""
    match = _VARIANT.match(str(text).strip().upper())
    if match is None:
        raise ValueError(f"variant {text!r} is not of the form CxNy with x in 1..5 and y >= 0 (e.g. C4N2)")
    return f"C{match.group(1)}", int(match.group(2))


@dataclass(frozen=True)
class TrackerConfig:
    """The tracker's parameters (``config/tracker.yaml``, section ``tracker``); thesis defaults (§6.7.1).

    ``motion.rotation_filter`` is set by ``variant`` (C3 ukf, C4 ubif, C5 ubigaf); C1 and C2 use
    no filter (C2 uses ``motion``'s ``dt`` and process noise for its prediction).
    """

    variant: str = "C4"  # combination of Table 6.11
    iterations: int = 2  # N, pose optimisation iterations per frame
    particles: int = 100  # M
    boosted: int = 25  # M − M0 hypotheses mixed in per frame (C2–C5)
    metric: str = "colour"  # §5.4.1 likelihood
    resampling: str = "reallocation"  # App. B scheme of the weighting step
    optimiser: str = "pfo"  # pfo | pso | constricted_pso | gabf (the last three with thesis defaults)
    seed: int = 0
    tile: int = 64  # silhouette tile size (px) of the batched render
    colour: ColourConfig = field(default_factory=lambda: ColourConfig(band_px=1.5))  # colour metric (5.14), see yaml
    pfo: PFOConfig = field(default_factory=lambda: PFOConfig(reference_depth_m=40.0))  # see yaml
    motion: MotionFilterConfig = field(default_factory=MotionFilterConfig)
    track: TrackStateConfig = field(default_factory=TrackStateConfig)
    covariance_floor_m: float = 0.05  # σ added to each translation variance
    # ours, per band of the estimate's depth (bands split at covariance_bands_m, see yaml): σ added to
    # each rotation variance, and σ of a fraction of the range added along the line of sight
    covariance_floor_deg: tuple[float, ...] = (10.0, 5.0, 8.0)
    covariance_range_fraction: tuple[float, ...] = (0.2, 0.05, 0.075)
    covariance_bands_m: tuple[float, ...] = (15.0, 60.0)
    # ours, 0 = off: per frame interval (Δt) without boosted hypotheses (the track coasting), σ added to
    # each position axis (this fraction of the range) and to each rotation axis (deg), growing linearly
    covariance_coast_fraction: float = 0.02
    covariance_coast_deg: float = 0.5
    depth_prior_sigma: float = 0.20  # ours, 0 = thesis: relative σ of the boosted-depth prior (depth_prior)
    depth_prior_floor: float = 0.5  # the prior's value far from the boosted depth
    depth_prior_max_m: float = 30.0  # no prior where the boosted depth is beyond this
    depth_prior_gate: float = 0.25  # ours, 0 = off: no prior when z_b is over this fraction off the last depth
    rotation_prior_sigma_deg: float = 10.0  # ours, 0 = thesis: σ of the rotation prior about the last estimate
    rotation_prior_floor: float = 0.5  # the rotation prior's value far from the last estimate's rotation
    rotation_prior_max_m: float = 15.0  # no rotation prior while the last estimate is beyond this depth
    rotation_prior_hold: bool = True  # ours: frames without boosted hypotheses keep the anchor (False: it follows)
    estimate: str = "mean"  # ours (best = thesis), see yaml
    rotation_window: int = 4  # ours, 1 = thesis: frames whose estimated rotations are averaged for output
    rotation_window_max_turn_deg: float = 30.0  # a larger turn from the last estimate restarts the window
    refine: RotationRefinementConfig = field(
        default_factory=lambda: RotationRefinementConfig(candidates=96, sigma_deg=(4.0, 1.5), align_px=0.5))  # ours

    def __post_init__(self):
        if self.variant not in COMBINATIONS:
            raise ValueError(f"variant must be one of {COMBINATIONS}, got {self.variant!r}")
        if self.iterations < 0 or self.particles < 2 or not 1 <= self.boosted <= self.particles:
            raise ValueError("need iterations N >= 0, particles M >= 2 and 1 <= boosted <= M, got "
                             f"N = {self.iterations}, M = {self.particles}, boosted = {self.boosted}")
        if self.metric not in LIKELIHOODS:
            raise ValueError(f"metric must be one of {sorted(LIKELIHOODS)}, got {self.metric!r}")
        if self.resampling not in RESAMPLERS:
            raise ValueError(f"resampling must be one of {sorted(RESAMPLERS)}, got {self.resampling!r}")
        if self.optimiser not in OPTIMISERS:
            raise ValueError(f"optimiser must be one of {sorted(OPTIMISERS)}, got {self.optimiser!r}")
        check_seed(self.seed)
        if not 16 <= self.tile <= MAX_TILE:
            raise ValueError(f"tile must be 16 to {MAX_TILE} px, got {self.tile!r}")
        # Bounded above as well: the published covariance must stay a usable float32 (MAVLink).
        for names, high in ((("covariance_floor_m",), 1e3), (("covariance_floor_deg", "covariance_coast_deg"), 180.0),
                            (("covariance_range_fraction", "covariance_coast_fraction"), 1.0)):
            for name in names:
                values = np.atleast_1d(np.asarray(getattr(self, name), float))
                if not np.all((values >= 0) & (values <= high)):
                    raise ValueError(f"{name} must be within 0 to {high:g}, got {getattr(self, name)!r}")
        bands = np.asarray(self.covariance_bands_m, float)
        per_band = {len(self.covariance_floor_deg), len(self.covariance_range_fraction)}
        if per_band != {len(bands) + 1} or not (np.all(bands > 0) and np.all(np.diff(bands) > 0)):
            raise ValueError("covariance_bands_m must be increasing positive depths, and covariance_floor_deg and "
                             "covariance_range_fraction one value per band (one more than the bounds); got "
                             f"{self.covariance_bands_m!r}, {self.covariance_floor_deg!r} and "
                             f"{self.covariance_range_fraction!r}")
        if not (self.depth_prior_sigma >= 0 and 0 < self.depth_prior_floor <= 1 and self.depth_prior_max_m > 0):
            raise ValueError("need depth_prior_sigma >= 0, 0 < depth_prior_floor <= 1 and depth_prior_max_m > 0")
        if not (self.rotation_prior_sigma_deg >= 0 and 0 < self.rotation_prior_floor <= 1
                and self.rotation_prior_max_m > 0):
            raise ValueError("need rotation_prior_sigma_deg >= 0, 0 < rotation_prior_floor <= 1 and rotation_prior_max_m > 0")
        if not self.depth_prior_gate >= 0:
            raise ValueError(f"depth_prior_gate must be non-negative, got {self.depth_prior_gate!r}")
        if int(self.rotation_window) != self.rotation_window or self.rotation_window < 1:
            raise ValueError(f"rotation_window must be a positive integer, got {self.rotation_window!r}")
        if not self.rotation_window_max_turn_deg > 0:
            raise ValueError(f"rotation_window_max_turn_deg must be positive, got {self.rotation_window_max_turn_deg!r}")
        if self.estimate not in ESTIMATES:
            raise ValueError(f"estimate must be one of {ESTIMATES}, got {self.estimate!r}")
        if self.variant in ROTATION_FILTER:
            object.__setattr__(self, "motion", replace(self.motion, rotation_filter=ROTATION_FILTER[self.variant]))

    @classmethod
    def from_variant(cls, name: str, **overrides) -> "TrackerConfig":
        """The configuration of a ``CxNy`` variant, other fields from ``overrides``."""
        combination, n = parse_variant(name)
        return cls(variant=combination, iterations=n, **overrides)

    @property
    def name(self) -> str:
        return f"{self.variant}N{self.iterations}"

    @property
    def uses_filters(self) -> bool:
        return self.variant in ROTATION_FILTER


STAGES = ("prepare", "proposal", "measurement", "filtering", "weighting", "resampling", "optimisation", "refinement",
          "output")


@dataclass(frozen=True)
class TrackResult:
    """One frame's output. ``position``/``quat``: UAV body in the camera optical frame (NaN when
    there is no estimate): the particles' weighted mean or the best particle (``estimate``), its
    rotation refined and averaged over the last ``rotation_window`` frames. ``covariance``: 6×6,
    ROS order (x, y, z, rot_x, rot_y, rot_z); the rotation part is of the small rotation r with
    ``q_particle = exp(r) ⊗ q_estimate``, i.e. about the camera's fixed axes (as
    ``PoseWithCovariance`` expects), in rad².
    ``best_likelihood``: the best particle's likelihood (before the rotation refinement); it
    drives the track state."""

    stamp_ns: int
    state: TrackState
    position: np.ndarray
    quat: np.ndarray
    covariance: np.ndarray
    best_likelihood: float
    effective_particles: float
    stage_ms: dict
    particles: ParticleSet | None = None

    @property
    def has_pose(self) -> bool:
        return bool(np.all(np.isfinite(self.position)))


def load_tracker_config(path=None) -> TrackerConfig:
    """The ``tracker`` section of a parameter file (default: the shipped ``config/tracker.yaml``)."""
    from ..config import from_mapping, load_node_parameters
    from ..resources import config_path

    path = config_path("tracker.yaml") if path is None else path
    return from_mapping(TrackerConfig, load_node_parameters(path, "tracker"), f"{path}: tracker")


def constant_velocity_prediction(particles: ParticleSet, cfg: MotionFilterConfig,
                                 rng: np.random.Generator) -> ParticleSet:
    """C2's transition prior (§5.2.2): (3.12) ``p += v Δt``, ``q ← q ⊗ Ω(ω) ⊗ Ω(ξ)`` with Gaussian
    disturbances of the motion configuration's process σ on p, v and ω."""
    m, dt = len(particles), cfg.dt
    pos = particles.pos + particles.vel * dt + rng.normal(size=(m, 3)) * cfg.position_process_std
    vel = particles.vel + rng.normal(size=(m, 3)) * cfg.velocity_process_std
    xi = rng.normal(size=(m, 3)) * cfg.omega_process_std
    quat = quat_multiply(quat_multiply(particles.quat, omega_quat(particles.omega, dt)), omega_quat(xi, dt))
    return ParticleSet(pos, quat_normalise(quat), vel, particles.omega + xi, particles.weight, particles.state)


MAX_PREDICTION_STEPS = 60  # ~2 s of Δt: bounds one frame's prediction cost after a long gap or a clock jump


def prediction_steps(gap_ns: int | None, dt: float) -> int:
    """How many Δt steps of the motion model (3.12) the prediction takes from the last frame to
    one ``gap_ns`` later: the gap in Δt, rounded, at least 1 and at most
    :data:`MAX_PREDICTION_STEPS` (1 for the first frame). The thesis's filters advance one Δt
    per frame (§6.7.1, Δt ≈ 0.034 s, every frame tracked); frames the tracker does not see (a
    tracker slower than the camera, a dropped frame) make gaps of several Δt."""
    if gap_ns is None:
        return 1
    return int(min(max(gap_steps(gap_ns, dt), 1), MAX_PREDICTION_STEPS))


def gap_steps(gap_ns: int, dt: float) -> int:
    """A stamp gap in whole Δt, rounded (not bounded: see :func:`prediction_steps`)."""
    return round(gap_ns * 1e-9 / dt)


def depth_prior(depth: np.ndarray, anchor: float, sigma: float, floor: float) -> np.ndarray:
    """Ours (not in the thesis): ``floor + (1 − floor)·exp(−½((z/z_b − 1)/σ)²)`` of each depth z about
    the boosted depth z_b (median weak-perspective depth (4.5) of the frame's boosted hypotheses).
    Within a few σ of z_b it separates depth from rotation errors (a wrong rotation whose depth
    compensates); the floor and a wide σ bound the harm of a wrong z_b. With oracle ROIs z_b erred
    by up to ±5 % below ~38 m on one approach but by a steady −10…−20 % at 20 m on another, and
    by 15–45 % (outliers ×15) beyond 40 m, hence σ = 0.2 and ``depth_prior_max_m``."""
    u = (np.asarray(depth, float) / anchor - 1.0) / sigma
    return floor + (1.0 - floor) * np.exp(-0.5 * u * u)


def rotation_prior(quats: np.ndarray, anchor: np.ndarray, sigma_rad: float, floor: float) -> np.ndarray:
    """Ours (not in the thesis): ``floor + (1 − floor)·exp(−½(θ/σ)²)`` of each rotation's geodesic
    angle θ to the anchor (the last frame's refined rotation, before the rotation window), ``q``
    and ``−q`` alike. A landing aircraft turns by a few degrees between frames; near the ship the
    colour metric scores turned silhouettes close to the true one, and without a prior the
    particles can walk 10° a frame."""
    u = geodesic_angle(quats, anchor) / sigma_rad
    return floor + (1.0 - floor) * np.exp(-0.5 * u * u)


def depth_band(depth: float, bounds_m) -> int:
    """Index of the band of depths split at ``bounds_m`` (increasing) that holds ``depth``; a depth
    on a bound belongs to the nearer band."""
    return int(np.searchsorted(bounds_m, depth, side="left"))


def particle_covariance(particles: ParticleSet, pos: np.ndarray, quat: np.ndarray,
                        floor_m: float = 0.0, floor_rad: float = 0.0, range_fraction: float = 0.0) -> np.ndarray:
    """Weighted second moment (6×6, ROS order) of the particles about the published estimate
    ``(pos, quat)``, in the coordinates ``[p − pos, log(q ⊗ quat⁻¹)]`` (so an estimate away from
    the cloud's mean, e.g. a refined or averaged rotation, widens it by that offset), plus
    ``floor²`` on the diagonal and, along the line of sight ``pos``, a variance
    ``(range_fraction·|pos|)²``."""
    w = particles.normalised_weights()
    rot = (Rotation.from_quat(particles.quat) * Rotation.from_quat(quat).inv()).as_rotvec()
    d = np.hstack([particles.pos - pos, rot])
    cov = (d * w[:, None]).T @ d
    cov = 0.5 * (cov + cov.T) + np.diag(np.repeat([floor_m**2, floor_rad**2], 3))
    cov[:3, :3] += range_fraction**2 * np.outer(pos, pos)
    return cov


def coasting_covariance(pos: np.ndarray, frames: int, range_fraction: float, sigma_rad: float) -> np.ndarray:
    """Ours: the 6×6 variance added after ``frames`` frame intervals (Δt) without boosted hypotheses,
    σ = ``frames·range_fraction·|pos|`` on each position axis and ``frames·sigma_rad`` on each
    rotation axis. Without hypotheses nothing ties the cloud to the frame, and the particles stay
    as tight as they were while the error grows: the errors of such frames leave the cloud's
    region in any direction, not only along the line of sight."""
    s_pos = frames * range_fraction * float(np.linalg.norm(pos))
    return np.diag(np.repeat([s_pos**2, (frames * sigma_rad) ** 2], 3))


def largest_draw(config: TrackerConfig) -> int:
    """The most poses a tracker of ``config`` renders in one draw call: its M particles, or the
    rotation refinement's candidates + 1."""
    return max(config.particles, config.refine.candidates + 1)


def render_batch(config: TrackerConfig) -> int:
    """The ``max_batch`` of a renderer for a tracker of ``config``: its :func:`largest_draw`, and at
    least 512."""
    return max(512, largest_draw(config))


class Tracker:
    """The tracking core of the ``tracker`` node; one per process (it owns the renderer's use).

    ``camera`` is the rectified camera; ``renderer`` may be shared (evaluation of several
    variants), else one is made with the low-detail mesh.
    """

    def __init__(self, config: TrackerConfig, camera, renderer=None):
        batch = largest_draw(config)
        if renderer is None:
            from ..model import fixed_wing_mesh
            from ..render import Renderer

            renderer = Renderer(camera, fixed_wing_mesh("low"), tile=config.tile, max_batch=render_batch(config))
        if renderer.max_batch < batch:
            raise ValueError(f"renderer max_batch {renderer.max_batch} < {batch}, the largest batch this tracker "
                             f"renders ({config.particles} particles, {config.refine.candidates} + 1 refinement poses)")
        self.config = config
        self.likelihood = make_likelihood(config.metric, renderer, config.colour if config.metric == "colour" else None)
        self.optimiser = make_optimiser(config.optimiser, config.pfo)
        self.refinement = RotationRefinement(config.refine)
        self._seed()
        self.monitor = TrackMonitor(config.track)
        self.particles: ParticleSet | None = None  # the last frame's set, best first
        self.filters = MotionBank(config.motion) if config.uses_filters else None
        self._fresh: ParticleSet | None = None  # this frame's boosted particles
        self._anchor: float | None = None  # this frame's boosted depth z_b (depth_prior), None: no prior
        self._turn_anchor: np.ndarray | None = None  # last refined rotation (rotation_prior), None: no prior
        self._coasting = 0  # frame intervals (Δt) since the last frame with boosted hypotheses
        self._last_frame: np.ndarray | None = None  # the last frame stepped, to tell a repeated one
        self._repeated = 0  # frame intervals (Δt) over which the tracked frames repeated (track_state)
        self._last_stamp_ns: int | None = None  # of the last frame stepped since the last reset
        self.window = RotationWindow(config.rotation_window, 1.5 * config.motion.dt, config.rotation_window_max_turn_deg)

    @property
    def state(self) -> TrackState:
        return self.monitor.state

    def hypotheses_needed(self) -> int:
        """How many boosted poses the next :meth:`step` uses: M when (re)initialising or in C1."""
        if self.particles is None or self.config.variant == "C1":
            return self.config.particles
        return self.config.boosted

    def reset(self) -> None:
        """Forget the track (the next frame with hypotheses re-initialises it) and the last
        stamp (a new time-line), and draw again from the seed: a replay started again gives the
        estimates of the first time."""
        self._drop_track()
        self._seed()
        self._last_stamp_ns = None
        self._last_frame, self._repeated = None, 0

    def _seed(self) -> None:
        """The random generators as the seed starts them (the refinement's has its own stream)."""
        self.rng = np.random.default_rng(np.random.SeedSequence(self.config.seed))
        self._refine_rng = np.random.default_rng(np.random.SeedSequence(self.config.seed).spawn(1)[0])

    def _drop_track(self) -> None:
        """Forget the track (LOST); frames must still come after the last one."""
        self.particles = None
        self._turn_anchor = None
        self.window.reset()
        self.monitor.lost()

    def step(self, frame: np.ndarray, stamp_ns: int, hypotheses=None) -> TrackResult:
        """Track one rectified RGB frame. ``hypotheses``: boosted poses, best first, with
        ``quats (k, 4)`` and ``positions (k, 3)`` (e.g. :class:`boosting.Hypotheses`), or None.
        Stamps must increase until the next :meth:`reset`: an earlier or repeated one, a bad
        frame or bad hypotheses raise ValueError before the track or the last stamp changes."""
        if self._last_stamp_ns is not None and stamp_ns <= self._last_stamp_ns:
            raise ValueError(f"frame stamp {stamp_ns} ns is not after the last one ({self._last_stamp_ns} ns); "
                             "reset() the tracker for a new time-line")
        clock = _Clock()
        self.likelihood.prepare(frame)
        clock.lap("prepare")
        new = _hypothesis_set(hypotheses, self.hypotheses_needed())
        steps = prediction_steps(None if self._last_stamp_ns is None else stamp_ns - self._last_stamp_ns,
                                 self.config.motion.dt)
        self._last_stamp_ns = int(stamp_ns)
        self._coasting = 0 if new is not None else self._coasting + steps
        self._count_repeats(frame, steps)
        self._anchor = self._boosted_depth(new)
        mixed = self._mix(new, steps)
        clock.lap("proposal")
        if mixed is None:
            self._drop_track()
            return self._empty(stamp_ns, clock)
        scores = np.full(len(mixed), np.nan)
        if self.filters is not None:
            mixed, scores = self._filter(mixed, clock)
        w = self._weights(mixed, scores)
        clock.lap("weighting")
        n_eff = mixed.with_weight(w).effective_size() if w.sum() > 0.0 else 0.0
        particles = self._resample(mixed, w)
        clock.lap("resampling")
        if self.config.iterations > 0 and particles.weight.sum() > 0:
            particles = self._optimise(particles)
        clock.lap("optimisation")
        return self._output(particles, stamp_ns, clock, n_eff)

    def _boosted_depth(self, new: ParticleSet | None) -> float | None:
        """This frame's anchor z_b of the depth prior: the boosted hypotheses' median depth, or None
        (no prior) beyond ``depth_prior_max_m`` or, with ``depth_prior_gate``, when it disagrees
        with the last frame's best particle's depth by more than that fraction (always when that
        depth is not positive)."""
        cfg = self.config
        if new is None or cfg.depth_prior_sigma <= 0:
            return None
        anchor = float(np.median(new.pos[:, 2]))
        if not 0 < anchor <= cfg.depth_prior_max_m:
            return None
        if cfg.depth_prior_gate > 0 and self.particles is not None:
            last = float(self.particles.pos[0, 2])
            if not last > 0.0 or abs(anchor / last - 1.0) > cfg.depth_prior_gate:
                return None
        return anchor

    def _prior(self, particles: ParticleSet) -> np.ndarray:
        """This frame's depth prior × rotation prior of each particle (ones without anchors)."""
        cfg = self.config
        prior = np.ones(len(particles))
        if self._anchor is not None:
            prior *= depth_prior(particles.pos[:, 2], self._anchor, cfg.depth_prior_sigma, cfg.depth_prior_floor)
        if self._turn_anchor is not None:
            prior *= rotation_prior(particles.quat, self._turn_anchor, np.radians(cfg.rotation_prior_sigma_deg),
                                    cfg.rotation_prior_floor)
        return prior

    def _score(self, particles: ParticleSet) -> np.ndarray:
        """The objective of weighting, z_t and optimisation: likelihood × priors, one render."""
        return self.likelihood(particles) * self._prior(particles)

    def _refinement_score(self, particles: ParticleSet) -> np.ndarray:
        """The rotation refinement's objective: as :meth:`_score`, the likelihood taken at the best
        of ``refine.align_px``'s image shifts of each silhouette (one render)."""
        batch = self.likelihood.renderer.silhouettes(particles.quat, particles.pos)
        best = self.likelihood.score_shifted(batch, self.config.refine.shifts).max(axis=1)
        return best * self._prior(particles)

    # --- Algorithm 3 steps ----------------------------------------------------------------------

    def _mix(self, new: ParticleSet | None, steps: int) -> ParticleSet | None:
        """Step 1: the best M0 carried particles (predicted ``steps`` Δt ahead, :func:`prediction_steps`)
        and the new boosted ones (Alg. 3)."""
        cfg = self.config
        self._fresh = new
        if self.particles is None or cfg.variant == "C1":
            if new is None:
                return None
            if self.particles is None:
                self.monitor.initialised()
            if self.filters is not None:
                self.filters.clear()
            return new
        room = cfg.particles - (0 if new is None else len(new))
        kept = self.particles.take(np.arange(min(len(self.particles), room)))
        if self.filters is None:  # C2: transition prior (5.2.2)
            for _ in range(steps):
                kept = constant_velocity_prediction(kept, cfg.motion, self.rng)
        else:  # C3-C5: the carried filters predicted to t (5.2.3)
            self.filters.take(np.arange(len(kept)))
            self.filters.predict(steps)
            pos, vel, quat, omega = self.filters.estimates()
            kept = ParticleSet(pos, quat, vel, omega, kept.weight)
        kept = ParticleSet(kept.pos, kept.quat, kept.vel, kept.omega, kept.weight)
        return kept if new is None else ParticleSet.concat([kept, new])

    def _filter(self, mixed: ParticleSet, clock) -> tuple[ParticleSet, np.ndarray]:
        """Step 2 (C3–C5): z_t = best-likelihood pose of the mix; the carried filters are updated
        with it. New boosted particles start a filter at their own pose: the thesis filters them
        too, but pulling a fresh hypothesis towards another one discards its own evidence (a wrong
        z_t would drag every new particle off, and the filter could not recover). Returns the
        filtered set and the scores still valid for it (the new particles'; NaN elsewhere)."""
        scores = np.full(len(mixed), np.nan)
        carried = len(self.filters)
        if carried:
            w = evaluate(self._score, mixed)
            clock.lap("measurement")
            best = int(np.argmax(w))
            self.filters.update(mixed.pos[best], mixed.quat[best])
            scores[carried:] = w[carried:]
        if self._fresh is not None:
            fresh = MotionBank(self.config.motion)
            fresh.init(self._fresh.pos, self._fresh.quat)
            self.filters.extend(fresh)
        pos, vel, quat, omega = self.filters.estimates()
        clock.lap("filtering")
        return ParticleSet(pos, quat, vel, omega, np.full(len(pos), 1.0 / len(pos))), scores

    def _weights(self, particles: ParticleSet, scores: np.ndarray) -> np.ndarray:
        """Step 3's approximate weighting (§5.4.1): one batched score of the poses not yet scored."""
        todo = np.flatnonzero(np.isnan(scores))
        if todo.size:
            scores[todo] = evaluate(self._score, particles.take(todo))
        return scores

    def _resample(self, particles: ParticleSet, w: np.ndarray) -> ParticleSet:
        """Step 3: App. B resampling back to the set's size; ``slot`` names each copy's filter."""
        particles = ParticleSet(particles.pos, particles.quat, particles.vel, particles.omega, particles.weight,
                                {"slot": np.arange(len(particles))})
        if not w.sum() > 0.0:
            return particles.with_weight(w)
        idx = fixed_size(resample(self.config.resampling, w, self.rng), w, self.rng, len(particles))
        return particles.take(idx, weight=w[idx])

    def _optimise(self, particles: ParticleSet) -> ParticleSet:
        """Step 4 (§5.5), with elitism: if every optimised pose scores below the best pose scored before
        the optimisation, that pose replaces the worst optimised one (the colour metric's peak is a few
        pixels wide, so the §6.7.1 PFO noise can step every copy off it; the thesis has no such guard)."""
        elite = particles.take([particles.best_index()])
        out = self.optimiser.run(particles, self._score, self.rng, self.config.iterations)
        if elite.weight[0] <= out.weight.max():
            return out
        keep = np.argsort(-out.weight, kind="stable")[: len(out) - 1]
        return ParticleSet.concat([elite, out.take(keep)])

    def _output(self, particles: ParticleSet, stamp_ns: int, clock, n_eff: float) -> TrackResult:
        """Step 5: the estimate (mean or best particle, rotation refined), covariance, track state;
        the set is kept best first. ``n_eff``: (6.5) of the importance weights, before resampling
        (after it, copies of one pose would count as distinct particles)."""
        cfg = self.config
        order = np.argsort(-particles.weight, kind="stable")
        particles = particles.take(order)
        best_w = float(particles.weight[0] / self._prior(particles.take([0]))[0])  # the likelihood alone
        state = self.monitor.update(best_w, self._coasting, self._repeated)
        if self.filters is not None:
            self.filters.take(particles.state["slot"])
            self.filters.recentre(particles.pos, particles.quat)
            particles = ParticleSet(particles.pos, particles.quat, particles.vel, particles.omega, particles.weight,
                                    {"slot": np.arange(len(particles))})
        if state == TrackState.LOST:
            self._drop_track()
            return self._empty(stamp_ns, clock, best_w)
        if best_w <= 0.0:  # nothing scored: carry the set on, no estimate this frame
            self.particles = particles.with_weight(np.full(len(particles), 1.0 / len(particles)))
            return self._empty(stamp_ns, clock, best_w)
        self.particles = particles
        if cfg.estimate == "mean":
            pos, quat = particles.mean_pose()
        else:
            pos, quat = particles.pos[0].copy(), particles.quat[0]
        quat, _ = self.refinement.refine(self._refinement_score, pos, quat, self._refine_rng)
        clock.lap("refinement")
        self._turn_anchor = self._next_turn_anchor(pos, quat)
        quat = self.window(stamp_ns, quat)
        band = depth_band(pos[2], cfg.covariance_bands_m)
        cov = particle_covariance(particles, pos, quat, cfg.covariance_floor_m,
                                  np.radians(cfg.covariance_floor_deg[band]), cfg.covariance_range_fraction[band])
        if self._coasting:
            cov += coasting_covariance(pos, self._coasting, cfg.covariance_coast_fraction,
                                       np.radians(cfg.covariance_coast_deg))
        clock.lap("output")
        return TrackResult(stamp_ns, state, pos, quat, cov, best_w, n_eff, clock.ms, particles)

    def _count_repeats(self, frame: np.ndarray, steps: int) -> None:
        """Count the frame intervals (``steps`` since the last tracked frame) over which the tracked
        frames were identical, pixel for pixel, to the one before (a frozen camera)."""
        same = self._last_frame is not None and np.array_equal(frame, self._last_frame)
        self._repeated = self._repeated + steps if same else 0
        self._last_frame = np.array(frame, copy=True)

    def _next_turn_anchor(self, pos: np.ndarray, quat: np.ndarray) -> np.ndarray | None:
        """The rotation prior's anchor for the next frame: this frame's refined rotation while the
        estimate is within ``rotation_prior_max_m``, else None; with ``rotation_prior_hold``, a frame
        without boosted hypotheses keeps the anchor it had, so a coasting track cannot walk its own
        prior away from the last rotation the frame's pixels supported."""
        cfg = self.config
        if not (cfg.rotation_prior_sigma_deg > 0 and pos[2] <= cfg.rotation_prior_max_m):
            return None
        if cfg.rotation_prior_hold and self._coasting and self._turn_anchor is not None:
            return self._turn_anchor
        return quat.copy()

    def _empty(self, stamp_ns: int, clock, best_w: float = 0.0) -> TrackResult:
        self.window.reset()
        clock.lap("output")
        nan = np.full(3, np.nan)
        return TrackResult(stamp_ns, self.state, nan, np.full(4, np.nan), np.full((6, 6), np.nan), best_w, 0.0,
                           clock.ms)


def _hypothesis_set(hypotheses, count: int) -> ParticleSet | None:
    """The first ``count`` boosted poses as particles at rest, or None if there are none."""
    if hypotheses is None:
        return None
    quats = np.asarray(hypotheses.quats, float)[:count]
    pos = np.asarray(hypotheses.positions, float)[:count]
    if len(quats) == 0:
        return None
    return ParticleSet.from_poses(pos, quat_normalise(quats))


class _Clock:
    """Milliseconds per stage of :data:`STAGES` (stages not run stay 0)."""

    def __init__(self):
        self.ms = dict.fromkeys(STAGES, 0.0)
        self._last = time.perf_counter()

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self.ms[stage] += 1e3 * (now - self._last)
        self._last = now
