"""``uav-landing evaluate``: thesis-format tracking results of CxNy variants on a simulated bag (§6.7.1).

It runs the renderer's self-test first, as the tracker node does at start-up, and stops on a
machine whose silhouettes are unlike the reference's (``render.selftest``)."""

from pathlib import Path

DEFAULT_VARIANTS = "C1N0,C3N0,C4N0,C4N2,C5N5"


def register(sub) -> None:
    p = sub.add_parser("evaluate", help="run tracker variants (CxNy) over a simulated bag; thesis-format tables")
    p.add_argument("--bag", type=Path, required=True, help="simulated rosbag2 folder (uav-landing simulate)")
    p.add_argument("--variants", default=DEFAULT_VARIANTS,
                   help="comma-separated CxNy: combination 1-5 of Table 6.11, N PFO iterations "
                        f"(default: {DEFAULT_VARIANTS})")
    p.add_argument("--particles", type=int, help="particles M (default: the tracker parameter file's)")
    p.add_argument("--metric", choices=("colour", "contour", "distance_transform"),
                   help="likelihood metric (default: the tracker parameter file's)")
    p.add_argument("--roi-source", choices=("detector", "oracle"), default="detector",
                   help="ROIs from the trained detector (default) or from the ground truth (oracle, labelled)")
    p.add_argument("--start", type=int, default=0, help="skip the first S frames (default: 0)")
    p.add_argument("--frames", type=int, help="only N frames (from --start)")
    p.add_argument("--stride", type=int, default=1,
                   help="track only every N-th frame, as a tracker that takes N frame intervals per step "
                        "does live (default: 1, every frame, as the thesis)")
    p.add_argument("--seed", type=int, default=0, help="tracker seed (default: 0)")
    p.add_argument("--config", type=Path, help="tracker parameter file (default: the shipped config/tracker.yaml)")
    p.add_argument("--json", type=Path, help="write the JSON summary here")
    p.add_argument("--plots", type=Path, help="write tables (txt, CSV) and error plots into this folder")
    p.add_argument("--remap", action="append", default=[], metavar="FROM:=TO",
                   help="a recording of other topic names (repeatable), as uav-landing graph --remap: e.g. "
                        "/deck_cam/image_raw:=/camera/image_raw")
    p.set_defaults(func=_run)


def _run(args) -> int:
    from ..cli import check_output
    from ..config import ConfigError
    from ..evaluation import save_summary, write_report
    from ..graph import parse_remaps
    from ..render.selftest import check_renderer
    from .evaluate import EvaluationError, evaluate_bag, format_results, parse_variants, sequence_label, summary
    from .upf import load_tracker_config

    try:
        variants = parse_variants(args.variants)
        if args.frames is not None and args.frames < 1:
            raise ValueError("--frames must be at least 1")
        if args.start < 0:
            raise ValueError("--start must be non-negative")
        if args.stride < 1:
            raise ValueError(f"--stride must be at least 1, got {args.stride}")
        if args.seed < 0:
            raise ValueError(f"--seed must be non-negative, got {args.seed}")
        if args.json:
            check_output("--json", args.json, others=(("--config", args.config),))
        if args.plots:
            check_output("--plots", args.plots, folder=True)
        remaps = parse_remaps(args.remap)
        base = load_tracker_config(args.config)
        # As the tracker node does: figures from silhouettes unlike the reference's are not the tracker's
        # (RendererSelfTestError is an OSError: the CLI reports it).
        print(f"renderer self-test {check_renderer().summary}")
        result = evaluate_bag(args.bag, variants, particles=args.particles, metric=args.metric,
                              roi_source=args.roi_source, frames=args.frames, start=args.start, seed=args.seed, base=base,
                              stride=args.stride, remaps=remaps)
    except (ValueError, ConfigError, EvaluationError, FileNotFoundError) as exc:
        raise SystemExit(f"uav-landing evaluate: {exc}") from exc
    print(format_results(result))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        save_summary(args.json, summary(result))
        print(f"wrote {args.json}")
    if args.plots:
        write_report(args.plots, sequence_label(result), result.errors)
        print(f"wrote tables and plots to {args.plots.resolve()}/")
    return 0
