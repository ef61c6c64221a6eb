"""The ``uav-landing`` command: one subcommand per offline job of the project."""

import argparse
import sys


def _build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="uav-landing", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    return parser


def main(argv=None) -> int:
    parser = _build_parser()
    args = parser.parse_args(argv)
    return int(args.run(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
