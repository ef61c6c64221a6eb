"""The ``uav-landing`` command: every registered subcommand parses; the demo refuses bad arguments;
its exit statuses; where the shipped configuration and models are found (the source checkout
first, then the first ament prefix that has them)."""

import importlib
import os
from pathlib import Path

import numpy as np
import pytest

from uav_landing_vision import resources
from uav_landing_vision.cli import build_parser, main
from uav_landing_vision.sim import Poses, write_pose_csv


def test_every_subcommand_has_help(capsys):
    parser = build_parser()
    commands = parser._subparsers._group_actions[0].choices
    assert {"demo", "bench"} <= set(commands)
    for name in commands:
        with pytest.raises(SystemExit) as exc:
            parser.parse_args([name, "--help"])
        assert exc.value.code == 0
    capsys.readouterr()


def test_demo_rejects_bad_frame_count():
    with pytest.raises(SystemExit, match="--frames must be at least 1"):
        main(["demo", "--frames", "0"])
    with pytest.raises(SystemExit, match="--strip must be at least 1, got 0"):  # one frame, silently, before
        main(["demo", "--strip", "0"])


def test_demo_replay_waits_for_every_link_of_the_graph(tmp_path):
    """The demo's player override lists the pipeline's topics as a YAML list that ROS parses
    into the string array ``ready_topics`` expects."""
    import yaml

    from uav_landing_vision.demo import graph_overrides
    from uav_landing_vision.graph import PIPELINE_TOPICS

    overrides = graph_overrides(tmp_path / "bag", tmp_path / "report", "bag")
    player = dict(overrides["bag_player"])
    assert yaml.safe_load(player["ready_topics"]) == list(PIPELINE_TOPICS)
    assert {"/uav/pose_hypotheses", "/uav/tracker_status"} <= set(PIPELINE_TOPICS)
    # Every other node on the bag's time, which the player publishes on /clock.
    assert player["clock"] == "true" and "use_sim_time" not in player
    assert all(dict(overrides[name]).get("use_sim_time") == "true" for name in overrides if name != "bag_player")


def test_graph_replaying_a_bag_through_the_whole_graph_waits_for_every_link(tmp_path):
    import argparse

    import yaml

    from uav_landing_vision.graph import PIPELINE_TOPICS, _plan
    from uav_landing_vision.resources import config_path

    bag = _bag_of(tmp_path / "bag", ["/camera/image_raw", "/camera/camera_info", "/uav/ground_truth"])

    def plan(nodes=None, *params):
        args = argparse.Namespace(nodes=nodes, bag=bag, param=list(params), drain=2.0, stop_timeout=10.0,
                                  config=config_path("tracker.yaml").parent)
        return dict(_plan(args)[1]["bag_player"])

    assert yaml.safe_load(plan()["ready_topics"]) == list(PIPELINE_TOPICS)  # the ground truth's link among them
    assert "ready_topics" not in plan("undistort,bag_player")  # a part of the graph: the file's setting
    # Paced on the tracker's status where there is a tracker (every frame tracked), else the file's ack.
    assert (plan()["ack_topic"], plan("undistort,detector,pose_boosting,tracker,bag_player")["ack_topic"]) == (
        "uav/tracker_status", "uav/tracker_status")
    assert "ack_topic" not in plan("undistort,bag_player")
    assert plan("undistort,tracker,bag_player", "bag_player:ack_topic=/mine")["ack_topic"] == "/mine"  # the user's wins
    own = _plan(argparse.Namespace(nodes=None, bag=bag, param=["bag_player:ready_topics=[/camera/image_raw]"],
                                   drain=2.0, stop_timeout=10.0, config=config_path("tracker.yaml").parent))[1]
    assert [v for k, v in own["bag_player"] if k == "ready_topics"] == ["[/camera/image_raw]"]  # the user's own only


@pytest.mark.parametrize("nodes, drain, stop_timeout, message", [
    ("undistort,undistort,evaluator", 2.0, 10.0, r"node\(s\) \['undistort'\] named more than once"),
    (None, 2.0, float("nan"), "both finite"),  # Popen.wait(timeout=nan) never returned: the graph hung
    (None, float("inf"), 10.0, "both finite"),
    ("", 2.0, 10.0, "no node to run"),  # ran every node, while ",," was refused
])
def test_graph_refuses_a_repeated_node_and_timeouts_that_are_not_finite(nodes, drain, stop_timeout, message):
    """A repeated name started two processes, the second took the first's place in the graph's
    table, and the first ran on after "all nodes stopped cleanly"."""
    import argparse

    from uav_landing_vision.graph import _plan
    from uav_landing_vision.resources import config_path

    args = argparse.Namespace(nodes=nodes, bag=None, param=[], drain=drain, stop_timeout=stop_timeout,
                              config=config_path("tracker.yaml").parent)
    with pytest.raises(ValueError, match=message):
        _plan(args)


@pytest.mark.parametrize("command", ["graph", "demo"])
@pytest.mark.parametrize("value", ["-1", "233", "x"])
def test_a_domain_id_rcl_would_not_keep_apart_is_refused(command, value, capsys):
    """rcl takes -1 as its default domain, 0: a graph meant for a domain of its own would have
    joined every default graph on the network."""
    from uav_landing_vision.cli import main

    with pytest.raises(SystemExit) as stop:
        main([command, "--domain-id", value])
    assert stop.value.code == 2 and "--domain-id" in capsys.readouterr().err


def _bag_of(path, topics):
    """A bag that records ``topics`` (one message each; only their names matter here)."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    types = {"/camera/image_raw": "sensor_msgs/msg/Image", "/camera/camera_info": "sensor_msgs/msg/CameraInfo",
             "/uav/ground_truth": "geometry_msgs/msg/PoseStamped"}
    with Writer(path, version=9) as writer:
        for topic in topics:
            writer.write(writer.add_connection(topic, types[topic], typestore=typestore), 1, b"\x00\x01\x00\x00")
    return path


def test_graph_replay_of_a_recording_without_ground_truth_waits_only_for_links_that_can_come_up(tmp_path):
    """A recorded landing has no /uav/ground_truth: nothing would ever publish it, and a paced
    player waiting for its publisher gave up after ready_timeout_s (exit 1, the graph failed)."""
    import argparse

    import yaml

    from uav_landing_vision.graph import GRAPH_NODES, PIPELINE_TOPICS, _plan
    from uav_landing_vision.resources import config_path

    def plan(bag):
        args = argparse.Namespace(nodes=None, bag=bag, param=[], drain=2.0, stop_timeout=10.0,
                                  config=config_path("tracker.yaml").parent)
        return {name: dict(pairs) for name, pairs in _plan(args)[1].items()}

    recorded = plan(_bag_of(tmp_path / "recorded", ["/camera/image_raw", "/camera/camera_info"]))
    assert yaml.safe_load(recorded["bag_player"]["ready_topics"]) == [t for t in PIPELINE_TOPICS if t != "/uav/ground_truth"]
    simulated = plan(_bag_of(tmp_path / "simulated", ["/camera/image_raw", "/camera/camera_info", "/uav/ground_truth"]))
    assert yaml.safe_load(simulated["bag_player"]["ready_topics"]) == list(PIPELINE_TOPICS)
    # A replay runs every node on the bag's time (the player's /clock), as ros2 bag play --clock.
    assert simulated["bag_player"]["clock"] == "true" and "use_sim_time" not in simulated["bag_player"]
    assert all(simulated[name]["use_sim_time"] == "true" for name in GRAPH_NODES if name != "bag_player")


def test_an_interrupted_demo_fails_and_shows_no_earlier_report(tmp_path, monkeypatch, capsys):
    import signal

    from uav_landing_vision import demo, graph

    class Interrupted:
        def __init__(self, *args, **kwargs):
            self.stopped_by_signal = None

        def run(self):
            self.stopped_by_signal = signal.SIGINT
            return 0  # the nodes stopped cleanly: a Ctrl-C is a normal way to stop a live graph

    old_report = tmp_path / "evaluation" / "tables.txt"
    old_report.parent.mkdir()
    old_report.write_text("an earlier run's tables")
    monkeypatch.setattr(demo, "simulated_bag", lambda *args: tmp_path / "bags" / "bag")
    monkeypatch.setattr(graph, "Graph", Interrupted)
    assert main(["demo", "--out", str(tmp_path)]) == 128 + signal.SIGINT
    assert not old_report.exists()
    assert "interrupted (SIGINT); no report" in capsys.readouterr().err


def test_make_detection_data_passes_the_landing_options_and_refuses_bad_ones(tmp_path, capsys):
    import json

    out = tmp_path / "data"
    assert main(["make-detection-data", "--out", str(out), "--count", "2", "--seed", "1", "--families", "normal",
                 "--banks-per-family", "1", "--landing-fraction", "1", "--landing-negative-fraction", "1",
                 "--landing-sun-spread", "30"]) == 0
    summary = json.loads((out / "dataset.json").read_text())
    assert summary["positives"] == 0  # every image a landing frame without the UAV
    assert summary["config"]["landing_sun_spread_deg"] == 30.0 and summary["config"]["banks_per_family"] == 1
    with pytest.raises(SystemExit, match="landing_negative_fraction"):
        main(["make-detection-data", "--out", str(tmp_path / "bad"), "--landing-negative-fraction", "2"])
    capsys.readouterr()


def test_a_closed_output_does_not_stop_the_graphs_shutdown(tmp_path, monkeypatch):
    import io

    from uav_landing_vision.graph import Graph

    class Closed(io.StringIO):
        def write(self, text):
            raise BrokenPipeError("the reader has gone")

    monkeypatch.setattr("sys.stdout", Closed())
    Graph([], tmp_path, {}, {}, stop_timeout=1.0)._say("stopping")  # raised, and aborted the escalation


def test_score_says_how_many_frames_its_tables_cover(tmp_path, capsys):
    """The statistics leave the lost frames out; the printed tables say how many there were,
    with or without a report folder."""
    import json

    (tmp_path / "truth.csv").write_text("stamp_ns,x,y,z,qx,qy,qz,qw\n10,0,0,5,0,0,0,1\n20,0,0,6,0,0,0,1\n"
                                        "30,0,0,7,0,0,0,1\n40,0,0,8,0,0,0,1\n")
    (tmp_path / "est.csv").write_text("stamp_ns,x,y,z,qx,qy,qz,qw\n10,0,0,5.5,0,0,0,1\n30,0,0,7,0,0,0,1\n"
                                      "40,0,0,8,nan,nan,nan,nan\n")
    argv = ["score", "--truth", str(tmp_path / "truth.csv"), "--estimate", str(tmp_path / "est.csv"), "--name", "C4N2"]
    assert main([*argv, "--json", str(tmp_path / "s.json")]) == 0
    assert "C4N2: statistics over 2 of 4 frames (50.0 % lost)" in capsys.readouterr().out
    assert json.loads((tmp_path / "s.json").read_text())["variants"]["C4N2"]["lost_frames_pct"] == 50.0
    assert main([*argv, "--json", str(tmp_path / "r.json"), "--report-dir", str(tmp_path / "report")]) == 0
    assert "C4N2: statistics over 2 of 4 frames (50.0 % lost)" in capsys.readouterr().out


def test_score_takes_the_estimates_of_a_run_that_posed_no_frame(tmp_path, capsys):
    """The evaluator writes estimates.csv "for uav-landing score", a header alone when every frame
    was lost; score refused it (no poses) where the evaluator's own summary said 100 % lost."""
    import json

    (tmp_path / "truth.csv").write_text("stamp_ns,x,y,z,qx,qy,qz,qw\n10,0,0,5,0,0,0,1\n20,0,0,6,0,0,0,1\n")
    write_pose_csv(tmp_path / "est.csv", Poses(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 4))))
    argv = ["score", "--truth", str(tmp_path / "truth.csv"), "--estimate", str(tmp_path / "est.csv"), "--name", "C4N2"]
    assert main([*argv, "--json", str(tmp_path / "s.json")]) == 0
    assert "C4N2: statistics over 0 of 2 frames (100.0 % lost)" in capsys.readouterr().out
    assert json.loads((tmp_path / "s.json").read_text())["variants"]["C4N2"]["lost_frames_pct"] == 100.0


def test_no_subcommand_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as stop:
        main([])
    assert stop.value.code == 2 and "COMMAND" in capsys.readouterr().err


def test_ctrl_c_in_a_command_exits_130_with_one_line(tmp_path, monkeypatch, capsys):
    score = importlib.import_module("uav_landing_vision.evaluation.score")
    for name in ("truth", "est.csv"):
        (tmp_path / name).touch()

    def interrupted(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(score, "score_files", interrupted)
    assert main(["score", "--truth", str(tmp_path / "truth"), "--estimate", str(tmp_path / "est.csv"),
                 "--json", str(tmp_path / "s.json")]) == 130
    assert capsys.readouterr().err == "interrupted\n"
    assert not (tmp_path / "s.json").exists()


def _share(prefix: Path, kind: str, name: str) -> Path:
    path = prefix / "share" / resources.PACKAGE / kind / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("shared")
    return path


def test_a_source_checkout_reads_its_own_config_and_models(monkeypatch):
    monkeypatch.setenv("AMENT_PREFIX_PATH", "")
    for path, kind in ((resources.config_path("camera.yaml"), "config"), (resources.config_path("scenarios"), "config"),
                       (resources.model_path("pose_database.npz"), "models"), (resources.model_path("detector.onnx"), "models")):
        assert path.exists() and path.parent.name == kind


def test_the_checkouts_files_win_over_an_installed_copy(tmp_path, monkeypatch):
    _share(tmp_path / "prefix", "config", "camera.yaml")
    _share(tmp_path / "prefix", "models", "pose_database.npz")
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path / "prefix"))
    assert not resources.config_path("camera.yaml").is_relative_to(tmp_path)
    assert not resources.model_path("pose_database.npz").is_relative_to(tmp_path)


def test_files_only_installed_come_from_the_first_prefix_that_has_the_package(tmp_path, monkeypatch):
    first = _share(tmp_path / "first", "config", "only_installed.yaml")
    _share(tmp_path / "second", "config", "only_installed.yaml")
    model = _share(tmp_path / "second", "models", "only_installed.npz")
    (tmp_path / "none").mkdir()
    monkeypatch.setenv("AMENT_PREFIX_PATH", os.pathsep.join(str(tmp_path / p) for p in ("none", "first", "second")))
    assert resources.config_path("only_installed.yaml") == first
    monkeypatch.setenv("AMENT_PREFIX_PATH", os.pathsep.join(str(tmp_path / p) for p in ("none", "second")))
    assert resources.model_path("only_installed.npz") == model


def test_an_empty_ament_prefix_is_not_the_working_directory(tmp_path, monkeypatch):
    _share(tmp_path / "cwd", "config", "only_installed.yaml")
    installed = _share(tmp_path / "prefix", "config", "only_installed.yaml")
    monkeypatch.chdir(tmp_path / "cwd")
    monkeypatch.setenv("AMENT_PREFIX_PATH", os.pathsep + str(tmp_path / "prefix"))
    assert resources.config_path("only_installed.yaml") == installed


def test_model_file_takes_paths_as_they_are_and_names_from_the_models_folder(tmp_path, monkeypatch):
    missing = tmp_path / "nosuch.onnx"
    assert resources.model_file(missing) == missing  # its reader reports it missing, by its path
    assert resources.model_file(str(missing)) == missing
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.onnx").write_bytes(b"")
    assert resources.model_file("mine.onnx") == Path("mine.onnx")
    assert resources.model_file("verifier.onnx") == resources.model_path("verifier.onnx")
    with pytest.raises(FileNotFoundError, match="models file 'other.onnx' not found"):
        resources.model_file("other.onnx")
    (tmp_path / "own.yaml").write_text("")
    assert resources.config_file("own.yaml") == Path("own.yaml")
    assert resources.config_file("camera.yaml") == resources.config_path("camera.yaml")
