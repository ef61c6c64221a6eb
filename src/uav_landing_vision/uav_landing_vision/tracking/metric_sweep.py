"""§6.5's sweep of the similarity metrics (Table 6.4): one axis at a time around a nominal pose.

The nominal pose is the UAV facing the camera, upright, on the optical axis at ``distance``
(Table 6.4: X = Y = 0, Z = 5 m, α = β = γ = 0). Rotations are about the camera's axes through
the UAV's centre (the thesis's Euler angles "with respect to the camera reference frame"),
−180…180° in 1° steps; translations span Table 6.4's intervals (Z 3…7 m, Y ±0.24 m, X ±0.74 m,
0.01 m steps) scaled by ``distance``/5 m so that other distances cover the same image span.
Metric variants are the thesis's: colour, Contour15/25 (λ_v = λ_e = 1), DT25/50/100.
The frame comes from the simulator (its ``normal`` or ``complex`` background, shaded
high-detail model, sensor noise) for a camera without distortion: the tracker sees rectified
frames. Scoring uses the low-detail mesh, as the tracker does.
"""

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..evaluation.report import strict_json
from ..geometry import euler_zyx_to_quat, quat_multiply
from .likelihood import ColourConfig, ContourConfig, DistanceTransformConfig, make_likelihood

NOMINAL_DISTANCE_M = 5.0
MIN_SPAN_PX = 16  # the least wing span in the image that the sweep scores
VARIANTS = {
    "colour": {"colour": ColourConfig()},
    "contour": {f"contour{r}": ContourConfig(search_px=r) for r in (15, 25)},
    "distance_transform": {f"dt{s}": DistanceTransformConfig(sigma=float(s)) for s in (25, 50, 100)},
}


@dataclass(frozen=True)
class SweepTest:
    """One row of Table 6.4: ``axis`` 0/1/2 = X/Y/Z; ``values`` of the swept coordinate."""

    number: int
    kind: str  # "rotation" (values in degrees) or "translation" (metres)
    axis: int
    values: np.ndarray

    @property
    def title(self) -> str:
        what = "Rotation around" if self.kind == "rotation" else "Translation along"
        angle = {0: " (α)", 1: " (β)", 2: " (γ)"}[self.axis] if self.kind == "rotation" else ""
        return f"Test {self.number} - {what} {'XYZ'[self.axis]}{angle}"

    @property
    def unit(self) -> str:
        return "deg" if self.kind == "rotation" else "m"


def table_6_4(distance: float = NOMINAL_DISTANCE_M) -> list[SweepTest]:
    """The six tests of Table 6.4 at ``distance`` (translations scaled by distance / 5 m)."""
    scale = distance / NOMINAL_DISTANCE_M
    angles = np.arange(-180, 181, dtype=float)

    def span(half, count):
        return np.linspace(-half, half, count) * scale

    return [
        SweepTest(1, "rotation", 2, angles),
        SweepTest(2, "rotation", 0, angles),
        SweepTest(3, "rotation", 1, angles),
        SweepTest(4, "translation", 2, distance + span(2.0, 401)),
        SweepTest(5, "translation", 1, span(0.24, 49)),
        SweepTest(6, "translation", 0, span(0.74, 149)),
    ]


def nominal_pose(distance: float = NOMINAL_DISTANCE_M) -> tuple[np.ndarray, np.ndarray]:
    """The UAV facing the camera, upright, on the optical axis at ``distance``."""
    from ..sim.trajectory import FACING_CAMERA

    return np.array(FACING_CAMERA, dtype=float), np.array([0.0, 0.0, distance])


def swept_poses(test: SweepTest, distance: float = NOMINAL_DISTANCE_M) -> tuple[np.ndarray, np.ndarray]:
    """Quaternions ``(N,4)`` and translations ``(N,3)`` of every value of ``test``."""
    q0, t0 = nominal_pose(distance)
    n = len(test.values)
    trans = np.tile(t0, (n, 1))
    quats = np.tile(q0, (n, 1))
    if test.kind == "rotation":
        euler = np.zeros((n, 3))  # [α, β, γ] about the camera's X, Y, Z
        euler[:, test.axis] = np.radians(test.values)
        quats = quat_multiply(euler_zyx_to_quat(euler), quats)
    else:
        trans[:, test.axis] = test.values
    return quats, trans


def truth_value(test: SweepTest, distance: float = NOMINAL_DISTANCE_M) -> float:
    """The nominal pose's value of the swept coordinate."""
    return distance if (test.kind, test.axis) == ("translation", 2) else 0.0


def sweep_frame(scenario, camera, distance: float = NOMINAL_DISTANCE_M, seed: int = 0) -> np.ndarray:
    """The simulator's RGB frame, seen by the rectified ``camera``, of the nominal pose over
    ``scenario``'s background."""
    from ..sim.backgrounds import make_background
    from ..sim.simulate import generators, sun_direction
    from ..sim.synthesis import FrameSynthesizer
    from ..sim.trajectory import camera_mount

    rngs = generators(seed)
    with FrameSynthesizer(camera, scenario.imaging) as synth:
        sky = make_background(scenario.background, synth.render_camera, scenario.ship, rngs["background"])
        cam_rot, cam_pos = camera_mount(scenario.ship)
        light = cam_rot.T @ sun_direction(scenario)
        quat, trans = nominal_pose(distance)
        frame, _ = synth.frame(sky.frame(0, 0.0, cam_rot, cam_pos), quat, trans, light, np.zeros(2), rngs["noise"])
    return frame


def run_sweep(metrics=tuple(VARIANTS), distance: float = NOMINAL_DISTANCE_M, background: str = "normal",
              seed: int = 0, tile: int = 64) -> dict:
    """Score every pose of every test for every variant of ``metrics``; curves and peaks.

    Each (test, variant) is one batched render and score. Returns a JSON-ready dict.
    """
    from ..model import SPAN, fixed_wing_mesh
    from ..render import Renderer
    from ..sim.config import load_scenario
    from ..sim.simulate import scenario_camera

    if not 0.5 < distance < np.inf:
        raise ValueError(f"distance must be finite and exceed 0.5 m, got {distance}")
    scenario = load_scenario(background)
    camera = scenario_camera(scenario).rectified()
    if camera.fx * SPAN / distance < MIN_SPAN_PX:  # the curves would be noise (peaks at -180° at 10 km)
        raise ValueError(f"at {distance:g} m the UAV spans {camera.fx * SPAN / distance:.1f} px, "
                         f"under {MIN_SPAN_PX}: choose a smaller distance")
    frame = sweep_frame(scenario, camera, distance, seed)  # after the check: it runs the simulator
    with Renderer(camera, fixed_wing_mesh("low"), tile=tile, max_batch=512) as renderer:
        scorers = {}
        for metric in metrics:
            for label, config in VARIANTS[metric].items():
                scorers[label] = make_likelihood(metric, renderer, config)
                scorers[label].prepare(frame)
        tests = []
        for test in table_6_4(distance):
            batch = renderer.silhouettes(*swept_poses(test, distance))
            truth = truth_value(test, distance)
            curves, peaks = {}, {}
            for label, scorer in scorers.items():
                curve = scorer.score_batch(batch)
                curves[label] = curve.tolist()
                peaks[label] = {"at": float(test.values[np.argmax(curve)]), "value": float(curve.max()),
                                "at_truth": float(curve[np.argmin(np.abs(test.values - truth))])}
            tests.append({"number": test.number, "title": test.title, "kind": test.kind, "axis": "XYZ"[test.axis],
                          "unit": test.unit, "truth": truth, "values": test.values.tolist(),
                          "curves": curves, "peaks": peaks})
    return {"background": background, "distance_m": distance, "seed": seed, "tile": tile, "tests": tests}


def write_results(result: dict, out_dir) -> list[Path]:
    """``metric_sweep.json``, ``metric_sweep.csv`` and the rotation/translation figures."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "metric_sweep.json", out / "metric_sweep.csv"]
    paths[0].write_text(strict_json(result, indent=1))
    with paths[1].open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["test", "axis", "kind", "value", "variant", "likelihood"])
        for t in result["tests"]:
            for label, curve in t["curves"].items():
                w.writerows([t["number"], t["axis"], t["kind"], v, label, c] for v, c in zip(t["values"], curve))
    for kind in ("rotation", "translation"):
        paths.append(out / f"metric_sweep_{kind}_{result['background']}.png")
        plot_tests([t for t in result["tests"] if t["kind"] == kind], paths[-1], result["background"])
    return paths


def plot_tests(tests: list[dict], path, background: str) -> None:
    """One panel per test (as Figs. 6.16–6.20), each variant scaled to its own maximum."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(tests), figsize=(4.6 * len(tests), 3.6), squeeze=False)
    for ax, t in zip(axes[0], tests):
        for label, curve in t["curves"].items():
            curve = np.asarray(curve)
            ax.plot(t["values"], curve / curve.max() if curve.max() > 0 else curve, lw=0.9, label=label)
        ax.axvline(t["truth"], color="k", ls="--", lw=0.8)
        ax.set_title(t["title"], fontsize=9)
        ax.set_xlabel(f"{'angle' if t['kind'] == 'rotation' else t['axis']} [{t['unit']}]")
        ax.set_ylabel("likelihood / its maximum")
        ax.grid(True, alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.suptitle(f"{background} background", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
