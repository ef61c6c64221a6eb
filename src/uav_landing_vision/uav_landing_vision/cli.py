"""The ``uav-landing`` command: one subcommand per offline job of the project.

Each subsystem registers its subcommands in its own ``commands.py`` (``register(subparsers)``),
importing heavy modules only inside the handlers so that ``uav-landing --help`` stays fast.
"""

import argparse
import importlib
import os
import sys
from pathlib import Path

_COMMAND_MODULES = [
    "uav_landing_vision.demo",
    "uav_landing_vision.bench",
    "uav_landing_vision.graph",
    "uav_landing_vision.render.commands",
    "uav_landing_vision.boosting.commands",
    "uav_landing_vision.detection.commands",
    "uav_landing_vision.sim.commands",
    "uav_landing_vision.evaluation.commands",
    "uav_landing_vision.tracking.commands",
]


def check_output(option: str, path, folder: bool = False, others=()) -> None:
    """ValueError unless ``path`` (a file, or with ``folder`` a folder) can be written, and is none
    of ``others``, ``(option, path or None)`` of the command's inputs and other outputs, which it
    would overwrite: checked before a long run rather than after it, when its results would be lost."""
    path = Path(path).absolute()
    for other, given in others:
        if given is not None and Path(given).resolve() == path.resolve():
            raise ValueError(f"{option} {path} is the {other} file: it would be overwritten")
    if path.exists():
        if path.is_dir() != folder:
            raise ValueError(f"{option} {path} is {'not ' if folder else ''}a folder")
        if not os.access(path, os.W_OK | (os.X_OK if folder else 0)):
            raise ValueError(f"{option} {path} is not writable")
        return
    above = next(p for p in path.parents if p.exists())
    if not (above.is_dir() and os.access(above, os.W_OK | os.X_OK)):
        raise ValueError(f"{option} {path}: {above} is not a writable folder")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="uav-landing", description="UAV landing vision station tools.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in _COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (ValueError, OSError) as exc:  # a bad input or file that a command did not report itself
        print(f"uav-landing {args.command}: {exc}", file=sys.stderr)
        return 1  # as a command's own SystemExit(message); argparse's usage errors exit 2
    except MemoryError as exc:  # e.g. a --count or --samples far beyond this machine
        print(f"uav-landing {args.command}: not enough memory for these settings ({exc})", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
