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
