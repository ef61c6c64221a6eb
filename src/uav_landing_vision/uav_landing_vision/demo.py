"""``uav-landing demo``: what ``make demo`` runs.

Until the end-to-end demo through the node graph exists (it needs the trained detector), the
demo renders a short fly-by of the UAV model to PNG files.
"""

from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("demo", help="render a short fly-by of the UAV model to PNG files")
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder (default: out/demo)")
    p.add_argument("--frames", type=int, default=24, help="number of frames (default: 24)")
    p.set_defaults(func=_run)


def _run(args) -> int:
    from .render.flyby import render_flyby

    if args.frames < 1:
        raise SystemExit("--frames must be at least 1")
    paths = render_flyby(args.out, frames=args.frames)
    print(f"wrote {len(paths)} fly-by frames to {args.out.resolve()}/ ({paths[0].name} … {paths[-1].name})")
    return 0
