"""The ``uav-landing`` command: every registered subcommand parses; the demo refuses bad arguments."""

import pytest

from uav_landing_vision.cli import build_parser, main


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
    with pytest.raises(SystemExit):
        main(["demo", "--frames", "0"])


def test_demo_replay_waits_for_every_link_of_the_graph(tmp_path):
    """The demo's player override lists the pipeline's topics as a YAML list that ROS parses
    into the string array ``ready_topics`` expects."""
    import yaml

    from uav_landing_vision.demo import graph_overrides
    from uav_landing_vision.graph import PIPELINE_TOPICS

    player = dict(graph_overrides(tmp_path / "bag", tmp_path / "report", "bag")["bag_player"])
    assert yaml.safe_load(player["ready_topics"]) == list(PIPELINE_TOPICS)
    assert {"/uav/pose_hypotheses", "/uav/tracker_status"} <= set(PIPELINE_TOPICS)


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
