"""``uav-landing demo`` (what ``make demo`` runs): a simulated landing through the node graph.

1. Simulate the landing of a shipped scenario into ``OUT/bags/`` (kept: later runs of the same
   scenario values reuse it).
2. Run the whole graph (:data:`~uav_landing_vision.graph.GRAPH_NODES`, one process per node,
   over DDS on its own ``ROS_DOMAIN_ID``) with ``bag_player`` paced on ``uav/tracker_status``,
   so every frame is tracked whatever the machine's speed.
3. The evaluator's thesis-format report lands in ``OUT/evaluation/``; its tables are printed,
   and ``OUT/overlay_strip.png`` shows the estimate's outline (green) and the truth's (magenta)
   on a few frames.
"""

import shutil
import signal
import sys
from pathlib import Path

import cv2
import numpy as np

from .graph import domain_id

ESTIMATE_COLOUR = (0, 255, 0)  # RGB
TRUTH_COLOUR = (255, 0, 255)


def register(sub) -> None:
    p = sub.add_parser("demo", help="simulate a landing and track it through the node graph (make demo)")
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder (default: out/demo)")
    p.add_argument("--scenario", default="normal", help="shipped scenario name or YAML (default: normal)")
    p.add_argument("--seed", type=int, help="scenario seed (default: the scenario's)")
    p.add_argument("--frames", type=int, help="first N frames of the approach only (default: all)")
    p.add_argument("--domain-id", type=domain_id, default=77,
                   help="ROS_DOMAIN_ID of the graph, apart from other ROS graphs on the network (default: 77)")
    p.add_argument("--strip", type=int, default=6, help="frames in the overlay strip (default: 6)")
    p.set_defaults(func=_run)


def _run(args) -> int:
    from .graph import GRAPH_NODES, Graph, node_environment
    from .resources import config_path
    from .sim import read_pose_csv

    if args.frames is not None and args.frames < 1:
        raise SystemExit("uav-landing demo: --frames must be at least 1")
    if args.seed is not None and args.seed < 0:
        raise SystemExit("uav-landing demo: --seed must be non-negative")
    if args.strip < 1:
        raise SystemExit(f"uav-landing demo: --strip must be at least 1, got {args.strip}")
    out = args.out.resolve()
    bag = simulated_bag(out / "bags", args.scenario, args.seed, args.frames)
    report = out / "evaluation"
    shutil.rmtree(report, ignore_errors=True)  # a report left by an earlier run must not pass for this one's
    overrides = graph_overrides(bag, report, sequence=bag.name)
    print(f"[demo] tracking {bag} through the graph ({', '.join(GRAPH_NODES)}), ROS_DOMAIN_ID {args.domain_id}",
          flush=True)
    env = node_environment(args.domain_id)
    graph = Graph(list(GRAPH_NODES), config_path("tracker.yaml").parent, overrides, env, stop_timeout=10.0)
    code = graph.run()
    if code != 0:
        raise SystemExit(f"uav-landing demo: the graph failed (exit {code}); see the node logs above")
    if graph.stopped_by_signal is not None:
        print(f"uav-landing demo: interrupted ({signal.Signals(graph.stopped_by_signal).name}); no report", file=sys.stderr)
        return 128 + graph.stopped_by_signal
    if not (report / "tables.txt").is_file():
        raise SystemExit(f"uav-landing demo: the evaluator wrote no report in {report}")
    print((report / "tables.txt").read_text())
    strip = overlay_strip(bag, read_pose_csv(report / "estimates.csv"), out / "overlay_strip.png", args.strip)
    print(f"[demo] report, error plots and estimates in {report}/; overlay strip {strip}")
    return 0


def graph_overrides(bag: Path, report_dir: Path, sequence: str) -> dict:
    """Per-node parameter overrides of a graph that replays ``bag`` frame by frame (paced on
    the tracker's status, nothing dropped, once every link of the graph is up, every node on the
    bag's time) and writes the evaluator's report to ``report_dir``."""
    from .graph import GRAPH_NODES, replay_overrides, replay_ready_topics, string_parameter
    from .tracking.upf import load_tracker_config

    tracker = load_tracker_config()
    overrides = replay_overrides(GRAPH_NODES, bag, replay_ready_topics(bag))
    overrides["bag_player"].append(("mode", "paced"))  # on the tracker's status (replay_overrides)
    overrides["evaluator"] += [("out_dir", string_parameter(report_dir)), ("sequence", string_parameter(sequence)),
                               ("variant", f"{tracker.variant}N{tracker.iterations}")]
    return overrides


def simulated_bag(folder: Path, scenario: str, seed: int | None, frames: int | None) -> Path:
    """The bag of ``scenario`` (simulated into ``folder`` unless it is there already, from the
    same scenario values: ``<bag>.scenario`` records them)."""
    from dataclasses import replace

    from .sim.config import ScenarioError, load_scenario
    from .sim.simulate import simulate

    try:
        sc = load_scenario(scenario)
    except ScenarioError as exc:
        raise SystemExit(f"uav-landing demo: {exc}") from exc
    seed = sc.seed if seed is None else seed
    bag = folder / f"{sc.name}_seed{seed}" if frames is None else folder / f"{sc.name}_seed{seed}_{frames}frames"
    recipe, record = f"{replace(sc, seed=seed)!r}\n", bag.with_name(bag.name + ".scenario")
    # simulate() makes the folder only once the bag is complete
    if (bag / "metadata.yaml").is_file() and record.is_file() and record.read_text() == recipe:
        print(f"[demo] using the simulated landing {bag}", flush=True)
        return bag
    shutil.rmtree(bag, ignore_errors=True)  # an edited scenario (or one not recorded): simulate it again
    result = simulate(sc, bag, seed=seed, frames=frames)
    record.write_text(recipe)
    print(f"[demo] simulated {result.frames} frames in {result.seconds:.0f} s: {bag}", flush=True)
    return bag


def overlay_strip(bag: Path, estimates, path: Path, count: int) -> Path:
    """A row of ``count`` undistorted frames, evenly spread over the bag, each with the outline
    of the model at the estimate and at the ground truth (when there is one), cropped about
    the UAV; written to ``path``."""
    from .camera import write_image
    from .model import fixed_wing_mesh
    from .render import Renderer
    from .sim import iter_frames, read_camera, read_poses

    raw_camera = read_camera(bag)
    camera, maps = raw_camera.rectified(), raw_camera.undistortion_maps()
    truth = read_poses(bag)
    estimate_at = {int(s): (t, q) for s, t, q in zip(estimates.stamps_ns, estimates.trans, estimates.quat)}
    chosen = set(np.linspace(0, len(truth.stamps_ns) - 1, max(count, 1)).round().astype(int).tolist())
    with Renderer(camera, fixed_wing_mesh("high")) as renderer:
        tiles = []
        for k, (stamp, raw) in enumerate(iter_frames(bag)):
            if k not in chosen:
                continue
            frame = cv2.remap(raw, maps[0], maps[1], cv2.INTER_LINEAR)
            i = int(np.searchsorted(truth.stamps_ns, stamp))
            true_pose = (truth.trans[i], truth.quat[i])
            _outline(frame, renderer, true_pose, TRUTH_COLOUR)
            if int(stamp) in estimate_at:
                _outline(frame, renderer, estimate_at[int(stamp)], ESTIMATE_COLOUR)
            tiles.append(_crop_about(frame, camera, true_pose[0], f"frame {k}, {true_pose[0][2]:.0f} m"))
    path.parent.mkdir(parents=True, exist_ok=True)
    write_image(path, np.hstack(tiles))
    return path


def _outline(frame: np.ndarray, renderer, pose, colour) -> None:
    trans, quat = pose
    mask = renderer.silhouette_full(quat, trans).astype(np.uint8)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(frame, contours, -1, colour, 1)


def _crop_about(frame: np.ndarray, camera, trans, label: str, size: int = 320) -> np.ndarray:
    """A ``size``² crop centred on the projected point ``trans`` (clamped to the frame), labelled."""
    u, v = camera.K[:2, :2] @ (np.asarray(trans[:2]) / trans[2]) + camera.K[:2, 2]
    x0 = int(np.clip(u - size / 2, 0, frame.shape[1] - size))
    y0 = int(np.clip(v - size / 2, 0, frame.shape[0] - size))
    tile = np.ascontiguousarray(frame[y0:y0 + size, x0:x0 + size])
    cv2.putText(tile, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return tile
