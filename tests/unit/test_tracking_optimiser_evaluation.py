"""``uav-landing eval-optimisers`` (§6.6): boosted hypotheses refined by each optimiser, Tables 6.9–6.10; the
tables recomputed from what each optimiser returned (scipy rotations as the oracle), the scored start, the
samples' poses, the table layout."""

import json
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from test_boosting_evaluation import fake_cell
from uav_landing_vision.boosting import NOMINAL_QUAT, DatabaseConfig, build_database
from uav_landing_vision.boosting import evaluation
from uav_landing_vision.camera import load_camera_info_yaml
from uav_landing_vision.cli import main
from uav_landing_vision.evaluation.statistics import STAT_KEYS, error_statistics
from uav_landing_vision.model import fixed_wing_mesh
from uav_landing_vision.resources import config_path
from uav_landing_vision.tracking import optimiser_evaluation
from uav_landing_vision.tracking.optimiser_evaluation import OptimiserEvalConfig, evaluate_optimisers, format_tables


@pytest.fixture(scope="module")
def result():
    camera = load_camera_info_yaml(config_path("camera.yaml"))
    config = OptimiserEvalConfig(samples=3, distances=(5.0, 20.0), particles=30, iterations=3,
                                 optimisers=("pfo", "pso", "gabf"))
    return evaluate_optimisers(camera, fixed_wing_mesh("high"), config, progress=False)


RECORDED = OptimiserEvalConfig(samples=2, distances=(6.0, 12.0), particles=12, iterations=2,
                               optimisers=("pfo", "gabf"), seed=3)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """``RECORDED`` run over a 300-entry ±30° database: per sample its pose, k and hypotheses, and
    per optimiser the start it was given, that start rescored, its iterations and its result."""
    camera = load_camera_info_yaml(config_path("camera.yaml"))
    mesh = fixed_wing_mesh("high")
    db = build_database(camera, mesh, DatabaseConfig(count=300, half_range_deg=(30.0, 30.0, 30.0), seed=3),
                        progress=False)
    path = db.save(tmp_path_factory.mktemp("db") / "db.npz")
    samples = []
    real_hypotheses, real_make = evaluation.rendered_hypotheses, optimiser_evaluation.make_optimiser

    def hypotheses_spy(renderer, db, camera, quat, trans, *args, **kwargs):
        frame, hyp = real_hypotheses(renderer, db, camera, quat, trans, *args, **kwargs)
        samples.append(dict(quat=np.array(quat, float), trans=np.array(trans, float), k=args[4], hyp=hyp, runs={}))
        return frame, hyp

    class Recorder:
        def __init__(self, name, pfo):
            self.name, self.inner = name, real_make(name, pfo)

        def run(self, start, likelihood, rng, iterations):
            rescored = likelihood(start)
            out = self.inner.run(start, likelihood, rng, iterations)
            samples[-1]["runs"][self.name] = dict(start=start, rescored=rescored, iterations=iterations, out=out)
            return out

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(evaluation, "BACKGROUND_FRAMES", 2)
        mp.setattr(evaluation, "rendered_hypotheses", hypotheses_spy)
        mp.setattr(optimiser_evaluation, "make_optimiser", lambda name, pfo: Recorder(name, pfo))
        result = evaluate_optimisers(camera, mesh, RECORDED, database_path=path, progress=False)
    return samples, result


def _errors(q_true, t_true, best):
    """Oracle: estimate − truth, and the Euler angles [α, β, γ] (deg) of q_g ⊗ q̄_r (scipy)."""
    truth = Rotation.from_quat(q_true)
    euler = (truth * Rotation.from_quat(best.quat[0]).inv()).as_euler("ZYX")[::-1]
    return best.pos[0] - t_true, np.degrees(euler)


def test_every_method_has_the_tables_rows_per_distance_and_axis(result):
    assert list(result["stats"]) == ["5", "20"] and result["samples"] == 3
    for per_method in result["stats"].values():
        assert list(per_method) == ["boosting", "pfo", "pso", "gabf"]
        cell = per_method["gabf"]
        assert list(cell["translation_m"]) == ["x", "y", "z"] and list(cell["rotation_deg"]) == ["alpha", "beta", "gamma"]
        assert list(cell["rotation_deg"]["beta"]) == list(STAT_KEYS)
    text = format_tables(result)
    assert "Pose optimisation schemes rotation error (degrees) at 20 m" in text and "Mod. PSO" not in text


def _fake_result(failures):
    return {"stats": {"5": {"boosting": fake_cell(100), "pso": fake_cell(200)}}, "failures": {"5": failures},
            "samples": 9, "best_likelihood": {"5": {"boosting": 0.25, "pso": 0.5}}}


def test_tables_count_the_samples_with_a_box_and_group_columns_by_method_then_axis():
    text = format_tables(_fake_result(2))
    lines = text.splitlines()
    assert lines[0] == "Pose optimisation schemes translation error (meters) at 5 m (7/9 samples with a box)"
    assert [float(v) for v in re.findall(r"-?\d+\.\d+", lines[3])] == [100.0, 101.0, 102.0, 200.0, 201.0, 202.0]
    assert "Mean likelihood of the estimate at 5 m: Boosting 0.250, PSO 0.500" in text


def test_the_tables_hold_each_methods_own_errors(result, recorded):
    """Errors of each method's own estimate, not of the boosted start nor the pose itself: the
    depth is found to a fraction of the range, and the optimisers move away from the start. Each
    method's table and mean likelihood are exactly those of its own most likely pose."""
    for distance, per_method in result["stats"].items():
        for cell in per_method.values():
            assert abs(cell["translation_m"]["z"]["median"]) < 0.4 * float(distance)
            assert max(cell["translation_m"][a]["mae"] for a in "xy") < 0.1 * float(distance)
        for part in ("translation_m", "rotation_deg"):
            start = json.dumps(per_method["boosting"][part], sort_keys=True)
            assert any(json.dumps(per_method[m][part], sort_keys=True) != start for m in ("pfo", "pso", "gabf"))
    samples, tables = recorded
    n = RECORDED.samples
    assert len(samples) == n * len(RECORDED.distances)
    for d_i, distance in enumerate(RECORDED.distances):
        key = f"{distance:g}"
        mine = [s for s in samples[d_i * n:(d_i + 1) * n] if s["hyp"] is not None]
        assert tables["failures"][key] == n - len(mine)
        for method in ("boosting", *RECORDED.optimisers):
            runs = [s["runs"][RECORDED.optimisers[0] if method == "boosting" else method] for s in mine]
            bests = [(run["start"] if method == "boosting" else run["out"]).best() for run in runs]
            errs = [_errors(s["quat"], s["trans"], b) for s, b in zip(mine, bests)]
            t, r = np.array([e[0] for e in errs]), np.array([e[1] for e in errs])
            cell = tables["stats"][key][method]
            for c, a in enumerate("xyz"):
                got, want = cell["translation_m"][a], error_statistics(t[:, c])
                np.testing.assert_allclose([got[s] for s in STAT_KEYS], [want[s] for s in STAT_KEYS], atol=1e-9,
                                           equal_nan=True)
            for c, a in enumerate(("alpha", "beta", "gamma")):
                got, want = cell["rotation_deg"][a], error_statistics(r[:, c])
                np.testing.assert_allclose([got[s] for s in STAT_KEYS], [want[s] for s in STAT_KEYS], atol=1e-6,
                                           equal_nan=True)
            mean = np.mean([b.weight[0] for b in bests])
            assert tables["best_likelihood"][key][method] == pytest.approx(mean, rel=1e-12)


def test_optimisers_start_from_the_m_scored_hypotheses_and_run_n_iterations(recorded):
    samples, _ = recorded
    for s in samples:
        assert s["k"] == RECORDED.particles
        if s["hyp"] is None:
            continue
        assert list(s["runs"]) == list(RECORDED.optimisers)
        for run in s["runs"].values():
            assert run["iterations"] == RECORDED.iterations
            np.testing.assert_allclose(run["start"].pos, s["hyp"].positions)
            np.testing.assert_allclose(run["start"].weight, run["rescored"], rtol=1e-9)  # weighted by (5.14)
            assert np.ptp(run["start"].weight) > 0


def test_samples_are_on_the_axis_at_each_distance_inside_the_database_interval(recorded):
    samples, _ = recorded
    for d_i, distance in enumerate(RECORDED.distances):
        for s in samples[d_i * RECORDED.samples:(d_i + 1) * RECORDED.samples]:
            np.testing.assert_array_equal(s["trans"], [0.0, 0.0, distance])
    quats = np.array([s["quat"] for s in samples])
    rel = Rotation.from_quat(quats) * Rotation.from_quat(NOMINAL_QUAT).inv()
    assert np.all(np.abs(np.degrees(rel.as_euler("ZYX"))) <= 30.0 + 1e-6)


def test_the_swarm_and_gabf_keep_their_best_so_they_never_end_below_the_boosted_start(result):
    """PSO returns each particle's best pose and GAbF its elite: their estimate scores at least the
    most likely hypothesis they started from (PFO, without elitism as in the thesis, may not)."""
    for per_method in result["best_likelihood"].values():
        assert per_method["pso"] >= per_method["boosting"] - 1e-12
        assert per_method["gabf"] >= per_method["boosting"] - 1e-12
        assert all(0.0 <= v <= 1.0 for v in per_method.values())


def test_same_seed_same_tables(result):
    camera = load_camera_info_yaml(config_path("camera.yaml"))
    config = OptimiserEvalConfig(samples=3, distances=(5.0, 20.0), particles=30, iterations=3,
                                 optimisers=("pfo", "pso", "gabf"))
    again = evaluate_optimisers(camera, fixed_wing_mesh("high"), config, progress=False)
    assert json.dumps(again, sort_keys=True) == json.dumps(result, sort_keys=True)


def test_command_writes_json_and_refuses_bad_settings(tmp_path, capsys):
    out = tmp_path / "opt.json"
    assert main(["eval-optimisers", "--samples", "1", "--distances", "10", "--particles", "10", "--iterations", "1",
                 "--optimisers", "constricted_pso", "--pfo-schedule", "3phase", "--quiet", "--json", str(out)]) == 0
    written = json.loads(out.read_text())
    assert list(written["stats"]["10"]) == ["boosting", "constricted_pso"]
    # the one sample at 10 m gives a box (the wings span ~200 px): it is scored, and the swarm keeps its best start
    assert written["failures"]["10"] == 0
    best = written["best_likelihood"]["10"]
    assert 0.0 < best["boosting"] <= best["constricted_pso"] <= 1.0
    assert "Mod. PSO" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="optimisers must be among"):
        main(["eval-optimisers", "--optimisers", "annealing"])
    for optimisers in [(), ("pso", "annealing")]:  # none, or an unknown one among known ones
        with pytest.raises(ValueError, match="optimisers must be among"):
            OptimiserEvalConfig(optimisers=optimisers)
    with pytest.raises(SystemExit, match="particles >= 2"):
        main(["eval-optimisers", "--particles", "1"])
