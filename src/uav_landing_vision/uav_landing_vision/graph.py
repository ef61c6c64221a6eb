"""``uav-landing graph``: the node graph, one process per node, where ``ros2 launch`` is not installed.

Each node of :data:`GRAPH_NODES` runs as
``python -m uav_landing_vision.nodes.<node> --ros-args --params-file <config>/<node>.yaml``
(the same parameter files as ``launch/landing_vision.launch.py``). Their output is streamed
with a ``[node]`` prefix. The graph stops, the nodes one at a time, the last started first, each
with SIGINT (then SIGTERM, then SIGKILL after ``--stop-timeout``; before SIGKILL, SIGUSR1 has a
hung node print its threads' stacks), on Ctrl-C or SIGTERM, ``--drain`` seconds after
``bag_player`` has played the bag (for the last frame's messages downstream), or when a node exits
on its own; the exit code is 0 only if every node ended cleanly.
With ``--bag`` every node runs on the bag's time (``use_sim_time``, from the player's ``/clock``),
as with ``ros2 bag play --clock``: the GCS bridge would otherwise find every replayed pose stale.
A bag that cannot be opened is refused before any node starts. ``--remap FROM:=TO`` remaps a
topic in every node (``-r``), e.g. a recording's ``/deck_cam/image_raw`` onto ``/camera/image_raw``.
A bag whose frames are only image_transport's compressed ones (``/camera/image_raw/compressed``)
is played with ``undistort`` decoding them (``image_transport: compressed``) and the player pacing
on them; ``--param`` can still set either.
This module imports no ROS module: the nodes do, in their own processes.
"""

import argparse
import json
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from contextlib import closing
from pathlib import Path

# The graph, in start order; a node is added by one line (its module, console script and
# config/<node>.yaml share the name).
GRAPH_NODES = (
    "undistort",
    "detector",
    "pose_boosting",
    "tracker",  # owns the process's only GL context
    "gcs_bridge",
    "evaluator",  # writes its report when the graph stops (no ground truth: none)
    "bag_player",  # started last: it waits for its subscribers, then plays
)
PLAYER = "bag_player"
MAX_DOMAIN_ID = 232  # rcl refuses larger ROS_DOMAIN_IDs
# Every link of the full graph. A replay that must not lose its first frames waits until each
# has a publisher and a subscriber (bag_player ``ready_topics``): the detector and pose
# boosting load their models for several seconds, longer than the player's settle time on a
# loaded machine.
PIPELINE_TOPICS = (
    "/camera/image_raw",
    "/camera/camera_info",
    "/camera/image_rect",
    "/camera/camera_info_rect",
    "/uav/detections",
    "/uav/pose_hypotheses",
    "/uav/pose",
    "/uav/tracker_status",
    "/uav/ground_truth",
)
# The inputs only a bag provides. A replay waits for those its bag has: nothing else ever publishes
# the others (a recorded landing has no ground truth), and a paced player would give up on them.
RECORDED_TOPICS = ("/camera/image_raw", "/camera/camera_info", "/uav/ground_truth")
# The frames as image_transport's compressed plugin sends them (sensor_msgs/CompressedImage): a
# bag that has only these is played with undistort decoding them (frame_overrides).
COMPRESSED_FRAMES = "/camera/image_raw/compressed"
# A replay through the tracker paces on its status, one per tracked frame: every frame is then
# tracked, as by `uav-landing evaluate`. Paced on undistort's output (bag_player.yaml), a tracker
# slower than the rest skipped frames: 22-28 of 60 here.
TRACKER_ACK = (("ack_topic", "uav/tracker_status"), ("ack_type", "uav_landing_msgs/msg/TrackerStatus"))
_CLEAN_EXIT = (0, -signal.SIGINT, 128 + signal.SIGINT)
_POLL_S = 0.1
STACK_DUMP_S = 1.0  # a hung node's time to print its stacks (SIGUSR1) before SIGKILL


def string_parameter(value) -> str:
    """``value`` as a string for a ``-p key:=value`` override, which rcl reads as YAML: quoted, so
    that a path with " #" is not cut at its comment or one with ": " refused."""
    # Not ASCII JSON: rcl refuses its \ud83d-style surrogate pairs. Characters YAML reads as line
    # breaks or refuses unescaped (DEL, C1, U+2028/9, BOM) stay escaped.
    return re.sub("[\x7f-\x9f\u2028\u2029\ufeff]", lambda m: f"\\u{ord(m.group()):04x}",
                  json.dumps(str(value), ensure_ascii=False))


def ready_topics_parameter(topics=PIPELINE_TOPICS) -> str:
    """``topics`` as the value of a ``-p ready_topics:=...`` override (a YAML list)."""
    return json.dumps(list(topics))


def ready_nodes_parameter(names) -> str:
    """The nodes of ``names`` but the player as the value of a ``-p ready_nodes:=...`` override."""
    return json.dumps([n for n in names if n != PLAYER])


def replay_ready_topics(bag, remaps=None) -> tuple[str, ...]:
    """:data:`PIPELINE_TOPICS` less the :data:`RECORDED_TOPICS` that ``bag`` lacks (all of them
    when it cannot be read: bag_player reports that at start-up), every name taken through the
    topic ``remaps`` ``{from: to}`` of the nodes."""
    recorded = _topics_if_readable(bag)
    return PIPELINE_TOPICS if recorded is None else _ready_topics(recorded, remaps)


def _ready_topics(recorded: set[str], remaps=None) -> tuple[str, ...]:
    """:func:`replay_ready_topics` of a bag with the topics ``recorded``."""
    remaps = remaps or {}
    played = {remaps.get(t, t) for t in recorded}
    topics = tuple(t for t in PIPELINE_TOPICS if t not in RECORDED_TOPICS or remaps.get(t, t) in played)
    return (COMPRESSED_FRAMES, *topics) if _compressed_frames(played, remaps) else topics


def _compressed_frames(played: set[str], remaps: dict) -> bool:
    """Whether the topics a bag ``played`` (its recorded ones through the ``remaps``) carry its
    frames only as compressed ones: :data:`COMPRESSED_FRAMES` and no ``/camera/image_raw``."""
    return remaps.get(COMPRESSED_FRAMES, COMPRESSED_FRAMES) in played and remaps.get(
        "/camera/image_raw", "/camera/image_raw") not in played


def frame_overrides(bag, remaps=None) -> dict:
    """:func:`_frame_overrides` of ``bag``; empty for one that cannot be read (bag_player reports
    that at start-up)."""
    recorded = _topics_if_readable(bag)
    return {} if recorded is None else _frame_overrides(recorded, remaps)


def _topics_if_readable(bag) -> set[str] | None:
    """The topics of ``bag``, None if it cannot be read. The launch file runs in `ros2 launch`'s
    Python, which may lack rosbags (the package's own may be a virtual environment): there a bag
    folder's metadata.yaml is read instead, and for anything else the lack is said."""
    try:
        from .sim.bag import BagError
    except ImportError as exc:
        try:
            return _listed_topics(Path(bag) / "metadata.yaml")
        except (OSError, ValueError):
            print(f"[uav_landing_vision] cannot read the topics of {bag} in this Python ({exc}): it is replayed "
                  "as a bag of raw frames, camera_info and ground truth", file=sys.stderr, flush=True)
            return None
    try:
        return _recorded_topics(bag)
    except BagError:
        return None


def _listed_topics(metadata: Path) -> set[str]:
    """The topics a rosbag2 ``metadata.yaml`` lists; OSError or ValueError if it cannot say."""
    import yaml

    try:
        info = yaml.safe_load(metadata.read_text())["rosbag2_bagfile_information"]
        return {entry["topic_metadata"]["name"] for entry in info["topics_with_message_count"]}
    except (yaml.YAMLError, KeyError, TypeError) as exc:
        raise ValueError(f"{metadata}: not a rosbag2 metadata file ({exc})") from exc


def _frame_overrides(recorded: set[str], remaps=None) -> dict:
    """``{node: [(key, value)]}`` that play a bag with the topics ``recorded`` if its frames are
    only compressed ones (:data:`COMPRESSED_FRAMES`): ``undistort`` decodes them, the player paces
    on them. Empty for a bag of raw frames."""
    remaps = remaps or {}
    if not _compressed_frames({remaps.get(t, t) for t in recorded}, remaps):
        return {}
    return {"undistort": [("image_transport", "compressed")], PLAYER: [("pace_topic", COMPRESSED_FRAMES)]}


def _recorded_topics(bag) -> set[str]:
    """The topics of ``bag``; BagError if it cannot be opened."""
    from .sim.bag import open_bag

    with closing(open_bag(bag)) as reader:
        return {conn.topic for conn in reader.connections}


def replay_overrides(names, bag, ready_topics=None) -> dict:
    """Parameter overrides of the graph ``names`` replaying ``bag``: the player plays it and
    publishes ``/clock``, every other node runs on that clock (as with ``ros2 bag play --clock``: a
    replayed pose is then not stale); given ``ready_topics`` (e.g. :func:`replay_ready_topics`),
    the player first waits for those links, or the first frames (and their ground truth, which
    the evaluator then never counts) are lost to the nodes still starting, and, as seen by each
    other node (``ready_nodes``), for every link among them on those topics. With the tracker
    in the graph, a paced player waits for its status (:data:`TRACKER_ACK`)."""
    overrides = {n: [] if n == PLAYER else [("use_sim_time", "true")] for n in names}
    overrides[PLAYER] += [("bag", string_parameter(Path(bag).resolve())), ("clock", "true")]
    if "tracker" in names:
        overrides[PLAYER] += list(TRACKER_ACK)
    if ready_topics is not None:
        overrides[PLAYER].append(("ready_topics", ready_topics_parameter(ready_topics)))
        overrides[PLAYER].append(("ready_nodes", ready_nodes_parameter(names)))
    return overrides


def register(sub) -> None:
    p = sub.add_parser("graph", help="run the node graph, one process per node (what ros2 launch would do)")
    p.add_argument("--bag", type=Path, help="rosbag2 bag to replay with bag_player; without it, no bag_player (live camera)")
    p.add_argument("--config", type=Path, help="folder of the <node>.yaml parameter files (default: the package's config/)")
    p.add_argument("--nodes", help=f"comma-separated subset of {','.join(GRAPH_NODES)} (default: all)")
    p.add_argument(
        "--param", action="append", default=[], metavar="NODE:KEY=VALUE",
        help="override one parameter of one node (repeatable), e.g. bag_player:mode=timed",
    )
    p.add_argument(
        "--remap", action="append", default=[], metavar="FROM:=TO",
        help="remap a topic (absolute names) in every node (repeatable), e.g. a recording's "
             "/deck_cam/image_raw:=/camera/image_raw",
    )
    p.add_argument("--domain-id", type=domain_id, help="ROS_DOMAIN_ID of the graph (default: the environment's)")
    p.add_argument("--stop-timeout", type=float, default=10.0, help="seconds a node gets to stop before it is killed (default: 10)")
    p.add_argument("--drain", type=float, default=2.0,
                   help="seconds between the end of the bag and the stop, for the last messages (default: 2)")
    p.set_defaults(func=_run)


def node_command(name: str, config_dir: Path, overrides=(), remaps=None) -> list[str]:
    """The command line of one node process: its parameter file, then ``overrides`` ``[(key,
    value)]`` and the topic ``remaps`` ``{from: to}``."""
    cmd = [sys.executable, "-m", f"uav_landing_vision.nodes.{name}", "--ros-args", "--params-file", str(config_dir / f"{name}.yaml")]
    for key, value in overrides:
        cmd += ["-p", f"{key}:={value}"]
    for source, target in (remaps or {}).items():
        cmd += ["-r", f"{source}:={target}"]
    return cmd


def _run(args) -> int:
    if args.config is None:
        from .resources import config_path

        args.config = config_path("tracker.yaml").parent
    try:
        remaps = parse_remaps(args.remap)
        names, overrides = _plan(args, remaps)
    except ValueError as exc:
        print(f"uav-landing graph: {exc}", file=sys.stderr)
        return 2
    env = node_environment(args.domain_id)
    return Graph(names, args.config, overrides, env, args.stop_timeout, args.drain, remaps).run()


def parse_remaps(items) -> dict:
    """``["/from:=/to", ...]`` as ``{from: to}``; ValueError on a rule that is not one."""
    remaps = {}
    for item in items:
        source, sep, target = item.partition(":=")
        if not (sep and source and target):
            raise ValueError(f"--remap {item!r}: expected FROM:=TO")
        if not (source.startswith("/") and target.startswith("/")):
            raise ValueError(f"--remap {item!r}: give absolute topic names (/name)")
        remaps[source] = target
    return remaps


def domain_id(text: str) -> int:
    """A ``--domain-id`` (argparse type): 0–232, rcl's range (rcl takes -1 for its default, 0: a
    graph meant for a private domain would have joined every default graph on the network)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if not 0 <= value <= MAX_DOMAIN_ID:
        raise argparse.ArgumentTypeError(f"a ROS domain ID is 0 to {MAX_DOMAIN_ID}, got {value}")
    return value


def node_environment(domain_id: int | None = None) -> dict:
    """The environment of the node processes: this one's, unbuffered, with this package
    importable and, if given, ``ROS_DOMAIN_ID``."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    # The nodes import this very package, wherever it is (source tree or install space).
    package_root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (package_root, env.get("PYTHONPATH")) if p)
    if domain_id is not None:
        env["ROS_DOMAIN_ID"] = str(domain_id)
    return env


def _plan(args, remaps=None) -> tuple[list[str], dict]:
    """The nodes to start and the parameter overrides of each; ValueError on a bad request."""
    names = list(GRAPH_NODES) if args.nodes is None else [n.strip() for n in args.nodes.split(",") if n.strip()]
    unknown = [n for n in names if n not in GRAPH_NODES]
    if unknown:
        raise ValueError(f"unknown node(s) {unknown}; known: {list(GRAPH_NODES)}")
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise ValueError(f"node(s) {repeated} named more than once in --nodes")
    if args.bag is None:
        names = [n for n in names if n != PLAYER]
    elif PLAYER not in names:
        raise ValueError("--bag needs bag_player among --nodes")
    elif not args.bag.exists():
        raise ValueError(f"bag {args.bag} does not exist")
    else:
        recorded = _readable_bag_topics(args.bag)
    if not names:
        raise ValueError("no node to run")
    if not (0 <= args.drain < math.inf and 0 < args.stop_timeout < math.inf):
        raise ValueError("--drain must be >= 0 and --stop-timeout > 0, both finite")
    if args.bag is None:
        overrides = {n: [] for n in names}
    else:  # the whole graph waits for its links unless told which
        told = any(i.startswith(f"{PLAYER}:ready_topics=") for i in args.param)
        whole = set(names) == set(GRAPH_NODES) and not told
        frames = _frame_overrides(recorded, remaps)
        ready = _ready_topics(recorded, remaps) if whole else None
        if frames and not (whole or told):  # the parameter file's inputs, the frames' topic swapped
            ready = tuple(t for t in _ready_topics(recorded, remaps) if t in (COMPRESSED_FRAMES, "/camera/camera_info"))
        overrides = replay_overrides(names, args.bag, ready)
        if ready is None and not any(i.startswith(f"{PLAYER}:ready_nodes=") for i in args.param):
            overrides[PLAYER].append(("ready_nodes", ready_nodes_parameter(names)))  # on the file's or the given ready_topics
        if frames:
            print(f"[graph] the bag's frames are compressed ({COMPRESSED_FRAMES}): undistort image_transport=compressed, "
                  f"bag_player pace_topic={COMPRESSED_FRAMES}", flush=True)
        for node, items in frames.items():
            if node in overrides:
                overrides[node] += items
    for item in args.param:
        node, sep, assignment = item.partition(":")
        key, eq, value = assignment.partition("=")
        if not (sep and eq and key):
            raise ValueError(f"--param {item!r}: expected NODE:KEY=VALUE")
        if node not in overrides:
            raise ValueError(f"--param {item!r}: node '{node}' is not in the graph")
        overrides[node].append((key, value))
    missing = [str(args.config / f"{n}.yaml") for n in names if not (args.config / f"{n}.yaml").is_file()]
    if missing:
        raise ValueError(f"missing parameter file(s): {', '.join(missing)}")
    return names, overrides


def _readable_bag_topics(bag) -> set[str]:
    """The topics of ``bag``; ValueError if it does not open: a damaged one would fail the player
    while the others start."""
    from .sim.bag import BagError

    try:
        return _recorded_topics(bag)
    except BagError as exc:
        raise ValueError(f"bag {bag} is not a readable rosbag2 bag: {exc}") from exc


class Graph:
    """The node processes of one run, their log streams and their shutdown."""

    def __init__(self, names, config_dir: Path, overrides: dict, env: dict, stop_timeout: float, drain_s: float = 2.0,
                 remaps=None):
        self.names = names
        self.config_dir = config_dir
        self.overrides = overrides
        self.remaps = remaps or {}
        self.env = env
        self.stop_timeout = stop_timeout
        self.drain_s = drain_s
        self.procs: dict[str, subprocess.Popen] = {}
        self.stopped_by_signal: int | None = None  # the signal that stopped the run, if one did
        self._print_lock = threading.Lock()
        self._stop_requested = threading.Event()

    def run(self) -> int:
        # SIGHUP too (a closed terminal or ssh session): the nodes have their own sessions, so
        # without the launcher they would run on.
        previous = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
        streams = []
        try:
            for name in self.names:
                # Own session: a terminal's Ctrl-C reaches the launcher only, which stops the nodes in order.
                proc = subprocess.Popen(
                    node_command(name, self.config_dir, self.overrides[name], self.remaps), env=self.env,
                    stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, errors="replace",
                    start_new_session=True,
                )
                self.procs[name] = proc
                streams.append(threading.Thread(target=self._stream, args=(name, proc), daemon=True))
                streams[-1].start()
                self._say(f"started {name} (pid {proc.pid})")
            failed = self._watch()
        finally:
            self._stop_all()
            for thread in streams:
                thread.join(timeout=5.0)
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        for name, proc in self.procs.items():
            if proc.returncode not in _CLEAN_EXIT and name not in failed:
                failed.append(name)
        if failed:
            self._say("failed: " + ", ".join(f"{name} (exit code {self.procs[name].returncode})" for name in failed))
            return 1
        self._say("all nodes stopped cleanly")
        return 0

    def _watch(self) -> list[str]:
        """Wait for a stop request or a node's exit; the nodes that failed by then."""
        while not self._stop_requested.is_set():
            for name, proc in self.procs.items():
                code = proc.poll()
                if code is None:
                    continue
                if name == PLAYER and code == 0:
                    self._say(f"bag played; stopping the graph in {self.drain_s:g} s")
                    self._stop_requested.wait(self.drain_s)
                    return []
                self._say(f"{name} exited with code {code}; stopping the graph")
                return [] if code in _CLEAN_EXIT else [name]
            self._stop_requested.wait(_POLL_S)
        self._say("stop requested; stopping the graph")
        return []

    def _stop_all(self) -> None:
        """Stop the nodes one at a time, the last started first: all at once, a node's DDS teardown
        runs into the others' (Fast DDS hung in one, seen in loaded e2e runs)."""
        for name in reversed(list(self.procs)):
            self._stop(name, self.procs[name])

    def _stop(self, name: str, proc: subprocess.Popen) -> None:
        """SIGINT, then SIGTERM, then (after SIGUSR1 for its stacks) SIGKILL, ``stop_timeout`` apart."""
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            if proc.poll() is not None:
                return
            if sig != signal.SIGINT:
                dump = " after SIGUSR1 (its threads' stacks)" if sig == signal.SIGKILL else ""
                self._say(f"{name} still running {self.stop_timeout:g} s after the last signal; sending {sig.name}{dump}")
                if dump:
                    proc.send_signal(signal.SIGUSR1)
                    time.sleep(STACK_DUMP_S)
            proc.send_signal(sig)
            try:
                proc.wait(timeout=self.stop_timeout)
            except subprocess.TimeoutExpired:
                continue

    def _on_signal(self, signum, frame) -> None:
        self.stopped_by_signal = signum
        self._stop_requested.set()

    def _stream(self, name: str, proc: subprocess.Popen) -> None:
        for line in proc.stdout:  # read to the end even if it cannot be shown: a full pipe blocks the node
            self._write(f"[{name}] {line}")

    def _say(self, text: str) -> None:
        self._write(f"[graph] {text}\n")

    def _write(self, text: str) -> None:
        """Show a log line; an output that has gone (a closed pipe) must not stop the shutdown."""
        with self._print_lock:
            try:
                sys.stdout.write(text)
                sys.stdout.flush()
            except OSError:
                pass
