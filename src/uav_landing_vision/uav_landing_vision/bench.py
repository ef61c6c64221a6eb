"""``uav-landing bench``: per-stage throughput on this machine (what the README reports)."""


def register(sub) -> None:
    p = sub.add_parser("bench", help="measure per-stage throughput on this machine")
    p.add_argument("--repeats", type=int, default=20, help="timed repetitions per case (default: 20)")
    p.set_defaults(func=_run)


def _run(args) -> int:
    from .detection import benchmark as detector_benchmark
    from .filters import benchmark as filter_benchmark
    from .render import benchmark as render_benchmark
    from .tracking import likelihood_benchmark, upf_benchmark

    if args.repeats < 1:
        raise SystemExit("uav-landing bench: --repeats must be at least 1")
    print("Silhouette rendering (one instanced draw + readback per call):")
    print(render_benchmark.format_rows(render_benchmark.run(repeats=args.repeats)))
    print("\nLikelihoods, M=100, tile 64, 1280x720 frame:")
    print(likelihood_benchmark.format_result(likelihood_benchmark.run(repeats=args.repeats)))
    print("\nMotion filters, one predict + update for a batch of 100:")
    for name, ms in filter_benchmark.run(m=100, repeats=10 * args.repeats).items():
        print(f"{name:>16} {ms:8.3f} ms")
    print()
    print(upf_benchmark.format_result(upf_benchmark.run()))
    print()
    try:
        print(detector_benchmark.format_result(detector_benchmark.run(repeats=args.repeats)))
    except OSError as exc:
        print(f"Detector: not measured, no model ({exc})")
    return 0
