"""End to end: a short simulated landing through the whole node graph, each node its own process
over DDS, paced on the tracker's status; the result must be what ``uav-landing evaluate`` gives."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from uav_landing_vision.graph import GRAPH_NODES, ready_topics_parameter
from uav_landing_vision.sim import read_pose_csv, read_poses
from uav_landing_vision.sim.config import load_scenario
from uav_landing_vision.sim.simulate import simulate
from uav_landing_vision.tracking.evaluate import evaluate_bag
from uav_landing_vision.tracking.upf import load_tracker_config

REPO = Path(__file__).parents[2]
FRAMES = 60
# Measured with the shipped models (`uav-landing evaluate` on this landing): C4N2 medians 0.62 m
# and 3.00°, no frame lost. So close in (30 -> 18 m) boosting alone does as well (C1N0 0.55 m,
# 2.63°; C3N0, C4N0, C2N0 0.40-0.57 m, 2.3-3.0°), so these bounds catch a pipeline that lost or
# misplaces the UAV (the previous detector, before boosting grew its ROIs: 4.70 m, 12.1°), not a
# weaker filter: that the graph runs the tracker is the equality with the core below.
TRANSLATION_MEDIAN_M = 1.0
ROTATION_MEDIAN_DEG = 5.0
GRAPH_TIMEOUT_S = 420.0
# The shipped normal scenario, the approach starting 30-32 m out (the first 60 frames reach ~18 m).
SCENARIO = """
seed: 3
approach:
  start_range_m: [30.0, 32.0]
background:
  kind: normal
"""


@pytest.fixture(scope="module")
def landing(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("landing")
    scenario = folder / "short_landing.yaml"
    scenario.write_text(SCENARIO)
    bag = folder / "bag"
    simulate(load_scenario(scenario), bag, frames=FRAMES)
    return bag


@pytest.fixture(scope="module")
def graph_run(landing, tmp_path_factory, ros_domain_id):
    """``uav-landing graph`` on the bag; (exit code, its output, the evaluator's report folder)."""
    out = tmp_path_factory.mktemp("graph")
    report = out / "report"
    tracker = load_tracker_config()
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO / "src" / "uav_landing_vision"), os.environ.get("PYTHONPATH", "")]))
    cmd = [sys.executable, "-m", "uav_landing_vision.cli", "graph", "--bag", str(landing), "--config", str(REPO / "config"),
           "--domain-id", str(ros_domain_id),
           "--param", "bag_player:ack_topic=uav/tracker_status",
           "--param", "bag_player:ack_type=uav_landing_msgs/msg/TrackerStatus",
           # Every link discovered first (the models load for seconds), then more than the
           # shipped 3 s for the processes' DDS matching: a loaded CI machine.
           "--param", f"bag_player:ready_topics={ready_topics_parameter()}",
           "--param", "bag_player:ready_settle_s=6.0",
           # The core never tracks a frame by prediction while its box is coming; on a loaded machine
           # the shipped 1 s can pass before the hypotheses arrive. Still below the 10 s ack timeout.
           "--param", "tracker:node.hypotheses_timeout_s=8.0",
           "--param", f"evaluator:out_dir={report}",
           "--param", f"evaluator:variant={tracker.variant}N{tracker.iterations}"]
    log = out / "graph.log"
    with log.open("w") as stream:
        proc = subprocess.Popen(cmd, env=env, cwd=REPO, stdout=stream, stderr=subprocess.STDOUT)
        try:
            code = proc.wait(timeout=GRAPH_TIMEOUT_S)
        finally:
            if proc.poll() is None:
                proc.kill()
    return code, log.read_text(), report


@pytest.fixture(scope="module")
def core_run(landing):
    """``uav-landing evaluate`` on the same bag, with the shipped tracker configuration."""
    tracker = load_tracker_config()
    return evaluate_bag(landing, [f"{tracker.variant}N{tracker.iterations}"], particles=tracker.particles,
                        metric=tracker.metric, roi_source="detector", seed=tracker.seed, base=tracker, progress=False)


def test_every_frame_goes_through_every_node(graph_run):
    code, output, report = graph_run
    assert code == 0, output[-5000:]
    assert all(f"started {name}" in output for name in GRAPH_NODES)
    assert f"acknowledged {FRAMES}, ack timeouts 0, dropped 0" in output, output[-5000:]
    assert "tracked by prediction" not in output, output[-5000:]  # the core never does
    assert "all nodes stopped cleanly" in output
    summary = json.loads((report / "summary.json").read_text())
    assert summary["frames"] == FRAMES


def test_graph_poses_equal_the_core_evaluation(graph_run, core_run, landing):
    code, output, report = graph_run
    assert code == 0, output[-5000:]
    graph = read_pose_csv(report / "estimates.csv")
    truth = read_poses(landing)
    (name,) = core_run.estimates
    core_t, core_q = core_run.estimates[name]
    posed = np.isfinite(core_t[:, 0])
    assert posed.mean() >= 0.95, f"the core posed {posed.sum()} of {FRAMES} frames"
    # Same frames posed, same poses (the quaternion sign is not canonical on the wire).
    np.testing.assert_array_equal(graph.stamps_ns, truth.stamps_ns[posed])
    np.testing.assert_allclose(graph.trans, core_t[posed], rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.abs(np.sum(graph.quat * core_q[posed], axis=1)), 1.0, rtol=0, atol=1e-9)


def test_the_landing_has_frames_for_the_track_box(landing):
    """The equality above covers the track box: the detector finds nothing in some frames (15 of
    60 when measured), which both the graph and the core then boost from the last pose's box."""
    import cv2

    from uav_landing_vision.detection.track_box import TrackBoxConfig
    from uav_landing_vision.sim import iter_frames, read_camera
    from uav_landing_vision.tracking.evaluate import detector_rois, shipped_config

    assert shipped_config(TrackBoxConfig, "detector", "track_box").enabled
    raw = read_camera(landing)
    maps = raw.undistortion_maps()
    rois = detector_rois(raw.rectified())
    missed = [k for k, (_, frame) in enumerate(iter_frames(landing))
              if rois(cv2.remap(frame, maps[0], maps[1], cv2.INTER_LINEAR), k) is None]
    assert 5 <= len(missed) <= FRAMES - 30, missed


def test_graph_accuracy_is_the_trackers(graph_run, core_run):
    code, output, report = graph_run
    assert code == 0, output[-5000:]
    (name,) = core_run.errors
    errors = core_run.errors[name]
    variant = json.loads((report / "summary.json").read_text())["variants"][name]
    assert variant["lost_frames_pct"] <= 5.0
    assert variant["translation_m"]["median"] == pytest.approx(np.nanmedian(errors["euclidean"]), abs=1e-6)
    assert variant["rotation_deg"]["median"] == pytest.approx(np.nanmedian(errors["geodesic"]), abs=1e-6)
    assert variant["translation_m"]["median"] < TRANSLATION_MEDIAN_M
    assert variant["rotation_deg"]["median"] < ROTATION_MEDIAN_DEG
