"""Scenario loading and ground-truth trajectories: cone, speeds, attitude, ship motion, determinism."""

from dataclasses import replace

import numpy as np
import pytest

from uav_landing_vision.camera import CameraModel, save_camera_info_yaml
from uav_landing_vision.geometry import matrix_to_euler_zyx, quat_to_matrix
from uav_landing_vision.sim import ScenarioError, generators, load_scenario, make_trajectory
from uav_landing_vision.sim.config import ApproachConfig, ImagingConfig, ShipConfig, SingleFrameConfig, validate
from uav_landing_vision.sim.simulate import scenario_camera
from uav_landing_vision.sim.trajectory import SmoothSignal, camera_mount

SHIPPED = ("normal", "complex", "video", "single_frame")


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_scenarios_load(name):
    s = load_scenario(name)
    assert s.name == name


@pytest.mark.parametrize("text, match", [
    ("approach: {}\nbogus: 1\n", "bogus"),
    ("approach: {alpha1_deg: 2.0, alpha2_deg: 5.0}\n", "alpha2_deg < alpha1_deg"),
    ("approach: {start_range_m: [80]}\n", "expected 2 values"),
    ("approach: {}\nbackground: {kind: fog}\n", "background.kind"),
    ("seed: 0\n", "exactly one of"),
    ("approach: {}\nship: {roll_deg: lots}\n", "roll_deg"),
    ("approach:\n  alpha1_deg: 10.0\n  alpha1_deg: 50.0\n", "duplicate key 'alpha1_deg' on line 3"),
    ("approach: {}\n1: 2\nfoo: 3\n", r"unknown key\(s\) \['1', 'foo'\]"),
    ("approach: {}\nseed: -1\n", "seed must be non-negative"),
    ("approach: {}\nstart_time_s: -5.0\n", "start_time_s must be in"),
    ("approach: {}\nbackground: {sun_azimuth_deg: .inf}\n", "background.sun_azimuth_deg: expected a finite number"),
    ("approach: {}\nbackground: {sun_elevation_deg: .nan}\n", "background.sun_elevation_deg: expected a finite number"),
    ("approach: {speed_jitter_mps: 1.75}\n", "speed_jitter_mps must be under a quarter of the closing speed"),
    ("approach: {cone_start_m: 0}\n", "approach.cone_start_m must be positive"),
    ("approach: {cone_start_m: -10}\n", "approach.cone_start_m must be positive"),
    ("approach: {disturbance_range_m: 0}\n", "approach.disturbance_range_m must be positive"),
    ("approach: {roll_far_deg: -15}\n", "approach.roll_far_deg must be non-negative"),
    ("approach: {yaw_near_deg: -1}\n", "approach.yaw_near_deg must be non-negative"),
    ("approach: {}\nship: {heave_m: -0.3}\n", "ship.heave_m must be non-negative"),
    ("approach: {}\nship: {pitch_deg: -1}\n", "ship.pitch_deg must be non-negative"),
    ("approach: {}\nbackground: {sea_jitter_m: -0.1}\n", "background.sea_jitter_m must be non-negative"),
    ("approach: {start_range_m: [20, 30]}\nship: {camera_position_m: [50, 0, 0.5]}\n",
     r"approach.start_range_m must start beyond the net \(50.0 m from the camera\)"),
    ("approach: {}\nship: {camera_position_m: [5, 0, -3]}\n", "the camera must be above the waterline"),
    ("dt_s: 1.0e-7\napproach: {}\n", "dt_s must be at least 1e-06 s"),
    ("approach: {}\nbackground: {sun_elevation_deg: -5}\n", r"sun_elevation_deg must be in \[0, 90\] \(above the horizon\), got -5"),
    ("approach: {}\nbackground: {sun_elevation_deg: 200}\n", r"sun_elevation_deg must be in \[0, 90\]"),
    ("single_frame: {distances_m: [5, 10], poses_per_distance: 100000000}\n",
     "single_frame: 2 distances × 100000000 poses is over 1000000 frames"),
    # Each range and ordering check on its own.
    ("approach: {}\nsingle_frame: {}\n", "exactly one of"),
    ("approach: {}\nstart_time_s: 3000000000\n", "start_time_s must be in"),
    ("approach: {alpha1_deg: 5, alpha2_deg: 5}\n", "alpha2_deg < alpha1_deg"),
    ("approach: {beta2_deg: 120}\n", "beta2_deg must be in"),
    ("approach: {start_range_m: [100, 80]}\n", "start_range_m must be"),
    ("approach: {disturbance_band_hz: [0.8, 0.1]}\n", "disturbance_band_hz"),
    ("single_frame: {distances_m: [0, 5]}\n", "distances_m must be positive"),
    ("single_frame: {poses_per_distance: 0}\n", "poses_per_distance must be at least 1"),
    ("single_frame: {angle_limit_deg: 270}\n", "angle_limit_deg must be in"),
    ("approach: {}\nship: {wave_period_s: [10, 5]}\n", "wave_period_s"),
    ("approach: {}\nimaging: {albedo: [1.5, 0.8, 0.8]}\n", "albedo"),
    ("approach: {}\nimaging: {samples: 0}\n", "samples"),
    ("approach: {}\nship: {net_height_m: 0.0, camera_position_m: [5, 0, 0.5]}\n", "net_height_m must be positive"),
    ("approach: {}\nstart_time_s: 2147483648\n", "start_time_s must be in"),
    ("approach: {start_range_m: [10, 20]}\n", "start_range_m must be"),
    ("approach: {start_range_m: [20, 40]}\nship: {camera_position_m: [0, 0, 30]}\n",
     r"start_range_m must start beyond the net \(30.0 m from the camera\)"),
    ("approach: {start_range_m: [30, 40]}\nship: {camera_position_m: [30, 0, 0]}\n", "must start beyond the net"),
    ("approach: {}\nship: {net_height_m: 2.0, camera_position_m: [5, 0, -2]}\n",
     "the camera must be above the waterline"),
    ("approach: {alpha2_deg: 0}\n", "0 < alpha2_deg < alpha1_deg < 45"),
    ("approach: {alpha1_deg: 45}\n", "0 < alpha2_deg < alpha1_deg < 45"),
    ("approach: {beta2_deg: 0}\n", "beta2_deg must be in"),
    ("approach: {beta2_deg: 90}\n", "beta2_deg must be in"),
    ("approach: {roll_near_deg: -1}\n", "approach.roll_near_deg must be non-negative"),
    ("approach: {pitch_far_deg: -1}\n", "approach.pitch_far_deg must be non-negative"),
    ("approach: {pitch_near_deg: -1}\n", "approach.pitch_near_deg must be non-negative"),
    ("approach: {yaw_far_deg: -1}\n", "approach.yaw_far_deg must be non-negative"),
    ("approach: {}\nship: {roll_deg: -1}\n", "ship.roll_deg must be non-negative"),
    ("approach: {}\nship: {yaw_deg: -1}\n", "ship.yaw_deg must be non-negative"),
    ("approach: {airspeed_mps: 8.0}\nship: {speed_mps: 8.0}\n", "airspeed_mps must exceed ship.speed_mps"),
    ("approach: {disturbance_band_hz: [0, 0.5]}\n", "disturbance_band_hz"),
    ("approach: {disturbance_band_hz: [0.5, 0.5]}\n", "disturbance_band_hz"),
    ("approach: {path_wander_deg: -1}\n", "wander/jitter must be non-negative"),
    ("approach: {speed_jitter_mps: -0.1}\n", "wander/jitter must be non-negative"),
    ("single_frame: {distances_m: []}\n", "distances_m must be positive"),
    ("single_frame: {angle_limit_deg: 0}\n", "angle_limit_deg must be in"),
    ("approach: {}\nship: {wave_period_s: [0, 5]}\n", "wave_period_s"),
    ("approach: {}\nimaging: {noise_sigma: -1}\n", "non-negative noise/blur"),
    ("approach: {}\nimaging: {exposure_fraction: -0.1}\n", "non-negative noise/blur"),
    ("approach: {}\nimaging: {max_blur_px: -1}\n", "non-negative noise/blur"),
])
def test_bad_scenarios_are_clear_errors(tmp_path, text, match):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ScenarioError, match=match):
        load_scenario(path)


@pytest.mark.parametrize("changes, match", [
    (dict(dt_s=100.0), "dt_s = 100.0 s leaves fewer than 2 frames"),
    (dict(ship=dict(speed_mps=14.999), approach=dict(speed_jitter_mps=0.0)), "may take up to 2[0-9]{6} frames"),
])
def test_approaches_too_short_or_too_long_are_clear_errors(changes, match):
    s = load_scenario("normal")
    s = validate(replace(s, **{k: replace(getattr(s, k), **v) if isinstance(v, dict) else v
                               for k, v in changes.items()}))
    with pytest.raises(ScenarioError, match=match):
        make_trajectory(s, generators(0))


def test_an_empty_section_takes_the_defaults(tmp_path):
    """``approach:`` with every key commented out is an empty section (YAML null), as normal.yaml says."""
    path = tmp_path / "empty_sections.yaml"
    path.write_text("approach:\n  # start_range_m: [80.0, 100.0]\nship:\nimaging:\n")
    s = load_scenario(path)
    assert s.approach == ApproachConfig() and s.ship == ShipConfig() and s.imaging == ImagingConfig()
    assert s.single_frame is None


def test_a_scenario_that_is_not_text_is_a_clear_error(tmp_path):
    path = tmp_path / "latin1.yaml"
    path.write_bytes("approach: {}  # caméra\n".encode("latin-1"))
    with pytest.raises(ScenarioError, match="cannot read scenario"):
        load_scenario(path)


def test_a_scenarios_files_are_found_beside_it_or_in_config_not_in_the_working_directory(tmp_path, monkeypatch):
    """A ./camera.yaml (a user's own calibration, say) replaced the shipped scenarios' camera unnoticed."""
    other = CameraModel(640, 480, [[800.0, 0, 320.0], [0, 800.0, 240.0], [0, 0, 1]])
    save_camera_info_yaml(other, tmp_path / "camera.yaml")
    monkeypatch.chdir(tmp_path)
    assert scenario_camera(load_scenario("normal")).K[0, 0] == 1100.0
    (tmp_path / "mine").mkdir()
    save_camera_info_yaml(other, tmp_path / "mine" / "lens.yaml")
    (tmp_path / "mine" / "landing.yaml").write_text("camera_info: lens.yaml\napproach: {}\n")
    monkeypatch.chdir(tmp_path / "mine" / "..")
    assert scenario_camera(load_scenario(tmp_path / "mine" / "landing.yaml")).K[0, 0] == 800.0
    save_camera_info_yaml(other, tmp_path / "cwd_only.yaml")  # only in the working directory: not taken
    (tmp_path / "mine" / "landing.yaml").write_text("camera_info: cwd_only.yaml\napproach: {}\n")
    with pytest.raises(FileNotFoundError, match=r"mine/cwd_only.yaml"):
        scenario_camera(load_scenario(tmp_path / "mine" / "landing.yaml"))


def test_unknown_scenario_name():
    with pytest.raises(ScenarioError, match="no shipped scenario"):
        load_scenario("nope")


@pytest.fixture(scope="module")
def approach():
    s = load_scenario("normal")
    return s, make_trajectory(s, generators(5))


def test_approach_range_speed_and_end(approach):
    s, tr = approach
    dist = np.linalg.norm(tr.trans, axis=1)
    assert 78 <= dist[0] <= 102
    assert 4.5 <= dist[-1] <= 6.0  # ends at the net, ~5 m from the camera
    assert np.linalg.norm(tr.uav_pos[-1]) < 0.3
    speed = np.linalg.norm(np.diff(tr.uav_pos, axis=0), axis=1) / s.dt_s
    closing = s.approach.airspeed_mps - s.ship.speed_mps
    assert abs(np.median(speed) - closing) < 1.0
    assert np.all(tr.trans[:, 2] > 0)


def test_approach_inside_landing_cone(approach):
    s, tr = approach
    a = s.approach
    r = np.linalg.norm(tr.uav_pos, axis=1)
    inside = (r <= a.cone_start_m) & (r > 0.5)
    p = tr.uav_pos[inside]
    alpha = np.degrees(np.arcsin(p[:, 2] / r[inside]))
    beta = np.degrees(np.arctan2(p[:, 1], -p[:, 0]))
    assert alpha.min() >= a.alpha2_deg and alpha.max() <= a.alpha1_deg
    assert np.abs(beta).max() <= a.beta2_deg / 2


def test_attitude_upright_nose_forward_and_disturbed(approach):
    s, tr = approach
    # UAV attitude in M: camera rotation (optical→M) times the pose rotation.
    euler = np.degrees(matrix_to_euler_zyx(tr.cam_rot @ quat_to_matrix(tr.quat)))
    far = np.linalg.norm(tr.uav_pos, axis=1) > 60
    assert np.abs(euler[:, 2]).max() < 30  # heading toward the bow
    assert np.abs(euler[:, 0]).max() < 60  # upright
    assert np.std(euler[far, 0]) > 5  # tens of degrees of roll at range
    assert np.abs(euler[~far, 0][-10:]).max() < np.abs(euler[far, 0]).max()


def test_ship_moves_the_camera(approach):
    s, tr = approach
    rot, pos = camera_mount(s.ship)
    assert np.ptp(tr.cam_pos[:, 2]) > 0.1
    roll = np.degrees(matrix_to_euler_zyx(tr.cam_rot @ rot.T)[:, 0])
    assert 1.0 < np.std(roll) < 6.0
    # Looking aft: the optical axis points to −x of M.
    assert np.all(tr.cam_rot[:, 0, 2] < -0.9)


def test_deterministic_and_independent_streams():
    s = load_scenario("complex")
    a, b = make_trajectory(s, generators(11)), make_trajectory(s, generators(11))
    assert np.array_equal(a.quat, b.quat) and np.array_equal(a.cam_pos, b.cam_pos)
    c = make_trajectory(s, generators(12))
    assert not np.array_equal(a.trans[0], c.trans[0])
    head = a.head(10)
    assert len(head) == 10 and np.array_equal(head.trans, a.trans[:10])


def test_single_frame_protocol():
    s = load_scenario("single_frame")
    tr = make_trajectory(s, generators(0))
    n = s.single_frame.poses_per_distance
    assert len(tr) == n * len(s.single_frame.distances_m)
    assert np.allclose(tr.trans[:, :2], 0) and tr.trans[n, 2] == s.single_frame.distances_m[1]
    assert not tr.continuous
    assert np.allclose(np.linalg.norm(tr.quat, axis=1), 1)
    assert np.all(tr.quat[:, 3] >= 0)


def test_smooth_signal_rms_and_smoothness():
    sig = SmoothSignal(np.random.default_rng(0), 2.0, (0.1, 0.5))
    t = np.arange(0, 2000, 0.034)
    v = sig(t)
    assert np.sqrt(np.mean(v**2)) == pytest.approx(2.0, rel=0.05)
    assert np.abs(np.diff(v)).max() < 2.0 * 2 * np.pi * 0.5 * 0.034 * 2.5


def test_a_jittery_approach_still_closes_in_and_reaches_the_net():
    s = load_scenario("normal")  # closing speed 7 m/s
    s = replace(s, approach=replace(s.approach, speed_jitter_mps=1.7))
    for seed in (13, 14, 15, 21, 26):  # seeds whose jitter is slow on the whole: more steps than 7 m/s needs
        tr = make_trajectory(s, generators(seed))
        assert np.linalg.norm(tr.uav_pos[-1]) < (7.0 + 3.5 * 1.7) * s.dt_s  # within a step of the net
        assert np.all(np.diff(np.linalg.norm(tr.uav_pos, axis=1)) < 0)  # never backing away


def test_approach_banks_into_its_turns():
    # Without disturbances the roll is the coordinated turn's: the lift (body z) leans to the
    # side the UAV accelerates to (the centre of the turn), never away from it.
    s = load_scenario("normal")
    calm = dict.fromkeys(("roll_far_deg", "roll_near_deg", "pitch_far_deg", "pitch_near_deg",
                          "yaw_far_deg", "yaw_near_deg"), 0.0)
    s = replace(s, approach=replace(s.approach, path_wander_deg=5.0, **calm))
    for seed in range(3):
        tr = make_trajectory(s, generators(seed))
        rot = (tr.cam_rot @ quat_to_matrix(tr.quat))[5:-5]  # UAV attitude in M (an inertial frame)
        acc = np.gradient(np.gradient(tr.uav_pos, s.dt_s, axis=0), s.dt_s, axis=0)[5:-5]
        heading = np.arctan2(rot[:, 1, 0], rot[:, 0, 0])
        left = np.stack([-np.sin(heading), np.cos(heading)], axis=-1)  # horizontal, left of the nose
        lateral = np.einsum("ni,ni->n", acc[:, :2], left)
        lean = np.einsum("ni,ni->n", rot[:, :2, 2], left)
        turning = np.abs(lateral) > 0.5  # m/s²: a bank of 3° or more
        assert turning.sum() > 20 and np.all(np.sign(lean[turning]) == np.sign(lateral[turning]))


def test_the_frame_limit_admits_an_approach_of_exactly_that_many_frames(monkeypatch):
    from uav_landing_vision.sim import trajectory

    s = load_scenario("normal")
    monkeypatch.setattr(trajectory, "MAX_FRAMES", 1)
    with pytest.raises(ScenarioError, match=r"may take up to (\d+) frames \(at most 1\)") as err:
        make_trajectory(s, generators(3))
    n = int(err.value.args[0].split("up to ")[1].split()[0])
    monkeypatch.setattr(trajectory, "MAX_FRAMES", n)
    assert len(make_trajectory(s, generators(3))) <= n
    monkeypatch.setattr(trajectory, "MAX_FRAMES", n - 1)
    with pytest.raises(ScenarioError, match=f"up to {n} frames"):
        make_trajectory(s, generators(3))


def test_the_uav_and_the_ship_draw_from_their_own_streams():
    """Another ship stream changes only the camera's motion, another UAV stream only the UAV's path."""
    s = load_scenario("normal")
    base = make_trajectory(s, generators(3))
    other_ship = make_trajectory(s, {**generators(3), "ship": generators(4)["ship"]})
    np.testing.assert_array_equal(other_ship.uav_pos, base.uav_pos)
    assert not np.allclose(other_ship.cam_rot, base.cam_rot)
    other_uav = make_trajectory(s, {**generators(3), "uav": generators(4)["uav"]})
    n = min(len(base), len(other_uav))
    np.testing.assert_array_equal(other_uav.cam_rot[:n], base.cam_rot[:n])
    np.testing.assert_array_equal(other_uav.cam_pos[:n], base.cam_pos[:n])
    assert not np.allclose(other_uav.uav_pos[:n], base.uav_pos[:n])


@pytest.mark.parametrize("text", [
    "dt_s: 1.0e-6\napproach: {}\n",
    "start_time_s: 0\napproach: {}\n",
    "approach: {}\nbackground: {sun_elevation_deg: 0}\n",
    "approach: {}\nbackground: {sun_elevation_deg: 90}\n",
    "approach: {start_range_m: [80, 80]}\n",
    "single_frame: {distances_m: [5], poses_per_distance: 1000000}\n",
    "approach: {}\nship: {wave_period_s: [6, 6]}\n",
    "approach: {}\nimaging: {albedo: [0, 1, 0.5]}\n",
])
def test_values_on_the_closed_ends_of_their_ranges_are_accepted(tmp_path, text):
    path = tmp_path / "edge.yaml"
    path.write_text(text)
    load_scenario(path)


def test_validate_refuses_a_sun_azimuth_that_is_not_finite():
    s = load_scenario("normal")
    with pytest.raises(ScenarioError, match="sun_azimuth_deg must be finite"):
        validate(replace(s, background=replace(s.background, sun_azimuth_deg=float("inf"))))


def test_a_scenario_keeps_its_own_name_and_an_empty_single_frame_section(tmp_path):
    path = tmp_path / "file_name.yaml"
    path.write_text("name: landing_42\nsingle_frame:\n")
    s = load_scenario(path)
    assert s.name == "landing_42" and s.single_frame == SingleFrameConfig() and s.approach is None


def test_a_file_beside_the_scenario_wins_over_the_shipped_one_and_a_video_is_never_taken_from_config(tmp_path):
    other = CameraModel(640, 480, [[800.0, 0, 320.0], [0, 800.0, 240.0], [0, 0, 1]])
    save_camera_info_yaml(other, tmp_path / "camera.yaml")  # also the name of the shipped calibration
    (tmp_path / "s.yaml").write_text("camera_info: camera.yaml\napproach: {}\nbackground: {video: tracker.yaml}\n")
    s = load_scenario(tmp_path / "s.yaml")
    assert s.camera_info == str((tmp_path / "camera.yaml").resolve())
    assert scenario_camera(s).K[0, 0] == 800.0
    assert s.background.video == str((tmp_path / "tracker.yaml").resolve())  # not config/tracker.yaml


def test_a_shipped_name_is_not_taken_from_the_working_directory(tmp_path, monkeypatch):
    (tmp_path / "normal").mkdir()
    monkeypatch.chdir(tmp_path)
    assert load_scenario("normal").approach is not None
