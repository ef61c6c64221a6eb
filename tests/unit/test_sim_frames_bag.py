"""Frame synthesis and bag output: ground truth vs. drawn UAV, rosbags round trip (field by field),
determinism, video; bags of other recorders (padded rows, bgr8, covariance poses, two image topics)."""

import dataclasses
import hashlib

import cv2
import numpy as np
import pytest
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

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
    Poses,
    read_camera,
    read_pose_csv,
    read_poses,
    SequenceWriter,
    scenario_camera,
    simulate,
    write_pose_csv,
)
from uav_landing_vision.sim import bag as sim_bag
from uav_landing_vision.sim.synthesis import FrameSynthesizer, motion_blur_kernel

MESH = fixed_wing_mesh("low")
TS = get_typestore(Stores.ROS2_JAZZY)


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
    """A bag of ``topics``: ``{topic: [(record_ns, message), ...]}``, or ``{topic: "pkg/msg/Type"}``
    for a connection without messages."""
    with Writer(path, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP) as writer:
        for topic, items in topics.items():
            msgtype = items if isinstance(items, str) else items[0][1].__msgtype__
            conn = writer.add_connection(topic, msgtype, typestore=TS)
            for record_ns, msg in [] if isinstance(items, str) else items:
                writer.write(conn, record_ns, TS.serialize_cdr(msg, conn.msgtype))


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
    _write_bag(tmp_path / "empty", {"/camera/camera_info": "sensor_msgs/msg/CameraInfo"})
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


# --- bags read back field by field, and bags of other recorders -----------------------------------

K = np.array([[36.0, 0.0, 19.6], [0.0, 33.0, 14.8], [0.0, 0.0, 1.0]])
FRAME = "deck_camera_optical"


def _frames(n, rng):
    stamps = [1_700_000_000_123_456_789 + i * 34_000_017 for i in range(n)]
    images = [rng.integers(0, 256, (30, 40, 3), dtype=np.uint8) for _ in range(n)]
    trans = rng.uniform(-20, 20, (n, 3))
    quat = rng.normal(size=(n, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    return stamps, images, trans, quat


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """A 4-frame sequence with distinct quaternion components and a distorted camera."""
    folder = tmp_path_factory.mktemp("seq")
    rng = np.random.default_rng(93)
    camera = CameraModel(40, 30, K, np.array([-0.1, 0.02, 0.001, -0.002, 0.003]), FRAME)
    stamps, images, trans, quat = _frames(4, rng)
    with SequenceWriter(folder / "bag", camera, png_dir=folder / "png") as writer:
        for s, img, t, q in zip(stamps, images, trans, quat):
            writer.write(s, img, t, q)
    return folder, camera, stamps, images, trans, quat


def _raw_messages(bag):
    with Reader(bag) as reader:
        return [(conn.topic, t, TS.deserialize_cdr(raw, conn.msgtype)) for conn, t, raw in reader.messages()]


def test_written_messages_carry_the_frame_stamp_frame_id_and_pose_fields(written):
    folder, camera, stamps, images, trans, quat = written
    msgs = _raw_messages(folder / "bag")
    assert len(msgs) == 3 * len(stamps)
    by_topic = {}
    for topic, record_ns, msg in msgs:
        by_topic.setdefault(topic, []).append((record_ns, msg))
    assert set(by_topic) == {sim_bag.IMAGE_TOPIC, sim_bag.INFO_TOPIC, sim_bag.TRUTH_TOPIC}
    for topic, items in by_topic.items():
        for (record_ns, msg), s in zip(items, stamps, strict=True):
            assert record_ns == s  # the bag's record time is the header stamp
            assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == divmod(s, 10**9)
            assert msg.header.frame_id == FRAME
    for (_, img_msg), img in zip(by_topic[sim_bag.IMAGE_TOPIC], images):
        assert (img_msg.encoding, img_msg.height, img_msg.width, img_msg.step) == ("rgb8", 30, 40, 120)
        np.testing.assert_array_equal(np.asarray(img_msg.data).reshape(30, 40, 3), img)
    for (_, truth), t, q in zip(by_topic[sim_bag.TRUTH_TOPIC], trans, quat):
        p, o = truth.pose.position, truth.pose.orientation
        assert [p.x, p.y, p.z] == t.tolist()
        assert [o.x, o.y, o.z, o.w] == q.tolist()  # geometry_msgs order x, y, z, w
    info = by_topic[sim_bag.INFO_TOPIC][0][1]
    assert info.distortion_model == "plumb_bob"
    np.testing.assert_array_equal(info.d, camera.dist)
    np.testing.assert_array_equal(info.k, K.ravel())
    np.testing.assert_array_equal(info.p, np.hstack([K, np.zeros((3, 1))]).ravel())


def test_ground_truth_quaternions_and_positions_read_back_in_x_y_z_w_order(written):
    folder, _, stamps, _, trans, quat = written
    for source in (folder / "bag", folder / "png"):
        poses = read_poses(source)
        assert poses.stamps_ns.tolist() == stamps
        np.testing.assert_array_equal(poses.trans, trans)
        np.testing.assert_array_equal(poses.quat, quat)


def test_read_camera_keeps_the_recorded_frame_id(written):
    folder, camera, *_ = written
    read = read_camera(folder / "bag")
    assert read.frame_id == FRAME
    np.testing.assert_array_equal(read.K, camera.K)
    np.testing.assert_array_equal(read.dist, camera.dist)


def test_a_fisheye_camera_is_recorded_with_its_distortion_model(tmp_path):
    camera = CameraModel(40, 30, K, np.array([0.01, -0.002, 0.0003, 0.0001]), FRAME, "equidistant")
    with sim_bag.SequenceWriter(tmp_path / "bag", camera) as writer:
        writer.write(10**9, np.zeros((30, 40, 3), np.uint8), np.zeros(3), np.array([0, 0, 0, 1.0]))
    read = read_camera(tmp_path / "bag")
    assert read.distortion_model == "equidistant"
    np.testing.assert_array_equal(read.dist, camera.dist)


def test_pose_csv_round_trip_keeps_quaternion_order(tmp_path):
    rng = np.random.default_rng(5)
    quat = rng.normal(size=(3, 4))
    poses = Poses(np.array([-5, 0, 2**62], np.int64), rng.normal(size=(3, 3)), quat)
    write_pose_csv(tmp_path / "p.csv", poses)
    header = (tmp_path / "p.csv").read_text().splitlines()[0]
    assert header == "stamp_ns,x,y,z,qx,qy,qz,qw"
    back = read_pose_csv(tmp_path / "p.csv")
    np.testing.assert_array_equal(back.stamps_ns, poses.stamps_ns)
    np.testing.assert_array_equal(back.trans, poses.trans)
    np.testing.assert_array_equal(back.quat, poses.quat)


def test_pose_csv_columns_are_read_by_name(tmp_path):
    (tmp_path / "p.csv").write_text("qw,stamp_ns,x,y,z,qx,qy,qz,extra\n0.9,7,1,2,3,0.1,0.2,0.3,x\n")
    poses = read_pose_csv(tmp_path / "p.csv")
    assert poses.stamps_ns.tolist() == [7]
    assert poses.trans.tolist() == [[1.0, 2.0, 3.0]] and poses.quat.tolist() == [[0.1, 0.2, 0.3, 0.9]]


@pytest.mark.parametrize("stamp", [2**63, -(2**63) - 1])
def test_pose_csv_stamps_beyond_64_bits_are_value_errors(tmp_path, stamp):
    (tmp_path / "p.csv").write_text(f"stamp_ns,x,y,z,qx,qy,qz,qw\n{stamp},0,0,0,0,0,0,1\n")
    with pytest.raises(ValueError, match="line 2: stamp_ns .* does not fit 64 bits"):
        read_pose_csv(tmp_path / "p.csv")


def test_recorded_topics_map_played_names_back_to_recorded_ones():
    remaps = {"/front/image": sim_bag.IMAGE_TOPIC, "/gt": sim_bag.TRUTH_TOPIC}
    assert sim_bag.recorded_topics(remaps) == ("/front/image", sim_bag.INFO_TOPIC, "/gt")
    assert sim_bag.recorded_topics() == (sim_bag.IMAGE_TOPIC, sim_bag.INFO_TOPIC, sim_bag.TRUTH_TOPIC)


def _image_msg(stamp_ns, rgb, encoding="rgb8", pad=0):
    m = TS.types
    sec, nanosec = divmod(stamp_ns, 10**9)
    header = m["std_msgs/msg/Header"](stamp=m["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id="c")
    h, w = rgb.shape[:2]
    pixels = rgb[..., ::-1] if encoding == "bgr8" else rgb
    rows = np.concatenate([pixels.reshape(h, 3 * w), np.full((h, pad), 77, np.uint8)], axis=1)
    return m["sensor_msgs/msg/Image"](header=header, height=h, width=w, encoding=encoding, is_bigendian=0,
                                      step=3 * w + pad, data=np.ascontiguousarray(rows).reshape(-1))


@pytest.mark.parametrize("encoding, pad", [("rgb8", 8), ("bgr8", 0), ("bgr8", 4)])
def test_frames_with_padded_rows_or_bgr8_are_read_as_rgb(tmp_path, encoding, pad):
    rng = np.random.default_rng(1)
    images = [rng.integers(0, 256, (5, 7, 3), dtype=np.uint8) for _ in range(2)]
    _write_bag(tmp_path / "bag", {sim_bag.IMAGE_TOPIC: [(10**9 * (i + 1), _image_msg(10**9 * (i + 1), img, encoding, pad))
                                                     for i, img in enumerate(images)]})
    read = list(sim_bag.iter_frames(tmp_path / "bag"))
    assert [s for s, _ in read] == [10**9, 2 * 10**9]
    for (_, got), img in zip(read, images, strict=True):
        np.testing.assert_array_equal(got, img)


def _two_camera_bag(path, count: int, seed: int):
    """A bag of ``count`` random frames on /left/image_raw and, 1 µs after each, on /right/image_raw."""
    rng = np.random.default_rng(seed)
    left = [(10**9 * (i + 1), _image_msg(10**9 * (i + 1), rng.integers(0, 256, (4, 6, 3), dtype=np.uint8)))
            for i in range(count)]
    right = [(s + 1000, _image_msg(s + 1000, rng.integers(0, 256, (4, 6, 3), dtype=np.uint8))) for s, _ in left]
    _write_bag(path, {"/left/image_raw": left, "/right/image_raw": right})
    return left, right


def test_frames_of_the_first_image_topic_only_when_no_topic_is_named(tmp_path):
    left, right = _two_camera_bag(tmp_path / "bag", 3, seed=2)
    frames = list(sim_bag.iter_frames(tmp_path / "bag", ""))
    assert len(frames) == 3
    stamps = [s for s, _ in frames]
    assert stamps in ([s for s, _ in left], [s for s, _ in right])


def test_a_frame_recorded_twice_with_one_stamp_is_refused(tmp_path):
    rgb = np.zeros((4, 6, 3), np.uint8)
    twice = [(10**9, _image_msg(10**9, rgb)), (10**9 + 1, _image_msg(10**9, rgb))]  # record times differ, stamps not
    _write_bag(tmp_path / "bag", {sim_bag.IMAGE_TOPIC: twice})
    with pytest.raises(ValueError, match="frame 1 is stamped 1000000000 ns, not after frame 0"):
        list(sim_bag.increasing_frames(tmp_path / "bag"))


def test_poses_with_covariance_are_read(tmp_path):
    m = TS.types
    rng = np.random.default_rng(4)
    items, expected = [], []
    for i in range(3):
        t, q = rng.normal(size=3), rng.normal(size=4)
        header = m["std_msgs/msg/Header"](stamp=m["builtin_interfaces/msg/Time"](sec=5 + i, nanosec=i), frame_id="c")
        position = m["geometry_msgs/msg/Point"](x=t[0], y=t[1], z=t[2])
        orientation = m["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])
        pose = m["geometry_msgs/msg/Pose"](position=position, orientation=orientation)
        msg = m["geometry_msgs/msg/PoseWithCovarianceStamped"](
            header=header, pose=m["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.eye(6).ravel()))
        items.append(((5 + i) * 10**9 + i, msg))
        expected.append((t, q))
    _write_bag(tmp_path / "bag", {"/uav/pose": items})
    poses = read_poses(tmp_path / "bag", "/uav/pose")
    assert poses.stamps_ns.tolist() == [s for s, _ in items]
    np.testing.assert_array_equal(poses.trans, [t for t, _ in expected])
    np.testing.assert_array_equal(poses.quat, [q for _, q in expected])


def _small_lens(scenario, folder):
    """``scenario`` with a 160×120 camera (a distorted one), whose background and maps are quick to make."""
    from uav_landing_vision.camera import save_camera_info_yaml

    lens = CameraModel(160, 120, np.array([[150.0, 0.0, 80.0], [0.0, 150.0, 60.0], [0.0, 0.0, 1.0]]),
                       np.array([-0.1, 0.02, 0.0, 0.0, 0.0]), FRAME)
    save_camera_info_yaml(lens, folder / "lens.yaml")
    return dataclasses.replace(scenario, camera_info=str(folder / "lens.yaml"))


def _blank_frames(monkeypatch):
    """Make FrameSynthesizer.frame return a black frame (no rendering)."""
    def blank(self, background, quat, trans, light_dir, blur_shift_px, rng):
        return np.zeros((self.camera.height, self.camera.width, 3), np.uint8), None

    monkeypatch.setattr(FrameSynthesizer, "frame", blank)


def test_the_bag_holds_the_trajectorys_poses_and_the_background_each_frames_time_and_camera(tmp_path, monkeypatch):
    import importlib

    sim_simulate = importlib.import_module("uav_landing_vision.sim.simulate")
    _blank_frames(monkeypatch)
    seen, make = [], sim_simulate.make_background

    def recording(*args, **kwargs):
        background = make(*args, **kwargs)
        frame = background.frame
        background.frame = lambda i, t, rot, pos: seen.append((i, t, rot, pos)) or frame(i, t, rot, pos)
        return background

    monkeypatch.setattr(sim_simulate, "make_background", recording)
    s = _small_lens(load_scenario("normal"), tmp_path)
    s = dataclasses.replace(s, approach=dataclasses.replace(s.approach, start_range_m=(12.0, 14.0)))
    simulate(s, tmp_path / "bag", seed=4, frames=4, progress=False, mesh=MESH)
    tr = make_trajectory(s, generators(4)).head(4)
    truth = read_poses(tmp_path / "bag")
    assert truth.stamps_ns.tolist() == [1_700_000_000 * 10**9 + k * 34_000_000 for k in range(4)]
    np.testing.assert_array_equal(truth.trans, tr.trans)
    np.testing.assert_array_equal(truth.quat, tr.quat)
    assert [i for i, *_ in seen] == [0, 1, 2, 3]
    for (_, t, rot, pos), k in zip(seen, range(4), strict=True):
        assert t == tr.times_s[k]
        np.testing.assert_array_equal(rot, tr.cam_rot[k])
        np.testing.assert_array_equal(pos, tr.cam_pos[k])


def test_stamps_are_whole_steps_of_dt_in_ns():
    from uav_landing_vision.sim.simulate import stamps_ns

    s = dataclasses.replace(load_scenario("normal"), start_time_s=1_600_000_000.0, dt_s=0.3)
    stamps = stamps_ns(s, np.arange(40) * s.dt_s)  # 3 × 0.3 is 0.8999999999999999
    assert stamps.tolist() == [1_600_000_000 * 10**9 + k * 300_000_000 for k in range(40)]


def test_a_frame_stamped_exactly_at_2_31_s_is_refused(tmp_path):
    s = dataclasses.replace(load_scenario("normal"), start_time_s=2**31 - 1, dt_s=0.5)
    with pytest.raises(ScenarioError, match=r"frame 2 would be stamped 2147483648.000 s"):
        simulate(s, tmp_path / "bag", frames=3, progress=False, mesh=MESH)
    assert list(tmp_path.iterdir()) == []


def test_a_staging_folder_left_by_a_killed_run_is_replaced_and_none_is_left(tmp_path, monkeypatch):
    _blank_frames(monkeypatch)
    (tmp_path / "bag.partial" / "bag").mkdir(parents=True)
    (tmp_path / "bag.partial" / "bag" / "stale.mcap").write_bytes(b"x")
    s = _small_lens(load_scenario("normal"), tmp_path)
    simulate(s, tmp_path / "bag", frames=2, png_dir=tmp_path / "png", progress=False, mesh=MESH)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag", "lens.yaml", "png"]
    assert not (tmp_path / "bag" / "stale.mcap").exists() and len(read_poses(tmp_path / "bag").stamps_ns) == 2


def test_every_frame_of_a_sequence_can_be_asked_for_and_no_more(tmp_path, monkeypatch):
    _blank_frames(monkeypatch)
    s = _small_lens(load_scenario("single_frame"), tmp_path)
    few = dataclasses.replace(s.single_frame, distances_m=(5.0, 9.0), poses_per_distance=2)
    s = dataclasses.replace(s, single_frame=few)
    assert simulate(s, tmp_path / "bag", frames=4, progress=False, mesh=MESH).frames == 4
    with pytest.raises(ScenarioError, match="has 4 frames; --frames 5 is too many"):
        simulate(s, tmp_path / "other", frames=5, progress=False, mesh=MESH)


def test_the_png_folder_is_complete_once_the_writer_is_closed(tmp_path):
    """Read back while the writer object still exists: the CSV has every row, and the folder's
    camera_info.yaml is the camera."""
    from uav_landing_vision.camera import load_camera_info_yaml

    stamps, images, trans, quat = _frames(3, np.random.default_rng(6))
    camera = CameraModel(40, 30, K, np.array([-0.1, 0.02, 0.001, -0.002, 0.003]), FRAME)
    writer = SequenceWriter(tmp_path / "bag", camera, png_dir=tmp_path / "png")
    for s, img, t, q in zip(stamps, images, trans, quat):
        writer.write(s, img, t, q)
    writer.close()
    poses = read_poses(tmp_path / "png")
    assert poses.stamps_ns.tolist() == stamps
    np.testing.assert_array_equal(poses.quat, quat)
    read = load_camera_info_yaml(tmp_path / "png" / "camera_info.yaml")
    np.testing.assert_array_equal(read.K, K)
    np.testing.assert_array_equal(read.dist, camera.dist)


def test_a_png_folder_that_exists_is_refused_before_the_bag_is_made(tmp_path):
    (tmp_path / "png").mkdir()
    camera = CameraModel(40, 30, K, np.zeros(5), FRAME)
    with pytest.raises(FileExistsError):
        SequenceWriter(tmp_path / "bag", camera, png_dir=tmp_path / "png")
    assert not (tmp_path / "bag").exists() and list((tmp_path / "png").iterdir()) == []


def test_mono8_frames_are_read_as_grey_rgb(tmp_path):
    grey = np.random.default_rng(3).integers(0, 256, (5, 7), dtype=np.uint8)
    m = TS.types
    header = m["std_msgs/msg/Header"](stamp=m["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id="c")
    msg = m["sensor_msgs/msg/Image"](header=header, height=5, width=7, encoding="mono8", is_bigendian=0, step=9,
                                     data=np.concatenate([grey, np.zeros((5, 2), np.uint8)], axis=1).reshape(-1))
    _write_bag(tmp_path / "bag", {sim_bag.IMAGE_TOPIC: [(10**9, msg)]})
    (_, image), = sim_bag.iter_frames(tmp_path / "bag")
    np.testing.assert_array_equal(image, np.repeat(grey[..., None], 3, axis=2))


def test_compressed_grey_frames_are_read_as_grey_rgb(tmp_path):
    grey = np.random.default_rng(4).integers(0, 256, (6, 8), dtype=np.uint8)
    m = TS.types
    header = m["std_msgs/msg/Header"](stamp=m["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id="c")
    msg = m["sensor_msgs/msg/CompressedImage"](header=header, format="mono8; png compressed mono8",
                                               data=cv2.imencode(".png", grey)[1].ravel())
    _write_bag(tmp_path / "bag", {sim_bag.COMPRESSED_IMAGE_TOPIC: [(10**9, msg)]})
    (_, image), = sim_bag.iter_frames(tmp_path / "bag")
    np.testing.assert_array_equal(image, np.repeat(grey[..., None], 3, axis=2))


def test_a_named_image_topic_is_read_even_after_another_image_topic(tmp_path):
    _, right = _two_camera_bag(tmp_path / "bag", 2, seed=7)
    assert [s for s, _ in sim_bag.iter_frames(tmp_path / "bag", "/right/image_raw")] == [s for s, _ in right]


def test_a_bag_of_compressed_frames_only_has_no_ground_truth(tmp_path):
    _compressed_recording(tmp_path / "bag", [(1, 0)])
    with pytest.raises(ValueError, match=r"no topic /uav/ground_truth; has \['/camera/image_raw/compressed"):
        read_poses(tmp_path / "bag")


def test_a_message_that_does_not_deserialise_is_a_value_error_naming_the_topic(tmp_path):
    with Writer(tmp_path / "bag", version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection(sim_bag.TRUTH_TOPIC, "geometry_msgs/msg/PoseStamped", typestore=TS)
        writer.write(conn, 10**9, b"\x00\x01\x00\x00\x05")
    with pytest.raises(ValueError, match=r"cannot read /uav/ground_truth of bag .*Could not deserialize"):
        read_poses(tmp_path / "bag")


def _info_msg(camera, frame_id):
    m = TS.types
    header = m["std_msgs/msg/Header"](stamp=m["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id=frame_id)
    roi = m["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    P = np.hstack([camera.K, np.zeros((3, 1))])
    return m["sensor_msgs/msg/CameraInfo"](header=header, height=camera.height, width=camera.width,
                                           distortion_model="plumb_bob", d=camera.dist.astype(float),
                                           k=camera.K.ravel(), r=np.eye(3).ravel(), p=P.ravel(), binning_x=0,
                                           binning_y=0, roi=roi)


def test_read_camera_takes_the_first_message_and_a_default_frame_id_for_none(tmp_path):
    from uav_landing_vision.camera import DEFAULT_FRAME_ID

    first = CameraModel(40, 30, K, np.zeros(5), FRAME)
    later = CameraModel(40, 30, K * [[2.0], [2.0], [1.0]], np.zeros(5), FRAME)
    infos = [(10**9, _info_msg(first, "")), (2 * 10**9, _info_msg(later, "x"))]
    _write_bag(tmp_path / "bag", {sim_bag.INFO_TOPIC: infos})
    read = read_camera(tmp_path / "bag")
    np.testing.assert_array_equal(read.K, K)
    assert read.frame_id == DEFAULT_FRAME_ID


def test_pose_csv_reads_the_extreme_64_bit_stamps(tmp_path):
    rows = f"{-(2**63)},0,0,0,0,0,0,1\n{2**63 - 1},0,0,0,0,0,0,1\n"
    (tmp_path / "p.csv").write_text("stamp_ns,x,y,z,qx,qy,qz,qw\n" + rows)
    assert read_pose_csv(tmp_path / "p.csv").stamps_ns.tolist() == [-(2**63), 2**63 - 1]


def test_frames_read_back_can_be_drawn_on(tmp_path):
    """An rgb8 frame is a writable array of its own, not a view of the message's bytes."""
    for _, image in iter_frames(_small_sequence(tmp_path / "bag", frames=2)):
        image[0, 0] = (255, 0, 0)  # raises for a read-only view
        assert image[0, 0].tolist() == [255, 0, 0]
