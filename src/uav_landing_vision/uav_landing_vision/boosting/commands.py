"""``uav-landing build-database`` and ``uav-landing eval-boosting`` (pose boosting, §4.3 / §6.4)."""

import shlex
import sys
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("build-database", help="render the pose-boosting database of a CAD model (§4.3.1)")
    p.add_argument("--out", type=Path, required=True, help="output .npz file")
    _model_args(p)
    p.add_argument("--count", type=int, default=11000, help="number of orientations (default: 11000)")
    p.add_argument("--distance", type=float, default=4.0, help="render depth Z in metres (default: 4)")
    rng = p.add_mutually_exclusive_group()
    rng.add_argument("--half-range-deg", type=float, nargs=3, metavar=("A", "B", "G"), default=(90.0, 90.0, 90.0),
                     help="Euler half-ranges about camera X, Y, Z (default: 90 90 90, the front hemisphere)")
    rng.add_argument("--full-sphere", action="store_true", help="all orientations: α, γ in ±180°, β in ±90°")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_build)

    p = sub.add_parser("eval-boosting", help="closest-hypothesis error of pose boosting (§6.4, Tables 6.2-6.3)")
    _model_args(p)
    p.add_argument("--database", type=Path, default=None, help="database .npz (default: the shipped one)")
    p.add_argument("--samples", type=int, default=15000, help="random poses per distance (default: 15000)")
    p.add_argument("--distances", type=float, nargs="+", default=[5.0, 15.0, 30.0], help="metres (default: 5 15 30)")
    p.add_argument("--top", type=int, nargs="+", default=[10, 25, 50, 100], help="hypothesis counts (default: 10 25 50 100)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    p.add_argument("--placement", choices=("axis", "view"), default="axis",
                   help="axis: X=Y=0 (default); view: random ray keeping the UAV in the image")
    p.add_argument("--aspect-weight", type=float, default=10.0,
                   help="weight of the aspect ratio in the distance (4.4) (default: 10; the thesis: 1)")
    p.add_argument("--thesis-centre", action="store_true", help="use the box centre as is in (4.6)-(4.7), as the thesis")
    p.add_argument("--thesis-orientation", action="store_true",
                   help="use each entry's orientation as is, not turned to the observed box angle, as the thesis")
    p.add_argument("--json", type=Path, default=None, metavar="OUT", help="write the statistics as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_evaluate)


def _model_args(p) -> None:
    p.add_argument("--camera", type=Path, default=None, help="camera_info YAML (default: config/camera.yaml)")
    p.add_argument("--model", default="high",
                   help="CAD file (OBJ/STL/PLY, body FLU, origin at the CG) or a built-in level: high, low (default: high)")
    p.add_argument("--unit", default="m", help="length unit of a CAD file: m, cm or mm (default: m)")


def _cad_file(args):
    """The CAD file ``--model`` names, or None for a built-in level."""
    from ..model import LEVELS

    return None if args.model in LEVELS else args.model


def _model_files(args) -> tuple:
    """``(option, path or None)`` of the camera and CAD files ``_model_args`` name."""
    return ("--camera", args.camera), ("--model", _cad_file(args))


def _load_camera_and_mesh(args):
    from ..camera import load_camera_info_yaml
    from ..model import fixed_wing_mesh, load_mesh
    from ..resources import config_path

    camera = load_camera_info_yaml(args.camera or config_path("camera.yaml")).rectified()
    cad = _cad_file(args)
    mesh = fixed_wing_mesh(args.model) if cad is None else load_mesh(cad, args.unit)
    return camera, mesh


def _build(args) -> int:
    import time

    from ..cli import check_output
    from .database import FULL_SPHERE_DEG, DatabaseConfig, build_database

    if args.seed < 0:
        raise SystemExit(f"uav-landing build-database: --seed must be non-negative, got {args.seed}")
    try:
        check_output("--out", args.out, others=_model_files(args))
        camera, mesh = _load_camera_and_mesh(args)
        config = DatabaseConfig(
            count=args.count, distance=args.distance, seed=args.seed,
            half_range_deg=FULL_SPHERE_DEG if args.full_sphere else tuple(args.half_range_deg),
        )
        command = "uav-landing " + shlex.join(sys.argv[1:]) if sys.argv[1:] else "uav-landing build-database"
        start = time.perf_counter()
        db = build_database(camera, mesh, config, command=command, progress=not args.quiet)
        path = db.save(args.out)
    except (ValueError, OSError) as exc:  # CameraInfoError, MeshError, DatabaseError, bad settings, files
        raise SystemExit(f"uav-landing build-database: {exc}") from None
    print(f"wrote {len(db)} entries ({config.count - len(db)} degenerate dropped) to {path} "
          f"({path.stat().st_size / 1024:.0f} KiB) in {time.perf_counter() - start:.1f} s")
    return 0


def _evaluate(args) -> int:
    from ..cli import check_output
    from ..evaluation.report import strict_json
    from .evaluation import BoostingEvalConfig, evaluate_boosting, format_tables

    try:
        config = BoostingEvalConfig(
            samples=args.samples, distances=tuple(args.distances), top=tuple(sorted(set(args.top))),
            seed=args.seed, placement=args.placement, centre_offset=not args.thesis_centre,
            turn_orientation=not args.thesis_orientation,
            aspect_weight=args.aspect_weight,
        )
        if args.json is not None:
            check_output("--json", args.json, others=(("--database", args.database), *_model_files(args)))
        camera, mesh = _load_camera_and_mesh(args)
        result = evaluate_boosting(camera, mesh, config, database_path=args.database, progress=not args.quiet)
    except (ValueError, OSError) as exc:  # CameraInfoError, MeshError, DatabaseError, bad settings, files
        raise SystemExit(f"uav-landing eval-boosting: {exc}") from None
    print(format_tables(result))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(strict_json({k: result[k] for k in ("samples", "failures", "stats")}))
        print(f"wrote {args.json}")
    return 0
