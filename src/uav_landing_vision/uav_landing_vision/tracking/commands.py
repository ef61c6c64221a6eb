"""``uav-landing eval-metrics`` (the §6.5 sweep of the similarity metrics, Table 6.4) and
``uav-landing eval-optimisers`` (§6.6's pose optimisation protocol, Tables 6.9–6.10)."""

from dataclasses import replace
from pathlib import Path

from . import evaluate_command

_METRICS = ("colour", "contour", "distance_transform")


def register(sub) -> None:
    p = sub.add_parser("eval-metrics", help="sweep the similarity metrics around a nominal pose (thesis §6.5)")
    p.add_argument("--out", type=Path, default=Path("out/eval-metrics"), help="output folder (default: out/eval-metrics)")
    p.add_argument("--metric", choices=_METRICS, action="append",
                   help="metric to sweep, repeatable (default: all, with the thesis's variants)")
    p.add_argument("--distance", type=float, default=5.0, help="nominal distance Z in m (default: 5, Table 6.4)")
    p.add_argument("--background", choices=("normal", "complex"), default="normal",
                   help="simulator background of the frame (default: normal)")
    p.add_argument("--seed", type=int, default=0, help="seed of the background and sensor noise (default: 0)")
    p.add_argument("--tile", type=int, default=64, help="silhouette tile size in px (default: 64)")
    p.set_defaults(func=_run)
    evaluate_command.register(sub)

    from .optimisation import RESAMPLERS
    from .optimiser_evaluation import OPTIMISER_NAMES

    p = sub.add_parser("eval-optimisers", help="pose optimisation schemes from boosted hypotheses (thesis §6.6, "
                                               "Tables 6.9-6.10)")
    p.add_argument("--samples", type=int, default=100, help="random poses per distance (default: 100)")
    p.add_argument("--distances", type=float, nargs="+", default=[5.0, 15.0, 25.0, 35.0, 45.0],
                   help="metres, on the optical axis (default: 5 15 25 35 45, §6.6)")
    p.add_argument("--particles", type=int, default=100, help="pose samples M (default: 100)")
    p.add_argument("--iterations", type=int, default=10, help="optimisation iterations N (default: 10)")
    p.add_argument("--optimisers", default=",".join(OPTIMISER_NAMES),
                   help=f"comma-separated subset of {','.join(OPTIMISER_NAMES)} (default: all)")
    p.add_argument("--pfo-schedule", choices=("noise", "3phase", "iterative"), default="noise",
                   help="PFO artificial noise (Tables 6.6-6.7; default: noise)")
    p.add_argument("--pfo-resampling", choices=sorted(RESAMPLERS), default="reallocation",
                   help="PFO resampling scheme (App. B; default: reallocation, as the tracker)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    p.add_argument("--json", type=Path, default=None, metavar="OUT", help="write the statistics as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_run_optimisers)


def _run_optimisers(args) -> int:
    from ..camera import load_camera_info_yaml
    from ..cli import check_output
    from ..evaluation.report import strict_json
    from ..model import fixed_wing_mesh
    from ..resources import config_path
    from .optimisation import SECTION_6_6_NOISE
    from .optimiser_evaluation import OptimiserEvalConfig, evaluate_optimisers, format_tables

    optimisers = tuple(dict.fromkeys(o.strip() for o in args.optimisers.split(",") if o.strip()))
    try:
        config = OptimiserEvalConfig(
            samples=args.samples, distances=tuple(args.distances), particles=args.particles,
            iterations=args.iterations, optimisers=optimisers,
            pfo=replace(SECTION_6_6_NOISE, schedule=args.pfo_schedule, resampling=args.pfo_resampling), seed=args.seed)
        if args.json is not None:
            check_output("--json", args.json)
    except ValueError as exc:
        raise SystemExit(f"uav-landing eval-optimisers: {exc}") from None
    camera = load_camera_info_yaml(config_path("camera.yaml"))
    result = evaluate_optimisers(camera, fixed_wing_mesh("high"), config, progress=not args.quiet)
    print(format_tables(result))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(strict_json(result))
        print(f"wrote {args.json}")
    return 0


def _run(args) -> int:
    from ..cli import check_output
    from .metric_sweep import run_sweep, write_results

    if not 0.5 < args.distance < float("inf"):
        raise SystemExit(f"uav-landing eval-metrics: --distance must be finite and exceed 0.5 m, got {args.distance}")
    if args.seed < 0:
        raise SystemExit(f"uav-landing eval-metrics: --seed must be non-negative, got {args.seed}")
    try:
        check_output("--out", args.out, folder=True)
        result = run_sweep(tuple(dict.fromkeys(args.metric or _METRICS)), args.distance, args.background,
                           args.seed, args.tile)
    except ValueError as exc:
        raise SystemExit(f"uav-landing eval-metrics: {exc}") from exc
    for test in result["tests"]:
        peaks = ", ".join(f"{label} {p['at']:g}" for label, p in test["peaks"].items())
        print(f"{test['title']}: truth {test['truth']:g} {test['unit']}; peaks at {peaks}")
    paths = write_results(result, args.out)
    print(f"wrote {', '.join(p.name for p in paths)} to {args.out.resolve()}/")
    return 0
