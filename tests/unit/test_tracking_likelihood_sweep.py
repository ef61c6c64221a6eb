"""§6.5 metric sweep: Table 6.4's tests, the swept poses, the frame drawn, the peaks read off the
curves, the files written and ``uav-landing eval-metrics``. Renderer, scorers and simulator are
stand-ins where the point is what the sweep hands them."""

import csv
import json

import numpy as np
import pytest

import uav_landing_vision.render as render
import uav_landing_vision.sim.backgrounds as backgrounds
import uav_landing_vision.sim.config as sim_config
import uav_landing_vision.sim.synthesis as synthesis
from uav_landing_vision.cli import main
from uav_landing_vision.geometry import quat_to_matrix
from uav_landing_vision.sim import load_scenario, scenario_camera
from uav_landing_vision.sim.trajectory import FACING_CAMERA
from uav_landing_vision.tracking import metric_sweep
from uav_landing_vision.tracking.metric_sweep import VARIANTS, nominal_pose, swept_poses, table_6_4, truth_value


def test_table_6_4_intervals_and_steps():
    tests = table_6_4(5.0)
    assert [(t.number, t.kind, "XYZ"[t.axis]) for t in tests] == [
        (1, "rotation", "Z"), (2, "rotation", "X"), (3, "rotation", "Y"),
        (4, "translation", "Z"), (5, "translation", "Y"), (6, "translation", "X"),
    ]  # fmt: skip
    spans = [(-180, 180, 1)] * 3 + [(3, 7, 0.01), (-0.24, 0.24, 0.01), (-0.74, 0.74, 0.01)]
    for t, (lo, hi, step) in zip(tests, spans):
        assert t.values[0] == pytest.approx(lo) and t.values[-1] == pytest.approx(hi)
        np.testing.assert_allclose(np.diff(t.values), step, atol=1e-9)
    assert table_6_4(10.0)[5].values[-1] == pytest.approx(1.48)  # scaled with the distance
    depth = table_6_4(10.0)[3]  # Z 3…7 m at 5 m: ±2 m about the distance, ±4 m at 10 m
    assert depth.values[[0, 200, -1]] == pytest.approx([6.0, 10.0, 14.0])
    assert table_6_4(2.5)[3].values[[0, -1]] == pytest.approx([1.5, 3.5])


def test_swept_poses_move_one_coordinate():
    q0, t0 = nominal_pose(5.0)
    np.testing.assert_allclose(quat_to_matrix(q0[None])[0][:, 1], [1, 0, 0], atol=1e-12)  # left wing → image right
    rot_z = table_6_4()[0]
    quats, trans = swept_poses(rot_z)
    at90 = quat_to_matrix(quats[rot_z.values == 90.0])[0]
    np.testing.assert_allclose(at90[:, 1], [0, 1, 0], atol=1e-12)  # rolled 90° about the optical axis
    np.testing.assert_allclose(at90[:, 0], [0, 0, -1], atol=1e-12)  # still facing the camera
    np.testing.assert_array_equal(trans, np.tile(t0, (361, 1)))
    along_x = table_6_4()[5]
    quats, trans = swept_poses(along_x)
    np.testing.assert_allclose(trans[:, 0], along_x.values)
    np.testing.assert_array_equal(trans[:, 1:], np.tile(t0[1:], (149, 1)))
    np.testing.assert_array_equal(quats, np.tile(q0, (149, 1)))
    assert truth_value(table_6_4()[3]) == 5.0 and truth_value(along_x) == 0.0


def test_swept_poses_keep_the_nominal_distance_of_the_sweep():
    for test in table_6_4(12.0):
        quats, trans = swept_poses(test, 12.0)
        np.testing.assert_allclose(np.linalg.norm(quats, axis=1), 1.0)
        if (test.kind, test.axis) != ("translation", 2):
            np.testing.assert_allclose(trans[:, 2], 12.0)
        else:
            np.testing.assert_allclose(trans[:, 2], test.values)


def test_rotation_tests_turn_about_the_camera_axis_they_name():
    """Each rotation test turns the nominal attitude about the camera's X, Y or Z axis; the
    rotation from the nominal attitude has that axis and the swept angle."""
    q0 = quat_to_matrix(nominal_pose()[0][None])[0]
    for test in table_6_4()[:3]:
        quats, _ = swept_poses(test)
        at30 = quat_to_matrix(quats[test.values == 30.0])[0] @ q0.T  # the turn, in camera axes
        axis = np.zeros(3)
        axis[test.axis] = 1.0
        np.testing.assert_allclose(at30 @ axis, axis, atol=1e-12)  # the named axis stays put
        other = np.roll(axis, 1)
        assert np.degrees(np.arccos(np.clip(other @ at30 @ other, -1, 1))) == pytest.approx(30.0)


def test_metric_variants_are_the_thesis_settings():
    """Colour, Contour15/25 (search 15 and 25 px, λ_v = λ_e = 1) and DT25/50/100 (σ)."""
    assert list(VARIANTS["colour"]) == ["colour"]
    contour = VARIANTS["contour"]
    assert {k: (c.search_px, c.lambda_v, c.lambda_e) for k, c in contour.items()} == {
        "contour15": (15, 1.0, 1.0), "contour25": (25, 1.0, 1.0)}
    assert {k: c.sigma for k, c in VARIANTS["distance_transform"].items()} == {"dt25": 25.0, "dt50": 50.0, "dt100": 100.0}


@pytest.fixture
def stand_in_sweep(monkeypatch):
    """``run_sweep`` with its scenario, frame, renderer and scorers replaced: records what each
    receives; the stand-in scorer's curve peaks at a third of each test's values."""
    seen = {"scenarios": [], "frames": [], "renderers": [], "batches": [], "prepared": []}
    real_load = sim_config.load_scenario

    def recorded_load(name):
        seen["scenarios"].append(name)
        return real_load(name)

    def sweep_frame(scenario, camera, distance, seed):
        seen["frames"].append((scenario.name, camera, distance, seed))
        return np.zeros((camera.height, camera.width, 3), np.uint8)

    class Renderer:
        def __init__(self, camera, mesh, tile, max_batch):
            seen["renderers"].append((camera, tile))

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def silhouettes(self, quats, trans):
            seen["batches"].append((quats, trans))
            return len(quats)

    class Scorer:
        def prepare(self, frame):
            seen["prepared"].append(frame.shape)

        def score_batch(self, n):
            return 1.0 - np.abs(np.arange(n) - n // 3) / n

    monkeypatch.setattr(sim_config, "load_scenario", recorded_load)
    monkeypatch.setattr(metric_sweep, "sweep_frame", sweep_frame)
    monkeypatch.setattr(render, "Renderer", Renderer)
    monkeypatch.setattr(metric_sweep, "make_likelihood", lambda metric, renderer, config: Scorer())
    return seen


def test_run_sweep_hands_background_seed_tile_and_poses_on(stand_in_sweep):
    seen = stand_in_sweep
    result = metric_sweep.run_sweep(("colour",), distance=8.0, background="complex", seed=3, tile=32)
    assert seen["scenarios"] == ["complex"]
    (name, camera, distance, seed), = seen["frames"]
    assert (name, distance, seed) == ("complex", 8.0, 3)
    assert not camera.is_distorted  # the tracker scores rectified frames
    assert [tile for _, tile in seen["renderers"]] == [32] and not seen["renderers"][0][0].is_distorted
    assert seen["prepared"] == [(camera.height, camera.width, 3)]
    assert (result["background"], result["distance_m"], result["seed"], result["tile"]) == ("complex", 8.0, 3, 32)
    for test, (quats, trans), doc in zip(table_6_4(8.0), seen["batches"], result["tests"]):
        q, t = swept_poses(test, 8.0)
        np.testing.assert_array_equal(quats, q)
        np.testing.assert_array_equal(trans, t)
        assert doc["truth"] == (8.0 if (test.kind, test.axis) == ("translation", 2) else 0.0)
        assert doc["values"] == test.values.tolist()


def test_run_sweep_reads_each_peak_and_the_value_at_the_truth(stand_in_sweep):
    result = metric_sweep.run_sweep(("colour",), distance=8.0)
    for test, doc in zip(table_6_4(8.0), result["tests"]):
        n = len(test.values)
        curve = 1.0 - np.abs(np.arange(n) - n // 3) / n
        assert doc["curves"]["colour"] == curve.tolist()
        truth_index = int(np.argmin(np.abs(test.values - doc["truth"])))
        assert truth_index == n // 2  # the nominal value is the middle one of every test
        assert doc["peaks"]["colour"] == {"at": test.values[n // 3], "value": 1.0, "at_truth": curve[truth_index]}


def test_sweep_frame_draws_the_nominal_pose_at_the_sweep_distance(monkeypatch):
    drawn = []

    class Synth:
        def __init__(self, camera, imaging):
            self.render_camera = camera

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def frame(self, sky, quat, trans, light, offset, rng):
            drawn.append((sky, quat, trans, light))
            return "frame", None

    sky = type("Sky", (), {"frame": lambda self, *args: "sky"})()
    monkeypatch.setattr(synthesis, "FrameSynthesizer", Synth)
    monkeypatch.setattr(backgrounds, "make_background", lambda *args: sky)
    scenario = load_scenario("normal")
    assert metric_sweep.sweep_frame(scenario, scenario_camera(scenario).rectified(), 9.0, seed=1) == "frame"
    (sky_frame, quat, trans, light), = drawn
    assert sky_frame == "sky"
    np.testing.assert_array_equal(trans, [0.0, 0.0, 9.0])
    np.testing.assert_allclose(quat, FACING_CAMERA)
    assert np.linalg.norm(light) == pytest.approx(1.0)


def test_write_results_csv_rows_are_value_then_likelihood(tmp_path, monkeypatch):
    monkeypatch.setattr(metric_sweep, "plot_tests", lambda tests, path, background: path.write_bytes(b"png"))
    result = {"background": "normal", "tests": [
        {"number": 4, "axis": "Z", "kind": "translation", "values": [4.0, 5.0, 6.0],
         "curves": {"dt25": [0.1, 0.9, 0.3], "colour": [0.2, 0.5, 0.4]}}]}
    paths = metric_sweep.write_results(result, tmp_path / "out")
    assert [p.name for p in paths] == ["metric_sweep.json", "metric_sweep.csv", "metric_sweep_rotation_normal.png",
                                       "metric_sweep_translation_normal.png"]
    assert json.loads(paths[0].read_text()) == result
    with paths[1].open() as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["test", "axis", "kind", "value", "variant", "likelihood"]
    assert rows[1:] == [["4", "Z", "translation", "4.0", "dt25", "0.1"], ["4", "Z", "translation", "5.0", "dt25", "0.9"],
                        ["4", "Z", "translation", "6.0", "dt25", "0.3"], ["4", "Z", "translation", "4.0", "colour", "0.2"],
                        ["4", "Z", "translation", "5.0", "colour", "0.5"], ["4", "Z", "translation", "6.0", "colour", "0.4"]]


def test_eval_metrics_command_peaks_at_the_true_pose(tmp_path, capsys):
    assert main(["eval-metrics", "--metric", "colour", "--out", str(tmp_path), "--seed", "1"]) == 0
    assert "Test 6 - Translation along X" in capsys.readouterr().out
    doc = json.loads((tmp_path / "metric_sweep.json").read_text())
    tolerance = {1: 2.0, 2: 2.0, 3: 2.0, 4: 0.3, 5: 0.02, 6: 0.02}
    for t in doc["tests"]:
        assert list(t["curves"]) == ["colour"]
        assert abs(t["peaks"]["colour"]["at"] - t["truth"]) <= tolerance[t["number"]], t["title"]
    with (tmp_path / "metric_sweep.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 3 * 361 + 401 + 49 + 149
    for kind in ("rotation", "translation"):
        assert (tmp_path / f"metric_sweep_{kind}_normal.png").stat().st_size > 10_000


def test_eval_metrics_refuses_bad_distance(tmp_path):
    with pytest.raises(SystemExit, match="distance"):
        main(["eval-metrics", "--distance", "0.2", "--out", str(tmp_path)])
    # So far that the UAV is a few pixels: curves of noise written as results before.
    with pytest.raises(SystemExit, match=r"at 10000 m the UAV spans 0.\d px, under 16: choose a smaller distance"):
        main(["eval-metrics", "--distance", "1e4", "--out", str(tmp_path / "far")])
    assert not (tmp_path / "far").exists()


def test_eval_metrics_checks_the_span_before_making_the_frame(monkeypatch, tmp_path):
    from uav_landing_vision.tracking import metric_sweep

    def no_frame(*args):
        raise AssertionError("the frame was made before the span check")

    monkeypatch.setattr(metric_sweep, "sweep_frame", no_frame)
    with pytest.raises(SystemExit, match="choose a smaller distance"):
        main(["eval-metrics", "--distance", "1e4", "--out", str(tmp_path)])
