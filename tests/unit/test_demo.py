"""``uav-landing demo``: its simulated landing (kept for later runs, simulated again when its scenario
changed), its request checks, the graph it runs and what it makes of the graph's end, and its overlay
strip's frames, truths and crops."""

import importlib
import signal
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from uav_landing_vision import demo
from uav_landing_vision.camera import CameraModel
from uav_landing_vision.cli import main
from uav_landing_vision.sim.simulate import SimulationResult

simulate_module = importlib.import_module("uav_landing_vision.sim.simulate")  # the package exports simulate()


def test_the_kept_landing_is_reused_only_while_its_scenario_is_unchanged(tmp_path, monkeypatch):
    runs = []

    def fake_simulate(scenario, bag, *, seed=None, frames=None):
        assert not bag.exists()  # simulate() writes a new folder only
        bag.mkdir(parents=True)
        (bag / "metadata.yaml").write_text("")
        runs.append((scenario.approach.start_range_m, seed, frames))
        return SimulationResult(frames=frames, seconds=0.0, bag_dir=bag)

    monkeypatch.setattr(simulate_module, "simulate", fake_simulate)
    scenario = tmp_path / "short.yaml"
    scenario.write_text("seed: 3\napproach:\n  start_range_m: [30.0, 32.0]\n")
    folder = tmp_path / "bags"
    bag = demo.simulated_bag(folder, str(scenario), None, 5)
    assert bag == folder / "short_seed3_5frames" and runs == [((30.0, 32.0), 3, 5)]
    assert demo.simulated_bag(folder, str(scenario), None, 5) == bag and len(runs) == 1  # kept
    scenario.write_text("seed: 3\napproach:\n  start_range_m: [40.0, 42.0]\n")  # edited: same name and seed
    assert demo.simulated_bag(folder, str(scenario), None, 5) == bag
    assert runs == [((30.0, 32.0), 3, 5), ((40.0, 42.0), 3, 5)]
    assert demo.simulated_bag(folder, str(scenario), None, 5) == bag and len(runs) == 2


CAMERA = CameraModel(640, 480, [[500.0, 0, 320.0], [0, 520.0, 240.0], [0, 0, 1]])


class FakeGraph:
    """Stands in for the node graph: returns ``code`` and records how it was made."""

    code, made = 0, []

    def __init__(self, names, config_dir, overrides, env, stop_timeout, drain_s=2.0, remaps=None):
        FakeGraph.made.append(SimpleNamespace(names=names, overrides=overrides, env=env))
        self.stopped_by_signal = None

    def run(self):
        return FakeGraph.code


@pytest.fixture
def fake_graph(monkeypatch, tmp_path):
    from uav_landing_vision import graph

    FakeGraph.code, FakeGraph.made = 0, []
    seeds = []
    monkeypatch.setattr(graph, "Graph", FakeGraph)
    monkeypatch.setattr(demo, "simulated_bag", lambda folder, scenario, seed, frames: seeds.append(seed) or folder / "bag")
    return seeds


def test_seed_zero_is_a_valid_scenario_seed_and_a_failed_graph_fails_the_demo(fake_graph, tmp_path):
    FakeGraph.code = 1
    with pytest.raises(SystemExit, match=r"the graph failed \(exit 1\)"):
        main(["demo", "--out", str(tmp_path), "--seed", "0", "--domain-id", "95"])
    assert fake_graph == [0] and FakeGraph.made[0].env["ROS_DOMAIN_ID"] == "95"
    with pytest.raises(SystemExit, match="--seed must be non-negative"):
        main(["demo", "--out", str(tmp_path), "--seed", "-1"])


def test_an_interrupted_demo_exits_with_the_shells_code_of_its_signal(fake_graph, tmp_path, monkeypatch):
    class Terminated(FakeGraph):
        def run(self):
            self.stopped_by_signal = signal.SIGTERM
            return 0

    from uav_landing_vision import graph

    monkeypatch.setattr(graph, "Graph", Terminated)
    assert main(["demo", "--out", str(tmp_path)]) == 128 + signal.SIGTERM


def test_the_demo_graph_is_paced_and_the_evaluator_writes_where_the_demo_reads(tmp_path):
    import yaml

    report = tmp_path / "out" / "evaluation"
    overrides = demo.graph_overrides(tmp_path / "bags" / "normal_seed1", report, sequence="normal_seed1")
    player = dict(overrides["bag_player"])
    assert player["mode"] == "paced" and player["ack_topic"] == "uav/tracker_status"
    evaluator = dict(overrides["evaluator"])
    assert yaml.safe_load(evaluator["out_dir"]) == str(report)
    assert yaml.safe_load(evaluator["sequence"]) == "normal_seed1"


@pytest.mark.parametrize("trans", [(0.4, -0.3, 10.0), (-2.0, 1.5, 6.0), (3.0, 2.5, 5.0), (0.0, 0.0, 20.0)])
def test_the_crop_is_centred_on_the_projected_point_and_kept_in_the_frame(trans):
    ys, xs = np.mgrid[0:480, 0:640]  # every pixel told apart by its colour
    frame = np.stack([xs % 256, ys % 256, xs // 256 + 4 * (ys // 256)], axis=2).astype(np.uint8)
    size = 160
    tile = demo._crop_about(frame.copy(), CAMERA, np.array(trans), "", size=size)
    (u, v), = cv2.projectPoints(np.array([trans]), np.zeros(3), np.zeros(3), CAMERA.K, None)[0].reshape(-1, 2)[:1]
    x0 = int(np.clip(u - size / 2, 0, 640 - size))
    y0 = int(np.clip(v - size / 2, 0, 480 - size))
    assert tile.shape == (size, size, 3)
    expected = frame[y0:y0 + size, x0:x0 + size]
    assert np.array_equal(tile[40:], expected[40:])  # below the label


def test_the_overlay_strip_spreads_its_frames_over_the_bag_and_draws_each_frames_own_truth(monkeypatch, tmp_path):
    import uav_landing_vision.camera as camera_module
    import uav_landing_vision.render as render_module
    import uav_landing_vision.sim as sim_module

    stamps = [100, 200, 300, 400, 500]
    truth = SimpleNamespace(stamps_ns=np.array(stamps), trans=np.array([[0.0, 0.0, 10.0 + k] for k in range(5)]),
                            quat=np.tile([0.0, 0.0, 0.0, 1.0], (5, 1)))
    estimates = SimpleNamespace(stamps_ns=np.array([300]), trans=np.array([[0.1, 0.0, 12.0]]), quat=np.array([[0.0, 0.0, 0.0, 1.0]]))
    drawn = []

    class FakeRenderer:
        def __init__(self, camera, mesh):
            pass

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def silhouette_full(self, quat, trans):
            drawn.append(float(trans[2]))
            return np.zeros((480, 640), bool)

    written = []
    monkeypatch.setattr(render_module, "Renderer", FakeRenderer)
    monkeypatch.setattr(sim_module, "read_camera", lambda bag: CAMERA)
    monkeypatch.setattr(sim_module, "read_poses", lambda bag: truth)
    monkeypatch.setattr(sim_module, "iter_frames", lambda bag: ((s, np.zeros((480, 640, 3), np.uint8)) for s in stamps))
    monkeypatch.setattr(camera_module, "write_image", lambda path, image: written.append(image.shape))
    demo.overlay_strip(tmp_path / "bag", estimates, tmp_path / "strip.png", 3)
    # frames 0, 2 and 4: each its truth (10, 12, 14 m); frame 2 also the estimate (12 m)
    assert drawn == [10.0, 12.0, 12.0, 14.0]
    assert written == [(320, 3 * 320, 3)]
