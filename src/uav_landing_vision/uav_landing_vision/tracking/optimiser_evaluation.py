"""Pose optimisation evaluation (§6.6, Tables 6.9–6.10): ``uav-landing eval-optimisers``.

Each sample is set up as :mod:`..boosting.evaluation` sets up §6.4's: a random orientation from
the pose database's interval, on the optical axis at one of the distances, rendered shaded over
the simulator's ``normal`` background, the ROI the silhouette's box. Pose boosting gives M
hypotheses from that ROI (§6.6.1: "the hypotheses generation scheme ... for the pose samples
initialization"); every optimiser then runs N iterations from the same hypotheses, scored with
the tracker's colour metric (5.14), and its estimate is its most likely pose. ``boosting`` is the
most likely hypothesis before any optimisation, the comparison the thesis draws with §6.4.
Errors: estimate − truth per coordinate, and the Euler angles of q_g ⊗ q̄_r (6.4).

Departures, each a setting of the tracker as shipped: the database's orientation interval (not
±180° on every axis: hypotheses outside it do not exist), the colour metric with its outline band,
and PFO's "noise" schedule at Table 6.6–6.7's "Noise" row (σ 0.05 / 0.05 / 0.01 m, 5° per axis;
the tables' "covariances" read as standard deviations, as everywhere in the project).
"""

import sys
from dataclasses import dataclass

import numpy as np

from ..boosting.evaluation import check_distances
from ..config import check_seed
from ..evaluation.statistics import ROW_NAMES, STAT_KEYS, error_statistics
from ..geometry import euler_error, quat_normalise
from .optimisation import OPTIMISERS, SECTION_6_6_NOISE, PFOConfig, make_optimiser
from .particles import ParticleSet

OPTIMISER_NAMES = tuple(OPTIMISERS)
COLUMN_NAMES = {"boosting": "Boosting", "pfo": "PFO", "pso": "PSO", "constricted_pso": "Mod. PSO", "gabf": "GAbF"}


@dataclass(frozen=True)
class OptimiserEvalConfig:
    """§6.6.1's set-up: distances (m), samples per distance, M pose samples, N iterations."""

    samples: int = 100
    distances: tuple[float, ...] = (5.0, 15.0, 25.0, 35.0, 45.0)
    particles: int = 100
    iterations: int = 10
    optimisers: tuple[str, ...] = OPTIMISER_NAMES
    pfo: PFOConfig = SECTION_6_6_NOISE
    seed: int = 0

    def __post_init__(self):
        if self.samples < 1 or self.particles < 2 or self.iterations < 1:
            raise ValueError("need samples >= 1, particles >= 2 and iterations >= 1")
        check_distances(self.distances)
        check_seed(self.seed)
        unknown = set(self.optimisers) - set(OPTIMISER_NAMES)
        if unknown or not self.optimisers:
            raise ValueError(f"optimisers must be among {OPTIMISER_NAMES}, got {self.optimisers}")


def evaluate_optimisers(camera, mesh, config: OptimiserEvalConfig = OptimiserEvalConfig(), *,
                        database_path=None, progress: bool = True) -> dict:
    """Run the evaluation: ``{"stats": {dist: {method: {"translation_m": .., "rotation_deg": ..}}},
    "failures": {dist: n}, "samples": n, "best_likelihood": {dist: {method: mean}}}``."""
    from tqdm import tqdm

    from ..boosting.database import DEFAULT_FILE, PoseDatabase, sample_orientations
    from ..boosting.evaluation import BACKGROUND_FRAMES, normal_backgrounds, rendered_hypotheses
    from ..boosting.obb import FastConfig
    from ..model import fixed_wing_mesh
    from ..render import Renderer
    from ..resources import model_path
    from .likelihood import make_likelihood
    from .upf import load_tracker_config

    camera = camera.rectified()
    tracker = load_tracker_config()
    db = PoseDatabase.load(database_path or model_path(DEFAULT_FILE), camera=camera, mesh=mesh)
    with Renderer(camera, mesh) as shading, \
            Renderer(camera, fixed_wing_mesh("low"), tile=tracker.tile, max_batch=max(512, config.particles)) as scoring:
        likelihood = make_likelihood("colour", scoring, tracker.colour)
        backgrounds, sun, albedo = normal_backgrounds(camera, BACKGROUND_FRAMES, config.seed)
        methods = ("boosting", *config.optimisers)
        stats, failures, best_likelihood = {}, {}, {}
        for d_i, distance in enumerate(config.distances):
            rng = np.random.default_rng(np.random.SeedSequence(config.seed, spawn_key=(2, d_i)))
            quats = sample_orientations(config.samples, db.half_range_deg, rng)
            trans = np.array([0.0, 0.0, distance])
            t_err = {m: np.full((config.samples, 3), np.nan) for m in methods}
            r_err = {m: np.full((config.samples, 3), np.nan) for m in methods}
            scores = {m: np.full(config.samples, np.nan) for m in methods}
            for i in tqdm(range(config.samples), desc=f"{distance:g} m", disable=not progress, file=sys.stderr,
                          mininterval=2.0):
                frame, hyp = rendered_hypotheses(shading, db, camera, quats[i], trans, backgrounds[i % len(backgrounds)],
                                                 sun, albedo, FastConfig(), config.particles)
                if hyp is None:
                    continue
                likelihood.prepare(frame)
                start = ParticleSet.from_poses(hyp.positions, quat_normalise(hyp.quats))
                start = start.with_weight(likelihood(start))
                for j, method in enumerate(methods):
                    if method == "boosting":
                        out = start
                    else:  # each optimiser with its own generator, from the same hypotheses
                        opt_rng = np.random.default_rng(np.random.SeedSequence(config.seed, spawn_key=(3, d_i, i, j)))
                        out = make_optimiser(method, config.pfo).run(start, likelihood, opt_rng, config.iterations)
                    best = out.best()
                    t_err[method][i] = best.pos[0] - trans
                    r_err[method][i] = euler_error(quats[i][None], best.quat)[0]
                    scores[method][i] = best.weight[0]
            key = f"{distance:g}"
            failures[key] = int(np.sum(~np.isfinite(scores["boosting"])))
            stats[key] = {m: {
                "translation_m": {a: error_statistics(t_err[m][:, c]) for c, a in enumerate("xyz")},
                "rotation_deg": {a: error_statistics(np.degrees(r_err[m][:, c]))
                                 for c, a in enumerate(("alpha", "beta", "gamma"))},
            } for m in methods}
            best_likelihood[key] = {m: float(np.nanmean(scores[m])) if np.isfinite(scores[m]).any() else float("nan")
                                    for m in methods}
    return {"stats": stats, "failures": failures, "samples": config.samples, "best_likelihood": best_likelihood}


def format_tables(result: dict) -> str:
    """Tables 6.9–6.10 per distance: each method's X / Y / Z (m) and α / β / γ (deg) errors."""
    out = []
    for dist, per_method in result["stats"].items():
        methods = list(per_method)
        used = result["samples"] - result["failures"][dist]
        for group, axes, title in (("translation_m", ("x", "y", "z"), "translation error (meters)"),
                                   ("rotation_deg", ("alpha", "beta", "gamma"), "rotation error (degrees)")):
            out.append(f"Pose optimisation schemes {title} at {dist} m ({used}/{result['samples']} samples with a box)")
            out.append(f"{'':16}" + "".join(f"| {COLUMN_NAMES[m]:<22}" for m in methods))
            out.append(f"{'':16}" + "".join("| " + "".join(f"{a[:5]:>8}" for a in axes)[2:] for _ in methods))
            for key in STAT_KEYS:
                cells = "".join(f"{per_method[m][group][a][key]:8.2f}" for m in methods for a in axes)
                out.append(f"{ROW_NAMES[key]:16}{cells}")
            out.append("")
        means = ", ".join(f"{COLUMN_NAMES[m]} {v:.3f}" for m, v in result["best_likelihood"][dist].items())
        out.append(f"Mean likelihood of the estimate at {dist} m: {means}")
        out.append("")
    return "\n".join(out)
