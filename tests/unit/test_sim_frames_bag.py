"""Frame synthesis and bag output: ground truth vs. drawn UAV, rosbags round trip, determinism, video."""

import dataclasses
import hashlib

import cv2
import numpy as np
import pytest

from uav_landing_vision.camera import CameraModel
from uav_landing_vision.model import fixed_wing_mesh
from uav_landing_vision.render import Renderer
from uav_landing_vision.sim import (
    BackgroundError,
    ScenarioError,
    VideoBackground,
    generators,
    iter_frames,
    load_scenario,
    make_trajectory,
    read_camera,
    read_poses,
    SequenceWriter,
    scenario_camera,
    simulate,
)
from uav_landing_vision.sim import bag as sim_bag
from uav_landing_vision.sim.synthesis import FrameSynthesizer, motion_blur_kernel

MESH = fixed_wing_mesh("low")


@pytest.fixture(scope="module")
def setup():
    s = load_scenario("complex")
    s = dataclasses.replace(s, imaging=dataclasses.replace(s.imaging, noise_sigma=0.0))
    cam = scenario_camera(s)
    synth = FrameSynthesizer(cam, s.imaging, MESH)
    return s, cam, synth, Renderer(cam.rectified(), MESH)


def _finer(cam: CameraModel, k: int) -> CameraModel:
    """The same lens sampled ``k``× finer: every pixel split into k×k (pixel centres kept)."""
    K = cam.K.copy()
    K[:2, :2] *= k
    K[:2, 2] = (K[:2, 2] + 0.5) * k - 0.5
    return CameraModel(cam.width * k, cam.height * k, K, cam.dist, cam.frame_id)


def test_ground_truth_matches_drawn_uav_after_undistortion(setup):
    """IoU ≥ 0.9 between the model's silhouette at the true pose (rectified camera) and the UAV
    drawn in the distorted frame, undistorted, from 5 to 85 m. Beyond ~8 m the UAV is a few
    pixels high, where one pixel of resampling already costs more than 0.1 of IoU; there the
    same lens is sampled 4× finer, so the check is of the geometry, not of the pixel size."""
    s, cam, _, _ = setup
    tr = make_trajectory(s, generators(2))
    r = np.linalg.norm(tr.trans, axis=1)
    for k, distances in ((1, (5.2, 7.0)), (4, (9.0, 16.0, 35.0, 60.0, 85.0))):
        lens = _finer(cam, k)
        synth = FrameSynthesizer(lens, s.imaging, MESH)
        rect = Renderer(lens.rectified(), MESH)
        bg = np.full((synth.render_camera.height, synth.render_camera.width, 3), 128, np.uint8)
        m1, m2 = lens.undistortion_maps()
        for i in [int(np.argmin(np.abs(r - d))) for d in distances]:
            raw, alpha = synth.frame(bg, tr.quat[i], tr.trans[i], np.array([0, -1.0, 0]), np.zeros(2), None)
            drawn = cv2.remap(alpha, m1, m2, cv2.INTER_LINEAR) > 0.5
            sil = rect.silhouette_full(tr.quat[i], tr.trans[i])
            assert sil.sum() >= 200, (i, r[i], k)  # enough pixels for IoU to judge the geometry
            iou = np.sum(drawn & sil) / np.sum(drawn | sil)
            assert iou >= 0.9, (i, r[i], k, iou)
            # the raw frame really is distorted: the undistorted silhouette differs from the raw one
            assert np.any((alpha > 0.5) != drawn)


def test_every_ground_truth_pose_covers_the_drawn_uav(setup):
    """Along a whole approach (every 4th frame, native resolution): what is drawn, once
    undistorted, lies inside the ROI of the model projected at the true pose (grown by 1 px for
    the resampling), and the drawn area matches the projected silhouette's."""
    from uav_landing_vision.detection.dataset import model_roi

    s, cam, synth, rect = setup
    tr = make_trajectory(s, generators(3))
    bg = np.full((synth.render_camera.height, synth.render_camera.width, 3), 128, np.uint8)
    m1, m2 = cam.undistortion_maps()
    lens = cam.rectified()
    for i in range(0, len(tr), 4):
        _, alpha = synth.frame(bg, tr.quat[i], tr.trans[i], np.array([0, -1.0, 0]), np.zeros(2), None)
        drawn = cv2.remap(alpha, m1, m2, cv2.INTER_LINEAR)
        x0, y0, x1, y1 = model_roi(MESH.vertices, lens.K, tr.quat[i], tr.trans[i], lens.width, lens.height)
        inside = drawn[max(int(y0) - 1, 0):int(np.ceil(y1)) + 1, max(int(x0) - 1, 0):int(np.ceil(x1)) + 1].sum()
        assert inside >= 0.99 * drawn.sum(), (i, inside, drawn.sum())
        # abs: a far UAV's silhouette, sampled at pixel centres, misses most of its sub-pixel
        # wings (at 71 m 12 px against a coverage of 20 px, which 4x finer sampling confirms)
        assert drawn.sum() == pytest.approx(rect.silhouette_full(tr.quat[i], tr.trans[i]).sum(), rel=0.35, abs=10)


def test_bag_roundtrip_and_determinism(tmp_path):
    s = load_scenario("normal")
    s = dataclasses.replace(s, approach=dataclasses.replace(s.approach, start_range_m=(12.0, 14.0)))
    hashes = []
    for run in ("a", "b"):
        res = simulate(s, tmp_path / run, seed=4, frames=5, png_dir=tmp_path / f"{run}_png", progress=False, mesh=MESH)
        assert res.frames == 5
        hashes.append([hashlib.sha256(img.tobytes()).hexdigest() for _, img in iter_frames(tmp_path / run)])
    assert hashes[0] == hashes[1] and len(set(hashes[0])) == 5
    frames = list(iter_frames(tmp_path / "a"))
    truth = read_poses(tmp_path / "a")
    assert [st for st, _ in frames] == truth.stamps_ns.tolist()
    assert np.all(np.diff(truth.stamps_ns) == 34_000_000)
    assert frames[0][1].shape == (720, 1280, 3)
    cam = read_camera(tmp_path / "a")
    assert np.allclose(cam.K, scenario_camera(s).K) and np.allclose(cam.dist, scenario_camera(s).dist)
    csv_truth = read_poses(tmp_path / "a_png")
    assert np.array_equal(csv_truth.stamps_ns, truth.stamps_ns) and np.allclose(csv_truth.trans, truth.trans)
    png = cv2.cvtColor(cv2.imread(str(tmp_path / "a_png" / f"{truth.stamps_ns[0]}.png")), cv2.COLOR_BGR2RGB)
    assert np.array_equal(png, frames[0][1])
    other = simulate(s, tmp_path / "c", seed=5, frames=2, progress=False, mesh=MESH)
    assert other.frames == 2
    assert hashlib.sha256(next(iter_frames(tmp_path / "c"))[1].tobytes()).hexdigest() != hashes[0][0]


def test_a_frame_that_cannot_be_written_as_png_stops_the_run_and_leaves_no_folder(tmp_path, monkeypatch):
    """cv2.imwrite returns False (a full disk) instead of raising: the frame was lost, its truth row kept."""
    s = load_scenario("normal")
    s = dataclasses.replace(s, approach=dataclasses.replace(s.approach, start_range_m=(12.0, 14.0)))
    monkeypatch.setattr(sim_bag.cv2, "imwrite", lambda *args: False)
    with pytest.raises(OSError, match=r"cannot write the image .*\.png"):
        simulate(s, tmp_path / "bag", seed=4, frames=2, png_dir=tmp_path / "png", progress=False, mesh=MESH)
    assert not (tmp_path / "png").exists() and not (tmp_path / "bag").exists()


def test_video_background_loops_and_fills(tmp_path, setup):
    _, cam, _, _ = setup
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (160, 120))
    for k in range(3):
        writer.write(np.full((120, 160, 3), 60 * (k + 1), np.uint8))
    writer.release()
    bg = VideoBackground(cam, str(path))
    levels = [int(np.median(bg.frame(i, 0.0))) for i in range(5)]
    assert bg.frame(0, 0.0).shape == (cam.height, cam.width, 3)
    assert levels[3] == levels[0] and levels[4] == levels[1] and levels[0] != levels[1]
    with pytest.raises(BackgroundError, match="not found"):
        VideoBackground(cam, str(tmp_path / "missing.mp4"))


def test_motion_blur_kernel():
    """A smear of L px (L even) along a row, a column or a diagonal spreads each point evenly over
    the L + 1 pixel centres it passes, centred on the kernel's middle."""
    assert motion_blur_kernel(np.array([0.3, 0.2])) is None  # under a pixel: no blur
    expected = np.zeros((7, 7))
    expected[3, :] = 1 / 7  # 6 px to the right (or left): the whole middle row
    np.testing.assert_allclose(motion_blur_kernel(np.array([6.0, 0.0])), expected, atol=1e-7)
    np.testing.assert_allclose(motion_blur_kernel(np.array([-6.0, 0.0])), expected, atol=1e-7)
    expected = np.zeros((9, 9))
    expected[:, 4] = 1 / 9  # 8 px up: the whole middle column
    np.testing.assert_allclose(motion_blur_kernel(np.array([0.0, -8.0])), expected, atol=1e-7)
    diagonal = motion_blur_kernel(np.array([4.0, 4.0]))  # 4 px right and down: 5 pixels of the diagonal
    expected = np.zeros((7, 7))
    expected[np.arange(1, 6), np.arange(1, 6)] = 1 / 5
    np.testing.assert_allclose(diagonal, expected, atol=1e-7)


@pytest.fixture(scope="module")
def small_bag(tmp_path_factory):
    """Two frames of a near approach, as a bag."""
    s = load_scenario("normal")
    s = dataclasses.replace(s, approach=dataclasses.replace(s.approach, start_range_m=(12.0, 14.0)))
    path = tmp_path_factory.mktemp("small") / "bag"
    simulate(s, path, seed=1, frames=2, progress=False, mesh=MESH)
    return path


def _write_bag(path, topics):
    """A bag with a connection per ``(topic, type)`` and no messages."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    writer = Writer(path, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    for topic, msgtype in topics:
        writer.add_connection(topic, msgtype, typestore=get_typestore(Stores.ROS2_JAZZY))
    writer.close()


def test_unreadable_bags_and_topics_are_clear_errors(tmp_path, small_bag):
    with pytest.raises(ValueError, match=r"cannot read /uav/ground_truth of bag .*missing"):
        read_poses(tmp_path / "missing")
    with pytest.raises(ValueError, match=r"topic /camera/image_raw is sensor_msgs/msg/Image, not geometry_msgs"):
        read_poses(small_bag, "/camera/image_raw")
    with pytest.raises(ValueError, match="topic /uav/ground_truth is geometry_msgs/msg/PoseStamped, not sensor_msgs"):
        next(iter_frames(small_bag, "/uav/ground_truth"))
    truncated = tmp_path / "truncated"
    truncated.mkdir()
    for part in small_bag.iterdir():
        data = part.read_bytes()
        (truncated / part.name).write_bytes(data[: len(data) // 2] if part.suffix == ".mcap" else data)
    with pytest.raises(ValueError, match=r"cannot read .* of bag .*truncated"):
        list(iter_frames(truncated))
    _write_bag(tmp_path / "empty", [("/camera/camera_info", "sensor_msgs/msg/CameraInfo")])
    with pytest.raises(ValueError, match="no message on /camera/camera_info"):
        read_camera(tmp_path / "empty")


def _small_sequence(path, compress=False, frames=3):
    """``frames`` frames of stripes with their poses, written by :class:`SequenceWriter`."""
    camera = CameraModel(40, 30, np.array([[36.0, 0.0, 19.6], [0.0, 36.0, 14.8], [0.0, 0.0, 1.0]]), np.zeros(5))
    with SequenceWriter(path, camera, compress=compress) as writer:
        for i in range(frames):
            writer.write(10**9 + i * 34_000_000, np.repeat(np.arange(i, i + 40, dtype=np.uint8), 90).reshape(30, 40, 3),
                         np.array([0.0, 0.0, 20.0 - i]), np.array([0.0, 0.0, 0.0, 1.0]))
    return path


def test_a_compressed_sequence_is_read_back_like_a_plain_one(tmp_path):
    plain, packed = _small_sequence(tmp_path / "plain"), _small_sequence(tmp_path / "packed", compress=True)
    size = {bag: sum(f.stat().st_size for f in bag.glob("*.mcap")) for bag in (plain, packed)}
    assert size[packed] < size[plain] / 2  # zstd chunks
    for (s0, a), (s1, b) in zip(iter_frames(plain), iter_frames(packed), strict=True):
        assert s0 == s1 and np.array_equal(a, b)
    assert np.array_equal(read_poses(packed).trans, read_poses(plain).trans)


def _compressed_recording(path, stamps) -> list[np.ndarray]:
    """A bag of image_transport's compressed frames (PNG of the BGR pixels) only, one per
    ``(sec, nanosec)`` header stamp; the frames as RGB."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    compressed, header = typestore.types["sensor_msgs/msg/CompressedImage"], typestore.types["std_msgs/msg/Header"]
    stamp = typestore.types["builtin_interfaces/msg/Time"]
    frames = [np.random.default_rng(i).integers(0, 256, (30, 40, 3), dtype=np.uint8) for i in range(len(stamps))]
    with Writer(path, version=9) as writer:
        conn = writer.add_connection("/camera/image_raw/compressed", "sensor_msgs/msg/CompressedImage", typestore=typestore)
        for i, (rgb, (sec, nanosec)) in enumerate(zip(frames, stamps)):
            png = cv2.imencode(".png", rgb[..., ::-1])[1].ravel()
            msg = compressed(header=header(stamp=stamp(sec=sec, nanosec=nanosec), frame_id="cam"),
                             format="rgb8; png compressed bgr8", data=png)
            writer.write(conn, (1 + i) * 10**9, typestore.serialize_cdr(msg, conn.msgtype))
    return frames


def test_frames_recorded_compressed_only_are_read_from_their_topic(tmp_path):
    """A recording of image_transport's compressed frames (``/camera/image_raw/compressed``, PNG or
    JPEG of the BGR pixels) is read where ``/camera/image_raw`` is asked for and absent, so
    ``evaluate`` and ``eval-detector`` take it as the graph does."""
    frames = _compressed_recording(tmp_path / "bag", [(1 + i, 0) for i in range(3)])
    read = list(iter_frames(tmp_path / "bag"))
    assert [s for s, _ in read] == [(1 + i) * 10**9 for i in range(3)]
    for (_, image), rgb in zip(read, frames, strict=True):
        np.testing.assert_array_equal(image, rgb)


def test_a_malformed_header_stamp_is_a_clear_error(tmp_path):
    """Read as a time, (1 s, 1.5e9 ns) is 2.5 s, between its neighbours: no order check would notice."""
    _compressed_recording(tmp_path / "bag", [(1, 0), (1, 1_500_000_000), (3, 0)])
    with pytest.raises(ValueError, match=r"header stamp 1 s \+ 1500000000 ns is malformed"):
        list(iter_frames(tmp_path / "bag"))


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_cut_off_compressed_bag_is_a_clear_error(tmp_path, storage):
    """A zstd-compressed file (``ros2 bag record --compression-mode file``) cut off: rosbags lets
    the decompressor's error through, not as its ReaderError."""
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, Reader, StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    writer = Writer(tmp_path / "damaged", version=9, storage_plugin=StoragePlugin[storage.upper()])
    writer.set_compression(CompressionMode.FILE, CompressionFormat.ZSTD)
    with Reader(_small_sequence(tmp_path / "bag", frames=20)) as reader, writer:
        typestore = get_typestore(Stores.ROS2_JAZZY)
        conns = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=typestore) for c in reader.connections}
        for conn, t_ns, raw in reader.messages():
            writer.write(conns[conn.id], t_ns, raw)
    damaged = next((tmp_path / "damaged").glob("*.zstd"))
    damaged.write_bytes(damaged.read_bytes()[: damaged.stat().st_size // 2])
    with pytest.raises(ValueError, match=r"cannot read /camera/image_raw of bag .*damaged: "):
        list(iter_frames(tmp_path / "damaged"))


def test_pose_csv_rows_are_checked(tmp_path):
    header = "stamp_ns,x,y,z,qx,qy,qz,qw\n"
    for body, match in (("1,0,0,0,0,0,0\n", "line 2 has fewer than the 8 columns"),
                        ("1,0,0,0,0,0,0,1\n2,abc,0,0,0,0,0,1\n", "line 3: could not convert string to float: 'abc'"),
                        ("", "needs a header")):
        (tmp_path / "poses.csv").write_text(body if match == "needs a header" else header + body)
        with pytest.raises(ValueError, match=match):
            read_poses(tmp_path / "poses.csv")
    (tmp_path / "poses.csv").write_text(header)  # no pose: the estimates of a run that lost every frame
    none = read_poses(tmp_path / "poses.csv")
    assert none.stamps_ns.shape == (0,) and none.trans.shape == (0, 3) and none.quat.shape == (0, 4)


def test_an_interrupted_simulation_leaves_nothing_to_reuse(tmp_path, monkeypatch):
    """Stopped after one frame, ``simulate`` leaves no bag, PNG folder or staging folder, so
    the demo simulates the landing again instead of taking up a one-frame bag."""
    from uav_landing_vision.demo import simulated_bag
    from uav_landing_vision.sim.bag import SequenceWriter

    write, calls = SequenceWriter.write, []

    def interrupted(self, *args):
        calls.append(args[0])
        if len(calls) % 2 == 0:  # the second frame of each run
            raise KeyboardInterrupt
        write(self, *args)

    monkeypatch.setattr(SequenceWriter, "write", interrupted)
    s = load_scenario("normal")
    with pytest.raises(KeyboardInterrupt):
        simulate(s, tmp_path / "bag", frames=2, png_dir=tmp_path / "png", progress=False, mesh=MESH)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(KeyboardInterrupt):
        simulated_bag(tmp_path / "bags", "normal", 0, 2)
    monkeypatch.setattr(SequenceWriter, "write", write)
    assert len(read_poses(simulated_bag(tmp_path / "bags", "normal", 0, 2)).stamps_ns) == 2


def test_an_existing_png_folder_leaves_no_bag(tmp_path):
    (tmp_path / "png").mkdir()
    with pytest.raises(FileExistsError, match="png"):
        simulate(load_scenario("normal"), tmp_path / "bag", frames=1, png_dir=tmp_path / "png", progress=False,
                 mesh=MESH)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["png"]


def test_stamps_past_the_ros_time_range_are_refused_before_writing(tmp_path):
    s = dataclasses.replace(load_scenario("normal"), start_time_s=2**31 - 0.05)  # valid, but frame 2 is past 2^31 s
    with pytest.raises(ScenarioError, match=r"frame 2 would be stamped 2147483648.018 s, past the ROS time range"):
        simulate(s, tmp_path / "bag", frames=5, progress=False, mesh=MESH)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("options, message", [
    (["--out", "bag", "--video", "clip.mp4"], "--video is for the 'video' background; scenario 'normal' has 'normal'"),
    (["--out", "bag", "--png-dir", "bag"], "--png-dir bag and --out bag must not contain each other"),
    (["--out", "bag", "--png-dir", "bag/png"], "--png-dir bag/png and --out bag must not contain each other"),
    (["--out", "png/bag", "--png-dir", "png"], "--png-dir png and --out png/bag must not contain each other"),
])
def test_simulate_refuses_options_it_cannot_honour(tmp_path, monkeypatch, options, message):
    from uav_landing_vision.cli import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "clip.mp4").write_bytes(b"")
    with pytest.raises(SystemExit, match=f"^uav-landing simulate: {message}"):
        main(["simulate", "--frames", "1", *options])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.mp4"]
