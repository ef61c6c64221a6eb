"""``uav-landing bench``: per-stage throughput on this machine (what the README reports)."""


def register(sub) -> None:
    p = sub.add_parser("bench", help="measure render throughput (and other stages) on this machine")
    p.add_argument("--repeats", type=int, default=20, help="timed repetitions per case (default: 20)")
    p.set_defaults(func=_run)


def _run(args) -> int:
    from .render import benchmark as render_benchmark

    print("Silhouette rendering (one instanced draw + readback per call):")
    print(f"{'mesh':>6} {'particles':>9} {'tile':>5} {'ms/call':>9} {'particles/s':>12}")
    for row in render_benchmark.run(repeats=args.repeats):
        print(f"{row['mesh']:>6} {row['particles']:>9} {row['tile']:>5} {row['ms']:>9.2f} {row['particles_per_s']:>12.0f}")
    return 0
