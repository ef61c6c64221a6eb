"""``uav-landing bench`` and the per-stage benchmarks behind it: what each one runs, how many
times, and in which unit it reports. The slow cores are replaced by stand-ins that advance a
fake clock by known amounts, so the reported numbers are known exactly (nothing is timed)."""

import types
from pathlib import Path

import numpy as np
import pytest

from uav_landing_vision import sim
from uav_landing_vision.camera import load_camera_info_yaml
from uav_landing_vision.cli import main
from uav_landing_vision.detection import benchmark as detector_benchmark
from uav_landing_vision.detection import detector, verifier
from uav_landing_vision.detection.detector import DetectorConfig
from uav_landing_vision.filters import KINDS
from uav_landing_vision.filters import benchmark as filter_benchmark
from uav_landing_vision.render import benchmark as render_benchmark
from uav_landing_vision.resources import config_path
from uav_landing_vision.tracking import likelihood_benchmark, upf_benchmark
from uav_landing_vision.tracking.evaluate import SHARED_STAGES
from uav_landing_vision.tracking.likelihood import LIKELIHOODS
from uav_landing_vision.tracking.upf import STAGES


class FakeClock:
    """``perf_counter`` of a clock that moves only when a stand-in says so."""

    def __init__(self):
        self.now = 100.0

    def perf_counter(self):
        return self.now

    def advance(self, seconds):
        self.now += seconds

    def module(self):
        return types.SimpleNamespace(perf_counter=self.perf_counter)


@pytest.fixture
def bench_stand_ins(monkeypatch):
    """Every benchmark's ``run`` records its keyword arguments and returns a small fixed result."""
    calls = {}

    def recording(name, result):
        def run(**kwargs):
            calls[name] = kwargs
            return result
        return run

    monkeypatch.setattr(render_benchmark, "run", recording("render", []))
    monkeypatch.setattr(render_benchmark, "format_rows", lambda rows: "render rows")
    monkeypatch.setattr(likelihood_benchmark, "run", recording("likelihood", {}))
    monkeypatch.setattr(likelihood_benchmark, "format_result", lambda r: "likelihood rows")
    monkeypatch.setattr(filter_benchmark, "run", recording("filters", {"ukf": 1.5}))
    monkeypatch.setattr(upf_benchmark, "run", recording("upf", {}))
    monkeypatch.setattr(upf_benchmark, "format_result", lambda r: "upf rows")
    monkeypatch.setattr(detector_benchmark, "run", recording("detector", {}))
    monkeypatch.setattr(detector_benchmark, "format_result", lambda r: "detector rows")
    return calls


def test_bench_passes_its_repeats_on_to_every_timed_benchmark(bench_stand_ins, capsys):
    assert main(["bench", "--repeats", "3"]) == 0
    assert bench_stand_ins["render"] == {"repeats": 3}
    assert bench_stand_ins["likelihood"] == {"repeats": 3}
    assert bench_stand_ins["filters"] == {"m": 100, "repeats": 30}  # a filter step is short: ten times as many
    assert bench_stand_ins["detector"] == {"repeats": 3}
    out = capsys.readouterr().out
    assert "       ukf    1.500 ms" in out  # the filter benchmark's milliseconds, printed as such


def test_bench_refuses_fewer_than_one_repeat(bench_stand_ins):
    with pytest.raises(SystemExit, match="--repeats must be at least 1"):
        main(["bench", "--repeats", "0"])
    assert bench_stand_ins == {}


def test_bench_without_a_detector_model_reports_the_rest(bench_stand_ins, monkeypatch, capsys):
    def no_model(**kwargs):
        raise FileNotFoundError("models file 'detector.onnx' not found")

    monkeypatch.setattr(detector_benchmark, "run", no_model)
    assert main(["bench", "--repeats", "1"]) == 0
    out = capsys.readouterr().out
    assert "render rows" in out and "upf rows" in out
    assert "Detector: not measured, no model (models file 'detector.onnx' not found)" in out


def test_render_random_poses_are_centred_in_the_middle_of_the_image():
    camera = load_camera_info_yaml(config_path("camera.yaml")).rectified()
    quats, trans = render_benchmark.random_poses(camera, 2000, np.random.default_rng(7))
    np.testing.assert_allclose(np.linalg.norm(quats, axis=1), 1.0)
    K = camera.K
    u = K[0, 0] * trans[:, 0] / trans[:, 2] + K[0, 2]
    v = K[1, 1] * trans[:, 1] / trans[:, 2] + K[1, 2]
    assert np.all((u >= 0.1 * camera.width) & (u <= 0.9 * camera.width))
    assert np.all((v >= 0.1 * camera.height) & (v <= 0.9 * camera.height))
    # ... and anywhere in it: across the whole middle 80 % of both sides, and the 5-80 m range
    assert u.min() < 0.15 * camera.width and u.max() > 0.85 * camera.width
    assert v.min() < 0.15 * camera.height and v.max() > 0.85 * camera.height
    assert 5.0 <= trans[:, 2].min() < 10.0 and 75.0 < trans[:, 2].max() <= 80.0


def test_render_benchmark_rows_are_milliseconds_per_call_after_a_warm_up(monkeypatch):
    clock = FakeClock()
    made = []

    class StandInRenderer:
        """Records its tile and calls; each ``silhouettes`` call takes 4 ms of the fake clock."""

        gl_renderer = "stand-in"

        def __init__(self, camera, mesh, tile, max_batch):
            self.tile, self.calls = tile, 0
            made.append(self)

        def silhouettes(self, quats, trans):
            self.calls += 1
            clock.advance(0.004)

        def release(self):
            pass

    monkeypatch.setattr(render_benchmark, "time", clock.module())
    monkeypatch.setattr(render_benchmark, "Renderer", StandInRenderer)
    rows = render_benchmark.run(particles=(3, 5), tiles=(16, 32), repeats=4)
    assert [(r["mesh"], r["particles"], r["tile"]) for r in rows] == [
        ("low", 3, 16), ("low", 3, 32), ("low", 5, 16), ("low", 5, 32), ("high", 5, 32)]
    assert [r.tile for r in made] == [16, 32, 16, 32, 32]
    assert all(r.calls == 4 + 1 for r in made)  # one untimed warm-up call each
    assert [r["ms"] for r in rows] == [4.0] * 5
    assert [r["particles_per_s"] for r in rows] == [750, 750, 1250, 1250, 1250]


def test_filter_benchmark_times_predict_and_update_of_every_filter_after_five_warm_up_steps(monkeypatch):
    clock = FakeClock()
    made = []

    class StandInFilter:
        def __init__(self, cfg, kind):
            self.cfg, self.kind, self.steps = cfg, kind, []
            made.append(self)

        def init(self, mean, rates):
            return 0

        def predict(self, state):
            return state + 1

        def update(self, state, z):
            self.steps.append((state, np.shape(z)))
            clock.advance(0.1 if len(self.steps) <= 5 else 0.002)  # the first steps are slow
            return state

    monkeypatch.setattr(filter_benchmark, "time", clock.module())
    monkeypatch.setattr(filter_benchmark, "TranslationFilter", lambda cfg: StandInFilter(cfg, "translation"))
    monkeypatch.setattr(filter_benchmark, "make_rotation_filter", lambda cfg: StandInFilter(cfg, cfg.rotation_filter))
    out = filter_benchmark.run(m=4, repeats=1)
    assert list(out) == ["ukf_translation", *KINDS, *(f"{k}+outliers" for k in KINDS)]
    assert out == {name: pytest.approx(2.0) for name in out}  # ms of the timed step, the warm-up left out
    by_name = dict(zip(out, made))
    assert [by_name[k].cfg.rotation_filter for k in KINDS] == list(KINDS)
    assert all(by_name[k].cfg.outlier_prob == 0.0 for k in KINDS)
    assert all(by_name[f"{k}+outliers"].cfg.outlier_prob == 0.12 for k in KINDS)
    for filt in made:  # predict, then update with a batch of m measurements, at every step
        assert [s for s, _ in filt.steps] == [1, 2, 3, 4, 5, 6]
        assert filt.steps[0][1] == ((4, 3) if filt.kind == "translation" else (4, 4))


def test_filter_benchmark_measurements_are_near_but_not_at_the_filters_attitudes(monkeypatch):
    seen = {}

    class StandIn:
        def __init__(self, cfg):
            self.cfg = cfg

        def init(self, mean, rates):
            seen.setdefault("mean", mean)
            return mean

        def predict(self, state):
            return state

        def update(self, state, z):
            seen.setdefault(self.cfg.rotation_filter, (state, z))
            return state

    monkeypatch.setattr(filter_benchmark, "make_rotation_filter", StandIn)
    filter_benchmark.run(m=50, repeats=1)
    quat, meas = seen["ukf"]
    np.testing.assert_allclose(np.linalg.norm(meas, axis=1), 1.0)
    angle = 2 * np.degrees(np.arccos(np.clip(np.abs(np.sum(quat * meas, axis=1)), 0, 1)))
    assert 0.5 < np.median(angle) < 20.0


def test_detector_benchmark_reports_milliseconds_of_the_detector_and_of_a_full_verifier_batch(monkeypatch):
    clock = FakeClock()
    seen = {"detect": [], "verify": []}
    step_ms = iter([50.0, *range(1, 11), 70.0, *[4.0] * 10])  # warm-up, then the timed calls

    class StandInDetector:
        def __init__(self, config):
            seen["config"] = config

        def detect(self, frame):
            seen["detect"].append(frame.shape)
            clock.advance(next(step_ms) / 1e3)

    class StandInVerifier:
        def __init__(self, model, threads):
            seen["verifier"] = (model, threads)

        def probabilities(self, frame, boxes):
            seen["verify"].append(boxes)
            clock.advance(next(step_ms) / 1e3)

    monkeypatch.setattr(detector_benchmark, "time", clock.module())
    monkeypatch.setattr(detector, "Detector", StandInDetector)
    monkeypatch.setattr(verifier, "BoxVerifier", StandInVerifier)
    result = detector_benchmark.run(repeats=10, threads=3, width=640, height=360)
    assert seen["config"].threads == 3 and seen["verifier"] == ("verifier.onnx", 3)
    assert seen["detect"] == [(360, 640, 3)] * 11  # one warm-up call, then the repeats
    assert len(seen["verify"]) == 11
    assert result["median_ms"] == pytest.approx(5.5) and result["p90_ms"] == pytest.approx(9.1)
    assert result["verifier_median_ms"] == pytest.approx(4.0)
    n = DetectorConfig().max_detections
    assert result["verifier_boxes"] == n and result["threads"] == 3 and tuple(result["size"]) == (640, 360)
    boxes = seen["verify"][0]
    assert boxes.shape == (n, 4)  # the most boxes the detector may return, every one inside the frame
    assert np.all(boxes[:, 0] >= 0) and np.all(boxes[:, 2] <= 640) and np.all(boxes[:, 2] > boxes[:, 0])
    assert np.all(boxes[:, 1] >= 0) and np.all(boxes[:, 3] <= 360) and np.all(boxes[:, 3] > boxes[:, 1])


def test_detector_benchmark_text_names_median_and_p90_in_their_places():
    text = detector_benchmark.format_result({"median_ms": 12.34, "p90_ms": 56.78, "threads": 2, "size": (1280, 720),
                          "verifier_median_ms": 3.21, "verifier_boxes": 20})
    assert text == ("Detector (onnxruntime, 2 threads), 1280x720 frame: median 12.3 ms, p90 56.8 ms; "
                    "box verifier (when on) on 20 boxes: median 3.2 ms")


def test_likelihood_benchmark_times_render_prepare_and_score_separately(monkeypatch):
    clock = FakeClock()
    seen = {"renderers": [], "prepare": [], "score": []}

    class StandInRenderer:
        gl_renderer = "stand-in"

        def __init__(self, camera, mesh, tile, max_batch):
            seen["renderers"].append((tile, max_batch))

        def shaded(self, quats, trans, background):
            return np.zeros_like(background), None

        def silhouettes(self, quats, trans):
            clock.advance(0.002)
            return "batch"

    class StandInLikelihood:
        def __init__(self, name):
            self.name = name

        def prepare(self, frame):
            seen["prepare"].append(self.name)
            clock.advance(0.001)

        def score_batch(self, batch):
            seen["score"].append((self.name, batch))
            clock.advance(0.003)

    monkeypatch.setattr(likelihood_benchmark, "time", clock.module())
    monkeypatch.setattr(likelihood_benchmark, "Renderer", StandInRenderer)
    monkeypatch.setattr(likelihood_benchmark, "make_likelihood", lambda name, renderer: StandInLikelihood(name))
    result = likelihood_benchmark.run(particles=7, tile=32, repeats=3)
    assert seen["renderers"] == [(32, 7)]
    assert result["particles"] == 7 and result["tile"] == 32
    assert result["render_ms"] == 2.0
    assert result["prepare_ms"] == {name: 1.0 for name in LIKELIHOODS}
    assert result["score_ms"] == {name: 3.0 for name in LIKELIHOODS}
    assert seen["score"] == [(name, "batch") for name in LIKELIHOODS for _ in range(3)]


def test_likelihood_benchmark_text_puts_prepare_before_score():
    text = likelihood_benchmark.format_result({"gl_renderer": "X", "particles": 100, "tile": 64, "render_ms": 1.5,
                          "prepare_ms": {"colour": 2.25}, "score_ms": {"colour": 7.75}})
    assert text.splitlines()[1] == "render + readback: 1.50 ms"
    assert text.splitlines()[-1].split() == ["colour", "2.25", "7.75"]


@pytest.fixture
def upf_stand_ins(monkeypatch):
    seen = {}

    def simulate(scenario, bag, **kwargs):
        seen["simulate"] = (scenario, Path(bag).name, kwargs)

    def evaluate_bag(bag, variants, **kwargs):
        seen["evaluate"] = (bag, variants, kwargs)
        return types.SimpleNamespace(stage_ms={variants[0]: {"prepare": 1.0}}, ms_per_frame={variants[0]: 9.0},
                                     frames=kwargs["frames"] - 1)

    monkeypatch.setattr(sim, "load_scenario", lambda name: f"scenario {name}")
    monkeypatch.setattr(sim, "simulate", simulate)
    monkeypatch.setattr(upf_benchmark, "evaluate_bag", evaluate_bag)
    return seen


def test_upf_benchmark_simulates_the_complex_scenario_and_tracks_from_oracle_rois(upf_stand_ins):
    result = upf_benchmark.run(frames=6, particles=40, variant="C3N1", seed=4)
    scenario, name, kwargs = upf_stand_ins["simulate"]
    assert scenario == "scenario complex" and name == "complex" and kwargs["frames"] == 6
    bag, variants, kwargs = upf_stand_ins["evaluate"]
    assert Path(bag).name == "complex" and variants == ["C3N1"]
    assert kwargs["particles"] == 40 and kwargs["roi_source"] == "oracle" and kwargs["frames"] == 6
    assert kwargs["seed"] == 4
    assert result == {"variant": "C3N1", "particles": 40, "frames": 5, "stage_ms": {"prepare": 1.0},
                      "ms_per_frame": 9.0}


def test_upf_benchmark_of_a_given_bag_simulates_nothing(upf_stand_ins, tmp_path):
    upf_benchmark.run(bag=tmp_path / "mine", frames=3)
    assert "simulate" not in upf_stand_ins
    assert upf_stand_ins["evaluate"][0] == tmp_path / "mine"


def test_upf_benchmark_text_lists_every_stage_then_the_total():
    stages = SHARED_STAGES + STAGES
    text = upf_benchmark.format_result({"variant": "C4N2", "particles": 100, "frames": 30, "ms_per_frame": 99.5,
                          "stage_ms": {s: float(i) for i, s in enumerate(stages)}})
    lines = text.splitlines()
    assert lines[0] == "Tracker C4N2, M=100, 30 frames (ms per frame):"
    assert [line.split()[0] for line in lines[1:-1]] == list(stages)
    assert [float(line.split()[1]) for line in lines[1:-1]] == list(range(len(stages)))
    assert lines[-1].split() == ["boosting+step", "99.5"]
