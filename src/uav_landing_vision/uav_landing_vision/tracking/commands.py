"""``uav-landing eval-metrics``: the §6.5 sweep of the similarity metrics (Table 6.4)."""

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


def _run(args) -> int:
    from .metric_sweep import run_sweep, write_results

    if not args.distance > 0.5:
        raise SystemExit("uav-landing eval-metrics: --distance must exceed 0.5 m")
    try:
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
