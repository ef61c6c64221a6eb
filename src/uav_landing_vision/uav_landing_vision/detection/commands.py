"""``uav-landing make-detection-data | train-detector | train-verifier | eval-detector``."""

from pathlib import Path


def _size(text: str) -> tuple[int, int]:
    w, _, h = text.partition("x")
    return int(w), int(h)


def register(sub) -> None:
    p = sub.add_parser("make-detection-data", help="generate the synthetic detection dataset (§4.2.2)")
    p.add_argument("--out", type=Path, required=True, help="dataset folder (a new one, or an unfinished one to continue)")
    p.add_argument("--count", type=int, default=1000, help="number of images (default: 1000)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--families", default="normal,complex", help="comma list of normal,complex,images,video")
    p.add_argument("--images", default="", help="folder of user background images (family 'images')")
    p.add_argument("--video", default="", help="video file or bag (family 'video')")
    p.add_argument("--camera", default="",
                   help="camera_info YAML (a path, else a config/ file name; default: config/camera.yaml)")
    p.add_argument("--approach-fraction", type=float, default=0.0,
                   help="fraction of head-on approach attitudes (default: 0; the rest landing-like/random)")
    p.add_argument("--landing-fraction", type=float, default=0.0,
                   help="fraction of frames of simulated landings (default: 0)")
    p.add_argument("--landing-negative-fraction", type=float, default=0.0,
                   help="fraction of those landing frames drawn without the UAV (default: 0)")
    p.add_argument("--landing-sun-spread", type=float, default=180.0,
                   help="landing frames' sun azimuth: the scenario's ± this many degrees (default: 180, any)")
    p.add_argument("--banks-per-family", type=int, default=3,
                   help="sky/sea panoramas (each with its own sun) per simulator family (default: 3)")
    p.add_argument("--label-box", choices=("oriented", "extent"), default="oriented",
                   help="label: the ROI of the oriented box (Fig. 4.4, default) or the model's projected extent")
    p.add_argument("--workers", type=int, default=1, help="processes generating in parallel (default: 1)")
    p.set_defaults(func=_make_data)

    p = sub.add_parser("train-detector", help="train the detector on the CPU and export it to ONNX")
    p.add_argument("--data", type=Path, nargs="+", default=[Path("out/detection_data")],
                   help="dataset folder(s) of make-detection-data, used together (default: out/detection_data)")
    p.add_argument("--out", type=Path, default=Path("out/detector_train"), help="run folder (checkpoints, log); a new one unless --resume")
    p.add_argument("--epochs", type=int, default=30)
    p.add_argument("--batch", type=int, default=16)
    p.add_argument("--lr", type=float, default=2e-3)
    p.add_argument("--input", type=_size, default=(640, 384), help="letterbox WxH (default 640x384)")
    p.add_argument("--crop", type=_size, default=(320, 192), help="training crop WxH (0x0: whole frames)")
    p.add_argument("--width", type=int, default=48, help="network width (stride-8 channels)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--loader-workers", type=int, default=0, help="image-decoding processes (default: 0)")
    p.add_argument("--max-images", type=int, default=0, help="use the first N images of each folder only (0: all)")
    p.add_argument("--init", type=Path, default=None,
                   help="start from this network (fine-tuning): another run's last.pt, or an exported .onnx of the "
                        "same width, whose folded batch normalisation then stays frozen")
    p.add_argument("--resume", action="store_true", help="continue from OUT/last.pt")
    p.add_argument("--export", type=Path, default=None, help="ONNX path (default: OUT/detector.onnx)")
    p.add_argument("--export-only", action="store_true",
                   help="export OUT/last.pt (e.g. of an interrupted run) without training")
    p.set_defaults(func=_train)

    p = sub.add_parser("train-verifier", help="train the box verifier on crops mined with the detector, export ONNX")
    p.add_argument("--data", type=Path, nargs="+", required=True, help="dataset folder(s) of make-detection-data")
    p.add_argument("--out", type=Path, default=Path("out/verifier_train"),
                   help="run folder (mined crops, checkpoints, log); a new one unless --resume")
    p.add_argument("--detector", default="detector.onnx", help="detector whose boxes are mined (shipped name or path)")
    p.add_argument("--mine-threshold", type=float, default=0.1, help="detector score down to which boxes are mined")
    p.add_argument("--epochs", type=int, default=6)
    p.add_argument("--batch", type=int, default=128)
    p.add_argument("--lr", type=float, default=2e-3)
    p.add_argument("--width", type=int, default=16, help="channels of the first stage")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--workers", type=int, default=2, help="mining processes (default: 2)")
    p.add_argument("--resume", action="store_true", help="continue from OUT/last.pt")
    p.add_argument("--export", type=Path, default=None, help="ONNX path (default: OUT/verifier.onnx)")
    p.set_defaults(func=_train_verifier)

    p = sub.add_parser("eval-detector", help="precision-recall, AP50, recall by size and speed on a bag")
    p.add_argument("--bag", type=Path, required=True, help="simulated rosbag2 folder with /uav/ground_truth")
    p.add_argument("--json", type=Path, required=True, help="metrics JSON to write")
    p.add_argument("--png", type=Path, default=None, help="PR curve PNG (default: next to the JSON)")
    p.add_argument("--model", default="detector.onnx", help="shipped model name or path")
    p.add_argument("--verifier", default="none",
                   help="box verifier: shipped model name (verifier.onnx) or path; 'none' (default): the detector alone")
    p.add_argument("--verifier-threshold", type=float, default=0.5,
                   help="boxes the verifier gives a lower probability are dropped (default: 0.5)")
    p.add_argument("--threshold", type=float, default=0.5, help="operating score threshold")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--truth-box", choices=("oriented", "extent"), default="oriented",
                   help="ground-truth ROI: the ROI of the model's oriented box, as the training labels "
                        "(Fig. 4.4), or the extent of the projected model")
    p.add_argument("--remap", action="append", default=[], metavar="FROM:=TO",
                   help="a recording of other topic names (repeatable), as uav-landing graph --remap: e.g. "
                        "/deck_cam/image_raw:=/camera/image_raw")
    p.set_defaults(func=_evaluate)


def _make_data(args) -> int:
    from .dataset import DatasetConfig, generate

    families = tuple(f.strip() for f in args.families.split(",") if f.strip())
    try:
        cfg = DatasetConfig(count=args.count, seed=args.seed, families=families, image_dir=args.images,
                            video=args.video, camera_info=args.camera, approach_fraction=args.approach_fraction,
                            landing_fraction=args.landing_fraction,
                            landing_negative_fraction=args.landing_negative_fraction,
                            landing_sun_spread_deg=args.landing_sun_spread, banks_per_family=args.banks_per_family,
                            label_box=args.label_box)
        summary = generate(cfg, args.out, workers=args.workers)
    except (ValueError, OSError) as exc:  # CameraInfoError, a camera file or folder that is not there
        raise SystemExit(f"uav-landing make-detection-data: {exc}") from None
    print(f"wrote {summary['images']} images ({summary['positives']} with the UAV) to {args.out}")
    return 0


def _train(args) -> int:
    import time

    from ..cli import check_output
    from .export import export_onnx
    from .train import TrainConfig, load_checkpoint, train, trained_network

    try:
        cfg = TrainConfig(data=tuple(str(d) for d in args.data), out=str(args.out), epochs=args.epochs, batch=args.batch,
                          lr=args.lr, input_size=args.input, crop=args.crop, width=args.width, seed=args.seed,
                          threads=args.threads, loader_workers=args.loader_workers, max_images=args.max_images,
                          init=str(args.init or ""))
    except ValueError as exc:
        raise SystemExit(f"uav-landing train-detector: {exc}") from None
    t0 = time.perf_counter()
    try:
        if args.export is not None:  # before the training, not after it
            check_output("--export", args.export)
        if not args.export_only:
            train(cfg, resume=args.resume)
        state = load_checkpoint(cfg)
    except (FileNotFoundError, ValueError) as exc:
        raise SystemExit(f"uav-landing train-detector: {exc}") from None
    log = state["log"]
    onnx_path = args.export or args.out / "detector.onnx"
    last = log["epochs"][-1] if log["epochs"] else {}
    description = (f"UavDetectorNet width {cfg.width}, input {cfg.input_size[0]}x{cfg.input_size[1]}, "
                   f"{log['train_images']} training images, {len(log['epochs'])} of {cfg.epochs} epochs, "
                   f"val AP50 {last.get('val_ap50', float('nan')):.3f}")
    export_onnx(trained_network(cfg, state), onnx_path, cfg.input_size, description)
    done = "checkpoint" if args.export_only else f"trained in {time.perf_counter() - t0:.0f} s"
    print(f"{done}; exported {onnx_path} ({description})")
    return 0


def _train_verifier(args) -> int:
    import time

    from ..cli import check_output
    from .export import export_verifier_onnx
    from .train import load_checkpoint
    from .verifier_train import VerifierTrainConfig, train_verifier, trained_verifier

    try:
        cfg = VerifierTrainConfig(data=tuple(str(d) for d in args.data), out=str(args.out), detector=args.detector,
                                  mine_threshold=args.mine_threshold, epochs=args.epochs, batch=args.batch,
                                  lr=args.lr, width=args.width, seed=args.seed, threads=args.threads,
                                  workers=args.workers)
        if args.export is not None:
            check_output("--export", args.export)
        t0 = time.perf_counter()
        train_verifier(cfg, resume=args.resume)
        state = load_checkpoint(cfg)
    except (FileNotFoundError, ValueError) as exc:
        raise SystemExit(f"uav-landing train-verifier: {exc}") from None
    log = state["log"]
    last = log["epochs"][-1]
    description = (f"BoxVerifierNet width {cfg.width}, {log['train_crops']} training crops mined with "
                   f"{Path(cfg.detector).name}, {len(log['epochs'])} epochs, val AP {last.get('val_ap', float('nan')):.4f}")
    onnx_path = export_verifier_onnx(trained_verifier(cfg, state), args.export or args.out / "verifier.onnx",
                                     description=description)
    print(f"trained in {time.perf_counter() - t0:.0f} s; exported {onnx_path} ({description})")
    return 0


def _evaluate(args) -> int:
    from ..cli import check_output
    from ..graph import parse_remaps
    from .detector import DetectorConfig
    from .evaluation import evaluate_bag

    verifier = "" if args.verifier == "none" else args.verifier
    try:
        cfg = DetectorConfig(model=args.model, verifier=verifier, verifier_threshold=args.verifier_threshold,
                             score_threshold=args.threshold, threads=args.threads)
        png = args.png or args.json.with_suffix(".png")
        if png.suffix.lower() != ".png":
            raise ValueError(f"--png {png}: give a file name ending in .png")
        check_output("--json", args.json)
        check_output("--png", png, others=(("--json", args.json),))
        r = evaluate_bag(args.bag, cfg, args.json, png, truth_box=args.truth_box, remaps=parse_remaps(args.remap))
    except (ValueError, OSError) as exc:  # a bag that cannot be read or lacks a topic, a missing model
        raise SystemExit(f"uav-landing eval-detector: {exc}") from None
    print(f"AP50 {r['ap50']:.3f}  precision {r['precision']:.3f}  recall {r['recall']:.3f} at {r['threshold']}  "
          f"FP/100 frames {r['false_positives_per_100_frames']:.1f} (best box only "
          f"{r['best_box_false_positives_per_100_frames']:.1f})  median {r['ms_per_frame']:.1f} ms/frame")
    if "truth_near_ties" in r:
        print(f"Fig. 4.4 truth: {r['truth_near_ties']} of {r['frames']} frames a near tie; {r['runner_up_misses']} "
              f"misses matched the runner-up box instead (area margins {r['runner_up_miss_margins']})")
    print(f"wrote {args.json} and {png}")
    return 0
