"""``uav-landing bench``: per-stage throughput on this machine (what the README reports)."""


def register(sub) -> None:
    p = sub.add_parser("bench", help="measure per-stage throughput on this machine")
    p.add_argument("--repeats", type=int, default=20, help="timed repetitions per case (default: 20)")
    p.set_defaults(func=_run)


def _run(args) -> int:
    from .render import benchmark as render_benchmark

    print("Silhouette rendering (one instanced draw + readback per call):")
    print(render_benchmark.format_rows(render_benchmark.run(repeats=args.repeats)))
    return 0
