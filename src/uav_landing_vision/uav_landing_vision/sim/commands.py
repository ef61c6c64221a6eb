"""``uav-landing simulate``: write a simulated landing sequence with ground truth to a rosbag2."""

from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("simulate", help="simulate a landing sequence (rosbag2 mcap with ground truth)")
    p.add_argument("--scenario", default="normal",
                   help="shipped scenario (normal, complex, video, single_frame) or a scenario YAML file")
    p.add_argument("--seed", type=int, help="random seed (default: the scenario's)")
    p.add_argument("--frames", type=int, help="keep only the first N frames (default: the whole approach)")
    p.add_argument("--video", help="video file or rosbag2 for the 'video' background")
    p.add_argument("--out", type=Path, required=True, help="new rosbag2 directory to write")
    p.add_argument("--png-dir", type=Path, help="also write PNG frames + ground_truth.csv + camera_info.yaml here")
    p.add_argument("--compress", action="store_true", help="zstd-compress the mcap chunks (smaller, slower)")
    p.set_defaults(func=_run)


def _refusal(message) -> SystemExit:
    return SystemExit(f"uav-landing simulate: {message}")


def _nested(a: Path, b: Path) -> bool:
    """Whether folders ``a`` and ``b`` are the same or one is inside the other."""
    a, b = a.resolve(), b.resolve()
    return a == b or a in b.parents or b in a.parents


def _run(args) -> int:
    from ..camera import CameraInfoError
    from .backgrounds import BackgroundError
    from .config import ScenarioError, load_scenario
    from .simulate import simulate

    if args.frames is not None and args.frames < 1:
        raise _refusal("--frames must be at least 1")
    if args.seed is not None and args.seed < 0:
        raise _refusal("--seed must be non-negative")
    for option, path in (("--out", args.out), ("--png-dir", args.png_dir)):
        if path is not None and path.exists():
            raise _refusal(f"{option} {path} exists already; give a new directory")
    if args.png_dir is not None and _nested(args.out, args.png_dir):
        raise _refusal(f"--png-dir {args.png_dir} and --out {args.out} must not contain each other")
    try:
        scenario = load_scenario(args.scenario)
        if args.video and scenario.background.kind != "video":
            raise _refusal(f"--video is for the 'video' background; scenario '{scenario.name}' has "
                           f"'{scenario.background.kind}'")
        result = simulate(scenario, args.out, seed=args.seed, frames=args.frames, video=args.video,
                          png_dir=args.png_dir, compress=args.compress)
    except (ScenarioError, BackgroundError, CameraInfoError, OSError) as exc:
        raise _refusal(exc) from exc
    print(f"wrote {result.frames} frames to {result.bag_dir.resolve()} in {result.seconds:.1f} s")
    return 0
