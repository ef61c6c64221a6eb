"""Tracker timing for ``make bench``: ms per frame per stage of one variant (C4N2, M = 100 by default).

Runs :func:`.evaluate.evaluate_bag` on a bag (default: the first ``frames`` frames of the
``complex`` scenario, simulated into a temporary folder). ROIs come from the ground truth: the
detector's time is not part of this budget (DESIGN §6), and its ROI would change no stage here.
``ms_per_frame`` is boosting plus the whole tracker step.
"""

import tempfile
from pathlib import Path

from .evaluate import SHARED_STAGES, evaluate_bag
from .upf import STAGES


def run(bag=None, frames: int = 30, particles: int = 100, variant: str = "C4N2", seed: int = 0) -> dict:
    """``{"variant", "particles", "frames", "stage_ms": {stage: mean ms}, "ms_per_frame"}``."""
    with tempfile.TemporaryDirectory(prefix="upf-bench-") as tmp:
        if bag is None:
            from ..sim import load_scenario, simulate

            bag = Path(tmp) / "complex"
            simulate(load_scenario("complex"), bag, frames=frames, progress=False)
        result = evaluate_bag(bag, [variant], particles=particles, roi_source="oracle", frames=frames, seed=seed,
                              progress=False)
    name = next(iter(result.stage_ms))
    return {"variant": name, "particles": particles, "frames": result.frames,
            "stage_ms": result.stage_ms[name], "ms_per_frame": result.ms_per_frame[name]}


def format_result(result: dict) -> str:
    """One line per stage, then the per-frame total."""
    lines = [f"Tracker {result['variant']}, M={result['particles']}, {result['frames']} frames (ms per frame):"]
    lines += [f"  {stage:<14}{result['stage_ms'][stage]:8.1f}" for stage in SHARED_STAGES + STAGES]
    lines.append(f"  {'boosting+step':<14}{result['ms_per_frame']:8.1f}")
    return "\n".join(lines)
