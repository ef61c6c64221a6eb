"""``uav-landing evaluate`` on a short simulated approach: accuracy, determinism, ROI sources, outputs;
its bookkeeping (which frames are scored, errors, lost frames, stage times, tables, summary, the
command's options) against a stand-in tracker of known outputs."""

import importlib
import json
from dataclasses import replace
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
import yaml
from bag_edits import record_frame_twice, rename_topics
from scipy.spatial.transform import Rotation

from uav_landing_vision import resources
from uav_landing_vision.cli import main
from uav_landing_vision.evaluation import load_summary, pose_errors
from uav_landing_vision.model import fixed_wing_mesh
from uav_landing_vision.render.boxes import projected_roi
from uav_landing_vision.resources import config_path
from uav_landing_vision.sim import load_scenario, read_camera, read_poses, simulate
from uav_landing_vision.tracking.evaluate import (
    SHARED_STAGES,
    EvaluationError,
    EvaluationResult,
    evaluate_bag,
    format_results,
    parse_variants,
    sequence_label,
    summary,
)
from uav_landing_vision.tracking.track_state import TrackState
from uav_landing_vision.tracking.upf import STAGES, Tracker, TrackResult, load_tracker_config

FRAMES = 12


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    """The complex scenario's approach started at 20 m instead of 80 m (a larger UAV: a short
    sequence that says something about accuracy)."""
    tmp = tmp_path_factory.mktemp("evaluate")
    doc = yaml.safe_load(config_path("scenarios/complex.yaml").read_text())
    doc["camera_info"] = str(config_path("camera.yaml"))
    doc["approach"].update(start_range_m=[20.0, 22.0], cone_start_m=15.0)
    scenario_file = tmp / "near.yaml"
    scenario_file.write_text(yaml.safe_dump(doc))
    simulate(load_scenario(scenario_file), tmp / "near", frames=FRAMES, progress=False)
    return tmp / "near"


@pytest.fixture(scope="module")
def result(bag):
    return evaluate_bag(bag, ["C1N0", "C4N2"], particles=50, roi_source="oracle", progress=False)


def test_oracle_run_is_accurate_and_labelled(bag, result):
    rng = np.linalg.norm(read_poses(bag).trans, axis=1).mean()
    assert result.frames == FRAMES
    # C1N0 publishes the weighted mean of each frame's boosted hypotheses, of scattered depths;
    # C4N2 that of a tracked cloud. Measured 1.09 m / 4.7° and 0.19 m / 3.6° on this sequence,
    # 0.23 m / 1.2° and 0.90 m / 1.7° once the UAV banked into its turns, 0.23 m / 3.3° and
    # 0.90 m / 2.1° with the four-frame rotation window: 12 frames say little.
    bounds = {"C1N0": (0.075, 30.0), "C4N2": (0.06, 10.0)}
    for name, (trans_fraction, rot_deg) in bounds.items():
        err = result.errors[name]
        assert np.all(np.isfinite(err["euclidean"]))  # no lost frame
        assert np.median(err["euclidean"]) < trans_fraction * rng
        assert np.median(err["geodesic"]) < rot_deg
        assert result.ms_per_frame[name] > 0
    doc = summary(result)
    assert "roi_source=oracle" in doc["sequence"]
    assert doc["variants"]["C4N2"]["lost_frames_pct"] == 0.0
    text = format_results(result)
    assert "roi_source=oracle" in text.splitlines()[0] and "Median" in text and "optimisation" in text
    cov = result.covariances["C4N2"]
    assert cov.shape == (FRAMES, 6, 6) and np.all(np.isfinite(cov))
    np.testing.assert_array_equal(result.truth[0], read_poses(bag).trans[:FRAMES])
    by_depth = text.split("median error by true depth")[1].splitlines()
    assert next(r for r in by_depth if r.startswith("all")).rstrip().endswith(f"({FRAMES})")
    coverage = text.split("95 % region")[1].splitlines()
    assert coverage[-1].split()[0] == "all" and f"/{FRAMES} |" in coverage[-1]


def test_same_seed_same_estimates(bag):
    a = evaluate_bag(bag, ["C4N2"], particles=30, roi_source="oracle", frames=4, progress=False)
    b = evaluate_bag(bag, ["C4N2"], particles=30, roi_source="oracle", frames=4, progress=False)
    for x, y in zip(a.estimates["C4N2"], b.estimates["C4N2"]):
        np.testing.assert_array_equal(x, y)


def test_a_refinement_batch_beyond_512_poses_is_rendered(bag):
    """The shared renderer is sized for the largest batch a tracker renders, refinement included."""
    config = load_tracker_config()
    base = replace(config, refine=replace(config.refine, candidates=600))
    result = evaluate_bag(bag, ["C4N2"], particles=30, roi_source="oracle", frames=2, progress=False, base=base)
    assert result.frames == 2


def test_start_skips_frames_and_the_tracker_starts_there(bag):
    """--start S --frames N tracks frames S..S+N−1 from a fresh tracker; errors are of those frames."""
    # the best particle's position: the mean of the resampled set depends on the generator's past draws
    base = replace(load_tracker_config(), estimate="best")
    full = evaluate_bag(bag, ["C1N0"], particles=30, roi_source="oracle", progress=False, base=base)
    part = evaluate_bag(bag, ["C1N0"], particles=30, roi_source="oracle", start=8, frames=10, progress=False,
                        base=base)
    assert part.frames == FRAMES - 8  # clipped to the frames left
    truth = read_poses(bag)
    est = part.estimates["C1N0"][0]
    np.testing.assert_allclose(np.linalg.norm(est - truth.trans[8:], axis=1), part.errors["C1N0"]["euclidean"])
    # C1 uses no past frame: the same frames give the same estimates as in the full run
    np.testing.assert_array_equal(est, full.estimates["C1N0"][0][8:])
    with pytest.raises(EvaluationError, match="start"):
        evaluate_bag(bag, ["C1N0"], particles=30, roi_source="oracle", start=-1, progress=False)


def test_detector_source_without_a_model_fails_clearly(bag, monkeypatch):
    real = resources.model_path

    def no_detector(name):
        if name.endswith(".onnx"):
            raise FileNotFoundError(f"models file '{name}' not found")
        return real(name)

    monkeypatch.setattr(resources, "model_path", no_detector)
    with pytest.raises(EvaluationError, match="detector.*oracle"):
        evaluate_bag(bag, ["C4N2"], frames=2, progress=False)
    with pytest.raises(SystemExit, match="--roi-source detector needs the trained detector"):
        main(["evaluate", "--bag", str(bag), "--frames", "2", "--variants", "C4N2"])


def test_frames_without_a_detection_are_boosted_from_the_last_pose(bag, monkeypatch):
    """Where the detector finds nothing, boosting gets the grown box of the variant's last
    estimate, as the detector node's track box gives it (shipped ``track_box`` settings)."""
    import importlib

    from uav_landing_vision.boosting import PoseHypothesisGenerator
    from uav_landing_vision.detection.track_box import TrackBoxConfig, grow_roi

    evaluate = importlib.import_module("uav_landing_vision.tracking.evaluate")
    camera, truth, vertices = read_camera(bag).rectified(), read_poses(bag), fixed_wing_mesh("high").vertices
    found = 4
    monkeypatch.setattr(evaluate, "detector_rois", lambda cam: lambda frame, k: (
        projected_roi(camera, vertices, truth.quat[k], truth.trans[k]) if k < found else None))
    boxes, generate = [], PoseHypothesisGenerator.generate

    def recorded(self, frame, roi, *args, **kwargs):
        boxes.append(tuple(roi))
        return generate(self, frame, roi, *args, **kwargs)

    monkeypatch.setattr(PoseHypothesisGenerator, "generate", recorded)
    result = evaluate.evaluate_bag(bag, ["C4N2"], particles=30, frames=8, progress=False)
    config = evaluate.shipped_config(TrackBoxConfig, "detector", "track_box")
    assert config.enabled and config.max_frames >= 8 - found
    position, quat = result.estimates["C4N2"]
    expected = [grow_roi(projected_roi(camera, vertices, quat[k - 1], position[k - 1]), config.grow, camera.width,
                         camera.height) for k in range(found, 8)]
    assert boxes[found:] == expected


def test_stride_tracks_and_scores_every_nth_frame(bag, monkeypatch):
    """--stride 3: frames 0, 3, 6, 9 of 12 are tracked, with their own stamps (the motion model
    predicts across the gaps), and scored against their own truth; C1 uses no past frame, so
    its estimates are those of the same frames tracked one by one."""
    base = replace(load_tracker_config(), estimate="best")
    full = evaluate_bag(bag, ["C1N0"], particles=30, roi_source="oracle", progress=False, base=base)
    stamps = []
    real_step = Tracker.step

    def step(self, frame, stamp_ns, hypotheses=None):
        stamps.append(stamp_ns)
        return real_step(self, frame, stamp_ns, hypotheses)

    monkeypatch.setattr(Tracker, "step", step)
    part = evaluate_bag(bag, ["C1N0"], particles=30, roi_source="oracle", progress=False, base=base, stride=3)
    truth = read_poses(bag)
    assert part.frames == 4 and stamps == list(truth.stamps_ns[::3])
    np.testing.assert_array_equal(part.truth[0], truth.trans[::3])
    np.testing.assert_array_equal(part.estimates["C1N0"][0], full.estimates["C1N0"][0][::3])
    assert "roi_source=oracle, stride=3" in summary(part)["sequence"] and "stride" not in summary(full)["sequence"]
    for stride in (0, 1.5, True):
        with pytest.raises(EvaluationError, match="stride must be a positive integer"):
            evaluate_bag(bag, ["C1N0"], particles=30, roi_source="oracle", progress=False, stride=stride)
    with pytest.raises(SystemExit, match="--stride must be at least 1, got 0"):
        main(["evaluate", "--bag", str(bag), "--stride", "0"])


def test_cli_writes_json_and_plots(bag, tmp_path, capsys):
    out = tmp_path / "summary.json"
    assert main(["evaluate", "--bag", str(bag), "--roi-source", "oracle", "--frames", "3", "--variants", "C1N0,C3N1",
                 "--particles", "30", "--json", str(out), "--plots", str(tmp_path / "plots")]) == 0
    doc = load_summary(out)
    assert set(doc["variants"]) == {"C1N0", "C3N1"} and doc["frames"] == 3
    assert "roi_source=oracle" in json.loads(out.read_text())["sequence"]
    assert (tmp_path / "plots" / "rotation_error.png").is_file()
    assert "roi_source=oracle" in capsys.readouterr().out


DECK_CAM = {"/camera/image_raw": "/deck_cam/image_raw", "/camera/camera_info": "/deck_cam/camera_info",
            "/uav/ground_truth": "/rtk/uav_pose"}


def test_a_recording_of_other_topic_names_is_read_with_remap(bag, tmp_path, capsys):
    """As ``uav-landing graph --remap``: the same figures as the bag under the graph's names."""
    renamed = tmp_path / "deck_cam"
    rename_topics(bag, renamed, DECK_CAM)
    args = ["--roi-source", "oracle", "--frames", "3", "--variants", "C3N1", "--particles", "30"]
    with pytest.raises(SystemExit, match="no topic /camera/camera_info; has .*/deck_cam/camera_info"):
        main(["evaluate", "--bag", str(renamed), *args])
    remaps = [a for old, new in DECK_CAM.items() for a in ("--remap", f"{new}:={old}")]
    assert main(["evaluate", "--bag", str(renamed), *remaps, *args, "--json", str(tmp_path / "renamed.json")]) == 0
    assert main(["evaluate", "--bag", str(bag), *args, "--json", str(tmp_path / "plain.json")]) == 0
    figures = [{k: v for k, v in load_summary(tmp_path / f"{name}.json")["variants"]["C3N1"].items() if k != "ms_per_frame"}
               for name in ("renamed", "plain")]
    assert figures[0] == figures[1]
    with pytest.raises(SystemExit, match="--remap '/deck_cam/image_raw': expected FROM:=TO"):
        main(["evaluate", "--bag", str(renamed), "--remap", "/deck_cam/image_raw", *args])


def test_cli_refuses_a_renderer_that_fails_the_self_test(bag, capsys, shift_rasterisation):
    """The tracker node refuses to start on such a machine; evaluate, which reports its figures, too."""
    shift_rasterisation(0.5)
    assert main(["evaluate", "--bag", str(bag), "--roi-source", "oracle", "--frames", "2", "--variants", "C1N0"]) == 1
    captured = capsys.readouterr()
    assert "uav-landing evaluate: this machine's OpenGL draws the UAV unlike the reference" in captured.err
    assert "roi_source=oracle" not in captured.out  # no figures


def test_cli_takes_particles_and_metric_from_the_config_file(bag, tmp_path, monkeypatch):
    """Without --particles or --metric, ``evaluate --config`` runs the file's M and metric."""
    import importlib

    doc = yaml.safe_load(config_path("tracker.yaml").read_text())
    doc["tracker"]["ros__parameters"].update(particles=40, metric="contour")
    (tmp_path / "tracker.yaml").write_text(yaml.safe_dump(doc))
    used = []

    class Stop(Exception):
        pass

    def tracker(config, *args):
        used.append(config)
        raise Stop

    monkeypatch.setattr(importlib.import_module("uav_landing_vision.tracking.evaluate"), "Tracker", tracker)
    with pytest.raises(Stop):
        main(["evaluate", "--bag", str(bag), "--config", str(tmp_path / "tracker.yaml"), "--roi-source", "oracle",
              "--variants", "C1N0"])
    assert (used[0].particles, used[0].metric) == (40, "contour")


def test_variant_lists():
    assert parse_variants("C1N0, c4n2,C1N0") == ["C1N0", "C4N2"]
    for bad in ("", "C4N2,C9N1", "C4"):
        with pytest.raises(ValueError):
            parse_variants(bad)
    with pytest.raises(SystemExit, match="CxNy"):
        main(["evaluate", "--bag", "nowhere", "--variants", "C4N2,C0N1"])


def test_projected_roi_holds_the_projected_model(bag):
    camera = read_camera(bag).rectified()
    truth = read_poses(bag)
    vertices = fixed_wing_mesh("high").vertices
    x, y, w, h = projected_roi(camera, vertices, truth.quat[0], truth.trans[0])
    rvec = Rotation.from_quat(truth.quat[0]).as_rotvec()
    uv, _ = cv2.projectPoints(vertices, rvec, truth.trans[0], camera.K, None)
    pixels = np.floor(uv.reshape(-1, 2) + 0.5)  # OpenCV: integer coordinates are pixel centres
    assert (x, y, x + w - 1, y + h - 1) == (*pixels.min(axis=0), *pixels.max(axis=0))
    assert w < 0.5 * camera.width
    assert projected_roi(camera, vertices, truth.quat[0], -truth.trans[0]) is None  # behind the camera


def test_the_run_releases_its_renderer_however_it_ends(bag, monkeypatch):
    """moderngl frees no GL object on garbage collection: a run that kept its renderer leaked a
    2048x1024 atlas and three frame-sized targets per call, ending well or not."""
    import importlib

    from uav_landing_vision.render import Renderer

    evaluate = importlib.import_module("uav_landing_vision.tracking.evaluate")
    released = []
    real_release = Renderer.release
    monkeypatch.setattr(Renderer, "release", lambda self: released.append(self) or real_release(self))
    evaluate.evaluate_bag(bag, ["C1N0"], particles=30, roi_source="oracle", frames=2, progress=False)
    assert len(released) == 1

    def broken_step(*args, **kwargs):
        raise RuntimeError("a tracker failing mid-run")

    monkeypatch.setattr(evaluate.Tracker, "step", broken_step)
    with pytest.raises(RuntimeError, match="mid-run"):
        evaluate.evaluate_bag(bag, ["C1N0"], particles=30, roi_source="oracle", frames=2, progress=False)
    assert len(released) == 2


def test_a_frame_stamped_no_later_than_the_one_before_is_refused_naming_the_bag(bag, tmp_path):
    """A recording with a frame twice (or out of order): one line naming the bag and the frame
    (it was the tracker's "reset() the tracker for a new time-line")."""
    repeated = tmp_path / "repeated"
    stamps = record_frame_twice(bag, repeated)
    with pytest.raises(SystemExit) as refused:
        main(["evaluate", "--bag", str(repeated), "--variants", "C1N0", "--particles", "30", "--roi-source", "oracle",
              "--frames", "4"])
    assert str(refused.value) == (f"uav-landing evaluate: {repeated}: frame 2 is stamped {stamps[1]} ns, not after "
                                  f"frame 1 ({stamps[1]} ns): a recording's frames must have increasing header stamps")


# --- the bookkeeping of a run, with a stand-in tracker of known outputs ----------------------------

OFFSET = np.array([0.3, 0.4, 0.0])  # estimate − truth: 0.5 m
TILT = Rotation.from_euler("y", 2.0, degrees=True)  # q_e = q_true ⊗ q̄_est: 2° about y
LOST_STATE, NO_POSE = 2, 3  # frames (bag index) the stand-in tracker reports LOST / gives no pose
evaluate = importlib.import_module("uav_landing_vision.tracking.evaluate")


def _stand_in_tracker(truth):
    """A tracker whose estimate at bag frame i is the truth moved by OFFSET and turned by TILT,
    reported LOST at LOST_STATE and without a pose at NO_POSE; its covariance names its variant."""
    index = {int(s): i for i, s in enumerate(truth.stamps_ns)}

    class StandIn:
        def __init__(self, config, camera, renderer):
            self.scale = float(config.variant[1:]) + config.iterations / 10.0

        def step(self, frame, stamp_ns, hypotheses=None):
            i = index[int(stamp_ns)]
            position = truth.trans[i] + OFFSET
            quat = (TILT.inv() * Rotation.from_quat(truth.quat[i])).as_quat()
            state = TrackState.LOST if i == LOST_STATE else TrackState.TRACKING
            if i == NO_POSE:
                position, quat, state = np.full(3, np.nan), np.full(4, np.nan), TrackState.ACQUIRING
            return TrackResult(int(stamp_ns), state, position, quat, np.eye(6) * self.scale, 1.0, 1.0,
                               {s: 1.0 for s in STAGES})

    return StandIn


def _clock():
    """perf_counter that advances one second per call: every timed span is a known 1000 ms."""
    now = [0.0]

    def perf_counter():
        now[0] += 1.0
        return now[0]

    return SimpleNamespace(perf_counter=perf_counter)


def test_each_frame_is_scored_against_its_own_truth_and_lost_states_count_as_lost(bag, monkeypatch):
    truth = read_poses(bag)
    monkeypatch.setattr(evaluate, "Tracker", _stand_in_tracker(truth))
    result = evaluate_bag(bag, ["C1N0", "C4N2"], particles=30, roi_source="oracle", progress=False)
    scored = np.array([i not in (LOST_STATE, NO_POSE) for i in range(FRAMES)])
    for name, scale in (("C1N0", 1.0), ("C4N2", 4.2)):
        err = result.errors[name]
        assert all(np.all(np.isnan(err[c][~scored])) for c in err)  # LOST or no pose: no error at all
        np.testing.assert_allclose(err["x"][scored], 0.3, atol=1e-9)  # signed t̂ − t
        np.testing.assert_allclose(err["y"][scored], 0.4, atol=1e-9)
        np.testing.assert_allclose(err["euclidean"][scored], 0.5, atol=1e-9)
        np.testing.assert_allclose(err["geodesic"][scored], 2.0, atol=1e-9)
        np.testing.assert_allclose(err["beta"][scored], 2.0, atol=1e-9)
        np.testing.assert_allclose(err["alpha"][scored], 0.0, atol=1e-9)
        assert np.all(np.isnan(result.estimates[name][0][~scored]))
        cov = result.covariances[name]
        np.testing.assert_array_equal(cov[scored], np.tile(np.eye(6) * scale, (scored.sum(), 1, 1)))
        assert np.all(np.isnan(cov[~scored]))
        assert summary(result)["variants"][name]["lost_frames_pct"] == pytest.approx(100.0 * 2 / FRAMES)
        assert result.states[name][LOST_STATE] == int(TrackState.LOST)


def test_stage_times_are_means_over_the_tracked_frames_and_ms_per_frame_is_boosting_plus_tracker(bag, monkeypatch):
    truth = read_poses(bag)
    monkeypatch.setattr(evaluate, "Tracker", _stand_in_tracker(truth))
    monkeypatch.setattr(evaluate, "time", _clock())
    result = evaluate_bag(bag, ["C4N2"], particles=30, roi_source="oracle", progress=False, stride=2)
    assert result.frames == FRAMES // 2
    stage_ms = result.stage_ms["C4N2"]
    assert {s: stage_ms[s] for s in SHARED_STAGES} == pytest.approx({s: 1000.0 for s in SHARED_STAGES})
    assert {s: stage_ms[s] for s in STAGES} == pytest.approx({s: 1.0 for s in STAGES})
    assert result.ms_per_frame["C4N2"] == pytest.approx(1000.0 + len(STAGES))


def test_boosting_time_includes_each_variants_own_boosting_where_the_detector_found_nothing(bag, monkeypatch):
    truth = read_poses(bag)
    monkeypatch.setattr(evaluate, "Tracker", _stand_in_tracker(truth))
    monkeypatch.setattr(evaluate, "time", _clock())
    found = 2
    camera, vertices = read_camera(bag).rectified(), fixed_wing_mesh("high").vertices
    monkeypatch.setattr(evaluate, "detector_rois", lambda cam: lambda frame, k: (
        projected_roi(camera, vertices, truth.quat[k], truth.trans[k]) if k < found else None))
    result = evaluate_bag(bag, ["C4N2"], particles=30, frames=4, progress=False)
    # shared boosting 1000 ms every frame, plus the variant's own 1000 ms on the 2 frames of 4 without a detection
    assert result.stage_ms["C4N2"]["boosting"] == pytest.approx(1000.0 + 1000.0 * 2 / 4)


def test_empty_entries_of_a_variant_list_are_skipped():
    assert parse_variants("C1N0,,C4N2, ,") == ["C1N0", "C4N2"]


def test_a_start_beyond_the_bag_has_no_frames(bag):
    with pytest.raises(EvaluationError, match="no frames"):
        evaluate_bag(bag, ["C1N0"], particles=30, roi_source="oracle", start=FRAMES + 5, progress=False)


def test_an_unknown_roi_source_is_refused_before_the_bag_is_read(tmp_path):
    with pytest.raises(EvaluationError, match="roi source must be one of"):
        evaluate_bag(tmp_path / "no_such_bag", ["C1N0"], roi_source="ground_truth", progress=False)


# --- tables and summary of a result with known errors ------------------------------------------


def _result(stride: int = 1) -> EvaluationResult:
    """Four frames at true depths 5, 6, 25 and 40 m (frame 2 far to the side: x = 50 m); the
    estimate 0.5 m and 2° off, lost at frame 3."""
    t = np.array([[0.0, 0.0, 5.0], [0.0, 0.0, 6.0], [50.0, 0.0, 25.0], [0.0, 0.0, 40.0]])
    q = np.tile([0.0, 0.0, 0.0, 1.0], (4, 1))
    t_est = t + OFFSET
    q_est = np.tile((TILT.inv()).as_quat(), (4, 1))
    t_est[3], q_est[3] = np.nan, np.nan
    cov = np.tile(np.eye(6), (4, 1, 1))
    cov[3] = np.nan
    stage_ms = {s: 7.0 if s == "boosting" else 1.0 for s in SHARED_STAGES + STAGES}
    return EvaluationResult("seq", "oracle", 4, {"C4N2": (t_est, q_est)}, {"C4N2": pose_errors(t, q, t_est, q_est)},
                            (t, q), {"C4N2": cov}, {"C4N2": stage_ms}, {"C4N2": 42.0},
                            {"C4N2": np.array([2, 2, 2, 0])}, stride)


def _row(part: str, name: str) -> list[str]:
    return next(line for line in part.splitlines() if line.startswith(name))[16:].split()


def test_results_tables_give_euclidean_translation_and_geodesic_rotation_medians():
    parts = format_results(_result()).split("\n\n")
    assert "translation error (m)" in parts[0] and _row(parts[0], "Median") == ["0.50"]
    assert "rotation error (deg)" in parts[1] and _row(parts[1], "Median") == ["2.00"]


def test_results_bin_the_median_errors_by_the_true_z_depth():
    by_depth = format_results(_result()).split("\n\n")[2]
    assert _row(by_depth, "0-8 m") == ["0.50", "|", "2.00", "(2)"]
    assert _row(by_depth, "15-30 m") == ["0.50", "|", "2.00", "(1)"]
    assert _row(by_depth, "30-60 m") == ["-", "(0)"]  # the lost frame


def test_results_print_the_lost_share_in_percent_and_the_ms_per_frame_of_the_variant():
    timing = format_results(_result()).split("\n\n")[3]
    assert _row(timing, "Lost %") == ["25.00"]
    assert _row(timing, "ms/frame") == ["42.0"]
    assert _row(timing, "boosting") == ["7.0"]


def test_summary_carries_the_ms_per_frame_and_the_label_says_any_stride_but_one():
    doc = summary(_result())
    assert doc["variants"]["C4N2"]["ms_per_frame"] == 42.0
    assert doc["variants"]["C4N2"]["lost_frames_pct"] == 25.0
    assert doc["sequence"] == "seq (roi_source=oracle)"
    assert sequence_label(_result(stride=2)) == "seq (roi_source=oracle, stride=2)"


# --- the command -------------------------------------------------------------------------------


@pytest.fixture
def recorded_run(monkeypatch):
    """evaluate_bag replaced by a recorder returning the known result; no renderer self-test."""
    calls = []

    def fake_evaluate_bag(bag, variants, **kwargs):
        calls.append({"bag": bag, "variants": variants, **kwargs})
        return _result(stride=kwargs.get("stride", 1))

    monkeypatch.setattr(evaluate, "evaluate_bag", fake_evaluate_bag)
    monkeypatch.setattr(importlib.import_module("uav_landing_vision.render.selftest"), "check_renderer",
                        lambda: SimpleNamespace(summary="passed (stand-in)"))
    return calls


def test_the_command_passes_every_option_on_and_labels_its_report(recorded_run, tmp_path):
    argv = ["evaluate", "--bag", str(tmp_path / "bag"), "--variants", "C4N2", "--roi-source", "oracle",
            "--frames", "3", "--start", "1", "--stride", "2", "--seed", "7", "--particles", "30", "--metric", "contour",
            "--json", str(tmp_path / "s.json"), "--plots", str(tmp_path / "plots")]
    assert main(argv) == 0
    call = recorded_run[0]
    assert call["variants"] == ["C4N2"]
    assert {k: call[k] for k in ("roi_source", "frames", "start", "stride", "seed", "particles", "metric")} == {
        "roi_source": "oracle", "frames": 3, "start": 1, "stride": 2, "seed": 7, "particles": 30, "metric": "contour"}
    label = "seq (roi_source=oracle, stride=2)"
    assert load_summary(tmp_path / "s.json")["sequence"] == label
    assert (tmp_path / "plots" / "tables.txt").read_text().startswith(f"{label}: translation error (m)")


@pytest.mark.parametrize("option, value, message", [
    ("--frames", "0", "--frames must be at least 1"),
    ("--start", "-1", "--start must be non-negative"),
    ("--stride", "0", "--stride must be at least 1, got 0"),
    ("--seed", "-1", "--seed must be non-negative, got -1"),
])
def test_the_command_refuses_a_bad_number_before_running(recorded_run, tmp_path, option, value, message):
    with pytest.raises(SystemExit, match=f"^uav-landing evaluate: {message}"):
        main(["evaluate", "--bag", str(tmp_path / "bag"), "--roi-source", "oracle", option, value])
    assert recorded_run == []


def test_every_tracker_gets_the_run_s_m_and_seed_all_m_hypotheses_and_its_states_are_kept(bag, monkeypatch):
    """``particles`` and ``seed`` reach every variant's tracker, each frame's boosting gives the M
    hypotheses a (re)initialisation needs (the tracker takes the first M − M0 otherwise), and the
    result keeps the state each tracker reported at each frame."""
    truth = read_poses(bag)
    stand_in = _stand_in_tracker(truth)
    configs, counts = [], []

    class Recording(stand_in):
        def __init__(self, config, camera, renderer):
            configs.append(config)
            super().__init__(config, camera, renderer)

        def step(self, frame, stamp_ns, hypotheses=None):
            counts.append(None if hypotheses is None else len(hypotheses))
            return super().step(frame, stamp_ns, hypotheses)

    monkeypatch.setattr(evaluate, "Tracker", Recording)
    result = evaluate_bag(bag, ["C1N0", "C4N2"], particles=30, seed=7, roi_source="oracle", frames=6, progress=False)
    assert [(c.variant, c.iterations, c.particles, c.seed) for c in configs] == [("C1", 0, 30, 7), ("C4", 2, 30, 7)]
    assert any(n is not None for n in counts) and all(n in (None, 30) for n in counts)
    expected = [TrackState.TRACKING] * 6
    expected[LOST_STATE], expected[NO_POSE] = TrackState.LOST, TrackState.ACQUIRING
    for name in ("C1N0", "C4N2"):
        assert result.states[name].tolist() == [int(s) for s in expected]


def test_track_boxes_come_from_the_last_pose_given_and_their_run_restarts_at_each_detection(bag, monkeypatch):
    """Detections at frames 0, 1 and 5, track boxes (at most 3 in a row) between: frame 4's box
    is of frame 2's pose, as frame 3 gave none; the detection at frame 5 starts a new run of 3
    track boxes (frames 6–8), and frame 9 gets none."""
    from uav_landing_vision.boosting import PoseHypothesisGenerator
    from uav_landing_vision.detection.track_box import TrackBoxConfig, grow_roi

    truth = read_poses(bag)
    camera, vertices = read_camera(bag).rectified(), fixed_wing_mesh("high").vertices
    monkeypatch.setattr(evaluate, "Tracker", _stand_in_tracker(truth))
    detected = {0, 1, 5}

    def detection(k):
        return projected_roi(camera, vertices, truth.quat[k], truth.trans[k])

    monkeypatch.setattr(evaluate, "detector_rois", lambda cam: lambda frame, k: detection(k) if k in detected else None)
    shipped = evaluate.shipped_config
    monkeypatch.setattr(evaluate, "shipped_config", lambda cls, node, group="": (
        replace(shipped(cls, node, group), max_frames=3) if cls is TrackBoxConfig else shipped(cls, node, group)))
    boxes, generate = [], PoseHypothesisGenerator.generate

    def recorded(self, frame, roi, *args, **kwargs):
        boxes.append(tuple(roi))
        return generate(self, frame, roi, *args, **kwargs)

    monkeypatch.setattr(PoseHypothesisGenerator, "generate", recorded)
    evaluate_bag(bag, ["C4N2"], particles=30, frames=10, progress=False)
    grow = shipped(TrackBoxConfig, "detector", "track_box").grow

    def track_box(i):  # the stand-in's pose at frame i
        quat = (TILT.inv() * Rotation.from_quat(truth.quat[i])).as_quat()
        return grow_roi(projected_roi(camera, vertices, quat, truth.trans[i] + OFFSET), grow, camera.width, camera.height)

    assert boxes == [detection(0), detection(1), track_box(1), track_box(2), track_box(2), detection(5),
                     track_box(5), track_box(6), track_box(7)]


def test_the_timing_table_keeps_wide_figures_of_several_variants_apart():
    """Two variants at over a second per frame: each column's figure stands on its own."""
    one = _result()
    two = replace(one, estimates={**one.estimates, "C1N0": one.estimates["C4N2"]},
                  errors={**one.errors, "C1N0": one.errors["C4N2"]},
                  covariances={**one.covariances, "C1N0": one.covariances["C4N2"]},
                  stage_ms={**one.stage_ms, "C1N0": one.stage_ms["C4N2"]},
                  ms_per_frame={"C4N2": 1234.5, "C1N0": 2345.6}, states={**one.states, "C1N0": one.states["C4N2"]})
    timing = format_results(two).split("\n\n")[3]
    assert _row(timing, "ms/frame") == ["1234.5", "2345.6"]
    assert _row(timing, "Lost %") == ["25.00", "25.00"]
