"""Landing cone (Fig. 1.5), stage machine (Fig. 1.4) and the bridge's send decisions on scripted flights."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from test_gcs_frames import camera_pose_from_truth

from uav_landing_vision.gcs import GcsBridge, Stage, StageMachine, cone_geometry, load_config
from uav_landing_vision.gcs.bridge import TRACKER_ACQUIRING, TRACKER_LOST, TRACKER_TRACKING, status_text
from uav_landing_vision.gcs.landing import ConeGeometry, glide_slope_angle, inside_cone, lateral_angle

CONFIG = load_config(Path(__file__).parents[2] / "config" / "gcs_bridge.yaml")
CONE = CONFIG.cone  # α1 10°, α2 3°, glide slope 6°, β2 20°, d 50 m, no return 10 m, course 0
GAMMA = math.radians(6.0)
COV = np.diag([0.01, 0.01, 0.25, 1e-4, 1e-4, 1e-4])


def on_axis(rng, lateral_m=0.0, gamma=GAMMA):
    """Landing-frame position ``rng`` metres out along the landing axis at elevation ``gamma``."""
    return np.array([-rng * math.cos(gamma), lateral_m, -rng * math.sin(gamma)])


class RecordingSender:
    """Stands in for MavlinkSender: records what the bridge decided to send."""

    def __init__(self):
        self.poses, self.texts, self.heartbeats = [], [], 0

    def poll(self):
        return False  # the link never fails

    def send_pose(self, pose, stamp_s):
        self.poses.append((stamp_s, pose))
        return ["ODOMETRY"]

    def send_heartbeat(self):
        self.heartbeats += 1

    def send_statustext(self, text, severity):
        self.texts.append((text, severity))

    def close(self):
        pass


def feed(bridge, t, p_land, rpy=(0.0, -GAMMA, 0.0), state=TRACKER_TRACKING):
    cam = CONFIG.camera
    p_cam, q_cam = camera_pose_from_truth(cam.position_m, cam.rpy, CONFIG.net_position_m, p_land, rpy)
    bridge.on_tracker_state(state, t)
    return bridge.on_pose(t, p_cam, q_cam, COV, now_s=t + 0.02)


def fly(bridge, path, t_end, frame_dt=1 / 30, ticks_every=3, latency=0.03):
    """Feed ``path(t)`` (a landing-frame position, or a tracker state when there is no pose) at
    30 Hz and tick at 10 Hz; returns [(t, TickResult)]."""
    out = []
    for k in range(int(round(t_end / frame_dt)) + 1):
        t = k * frame_dt
        sample = path(t)
        if isinstance(sample, np.ndarray):
            feed(bridge, t, sample)
        elif sample is not None:
            bridge.on_tracker_state(sample, t)
        if k % ticks_every == 0:
            out.append((t, bridge.tick(t + latency)))
    return out


def stages(results):
    seq = [results[0][1].guidance.stage]
    for _, r in results[1:]:
        if r.guidance.stage != seq[-1]:
            seq.append(r.guidance.stage)
    return seq


def first_tick(results, stage):
    return next(t for t, r in results if r.guidance.stage == stage)


def approach(rng0=120.0, speed=20.0, acquire_at=100.0):
    """Straight-in on the glide slope; the tracker acquires the UAV at ``acquire_at`` m."""

    def path(t):
        rng = rng0 - speed * t
        if rng > acquire_at:
            return TRACKER_ACQUIRING
        return on_axis(rng)

    return path


def range_at(t, rng0=120.0, speed=20.0):
    return rng0 - speed * t


@pytest.fixture
def bridge():
    sender = RecordingSender()
    b = GcsBridge(CONFIG, sender=sender)
    b.sender = sender
    return b


# --- cone geometry ---------------------------------------------------------------------------


def test_angles_on_hand_built_positions():
    assert glide_slope_angle([-50.0, 0.0, -50.0 * math.tan(GAMMA)]) == pytest.approx(GAMMA, abs=1e-15)
    assert lateral_angle([-50.0, 5.0, -5.0], 0.0) == pytest.approx(math.atan2(5, 50), abs=1e-15)  # starboard +
    assert lateral_angle([-50.0, -5.0, -5.0], 0.0) == pytest.approx(-math.atan2(5, 50), abs=1e-15)
    # Course 90° (flying to starboard, approaching from port): right of the path is aft (−x).
    assert lateral_angle([0.0, -50.0, -5.0], math.pi / 2) == pytest.approx(0.0, abs=1e-15)
    assert lateral_angle([-5.0, -50.0, -5.0], math.pi / 2) == pytest.approx(math.atan2(5, 50), abs=1e-15)
    assert abs(lateral_angle([50.0, 0.0, -5.0], 0.0)) == pytest.approx(math.pi)  # ahead of the net


def test_cone_boundaries():
    inside = cone_geometry(on_axis(49.9), CONE)
    assert inside.inside_cone and inside.range == pytest.approx(49.9)
    assert inside.glide_slope_error == pytest.approx(0.0, abs=1e-15)
    assert not cone_geometry(on_axis(50.1), CONE).inside_cone  # beyond d
    assert not cone_geometry(on_axis(30.0, gamma=math.radians(10.01)), CONE).inside_cone  # above α1
    assert not cone_geometry(on_axis(30.0, gamma=math.radians(2.99)), CONE).inside_cone  # below α2
    assert cone_geometry(on_axis(30.0, gamma=math.radians(9.99)), CONE).inside_cone
    lat = 30.0 * math.cos(GAMMA) * math.tan(math.radians(9.99))
    assert cone_geometry(on_axis(30.0, lateral_m=lat), CONE).inside_cone
    assert not cone_geometry(on_axis(30.0, lateral_m=-1.003 * lat), CONE).inside_cone  # |β1| > β2/2


def test_cone_edges_are_inside():
    """Fig. 1.5's inequalities are not strict: the edges of the cone are inside it."""
    assert inside_cone(CONE.distance_m, CONE.alpha1, 0.5 * CONE.beta2, CONE)
    assert inside_cone(CONE.distance_m, CONE.alpha2, -0.5 * CONE.beta2, CONE)


# --- scripted flights through the bridge -----------------------------------------------------


def test_nominal_landing(bridge):
    def path(t):
        return TRACKER_LOST if range_at(t) < 3.0 else approach()(t)  # the UAV hits the net at ~3 m

    results = fly(bridge, path, t_end=6.0)
    assert stages(results) == [Stage.LOITER, Stage.APPROACH, Stage.LAND, Stage.NO_RETURN]
    assert range_at(first_tick(results, Stage.APPROACH)) <= 100.0
    assert 50.0 - 20.0 * 0.1 <= range_at(first_tick(results, Stage.LAND)) <= 50.0
    assert 10.0 - 20.0 * 0.1 <= range_at(first_tick(results, Stage.NO_RETURN)) <= 10.0
    assert [text.split()[1] for text, _ in bridge.sender.texts] == ["APPROACH", "LAND", "NO_RETURN"]
    assert {severity for _, severity in bridge.sender.texts} == {5}  # MAV_SEVERITY_NOTICE: no warning
    last_pose_stamp = bridge.sender.poses[-1][0]
    assert range_at(last_pose_stamp) >= 3.0  # nothing sent once the track is lost
    assert all(len(text) <= 50 for text, _ in bridge.sender.texts)


def test_stage_change_text_gives_range_glide_slope_error_and_lateral_angle_in_degrees():
    geometry = ConeGeometry(range=42.04, glide_slope_angle=math.radians(6.3), glide_slope_error=math.radians(0.3),
                            lateral_angle=math.radians(-1.2), inside_cone=True)
    assert status_text(Stage.LAND, geometry) == "VISION LAND r=42.0m gs=+0.3 lat=-1.2deg"
    assert status_text(Stage.GO_AROUND, None) == "VISION GO_AROUND (no track)"


def test_guidance_matches_truth(bridge):
    fly(bridge, approach(), t_end=3.0)
    rng = 36.0
    feed(bridge, 10.0, on_axis(rng, lateral_m=2.0, gamma=math.radians(7.0)))
    g = bridge.tick(10.05).guidance
    p = on_axis(rng, lateral_m=2.0, gamma=math.radians(7.0))
    assert g.stamp_s == 10.0 and g.stage == Stage.LAND and g.inside_cone
    assert g.range == pytest.approx(np.linalg.norm(p), abs=1e-9)
    assert g.glide_slope_angle == pytest.approx(math.atan2(-p[2], math.hypot(p[0], p[1])), abs=1e-9)
    assert g.glide_slope_error == pytest.approx(g.glide_slope_angle - GAMMA, abs=1e-12)
    assert g.lateral_angle == pytest.approx(math.atan2(2.0, -p[0]), abs=1e-9)


def test_loss_of_track_at_30_m_goes_around_within_half_a_second(bridge):
    t_loss = (120.0 - 30.0) / 20.0

    def path(t):
        return None if t > t_loss else approach()(t)  # poses stop; the tracker says nothing

    results = fly(bridge, path, t_end=t_loss + 1.0)
    assert stages(results) == [Stage.LOITER, Stage.APPROACH, Stage.LAND, Stage.GO_AROUND]
    last_pose = bridge.sender.poses[-1][0]
    assert last_pose <= t_loss
    assert 0.0 < first_tick(results, Stage.GO_AROUND) + 0.03 - last_pose <= 0.5
    ga = [r for t, r in results if r.guidance.stage == Stage.GO_AROUND]
    assert all(math.isnan(r.guidance.range) and not r.guidance.inside_cone for r in ga)
    text, severity = bridge.sender.texts[-1]
    assert "GO_AROUND" in text and severity == 4  # MAV_SEVERITY_WARNING
    # GO_AROUND → LOITER after the hold; a fresh track then starts a new APPROACH.
    assert bridge.tick(t_loss + 0.5 + CONFIG.go_around_hold_s).guidance.stage == Stage.LOITER


def test_tracker_lost_goes_around_at_the_next_tick(bridge):
    t_loss = (120.0 - 30.0) / 20.0
    results = fly(bridge, lambda t: TRACKER_LOST if t > t_loss else approach()(t), t_end=t_loss + 0.5)
    assert first_tick(results, Stage.GO_AROUND) - t_loss <= 0.1 + 1e-9
    assert bridge.sender.poses[-1][0] <= t_loss


def test_loss_inside_no_return_stays_no_return(bridge):
    t_loss = (120.0 - 6.0) / 20.0
    results = fly(bridge, lambda t: None if t > t_loss else approach()(t), t_end=t_loss + 2.0)
    assert stages(results)[-1] == Stage.NO_RETURN
    assert bridge.sender.poses[-1][0] <= t_loss
    texts = len(bridge.sender.texts)
    assert bridge.reset() == Stage.NO_RETURN and bridge.stage == Stage.LOITER
    assert bridge.sender.texts[texts:] == [("VISION LOITER (operator reset from NO_RETURN)", 5)]  # NOTICE
    assert bridge.reset() == Stage.LOITER and len(bridge.sender.texts) == texts + 1  # no change, no text


def test_leaving_the_cone_goes_around(bridge):
    def path(t):
        rng = range_at(t)
        drift = max(0.0, 40.0 - rng) * 0.5  # from 40 m the UAV slides to starboard
        return on_axis(rng, lateral_m=drift) if rng <= 100.0 else TRACKER_ACQUIRING

    results = fly(bridge, path, t_end=5.0)
    assert stages(results) == [Stage.LOITER, Stage.APPROACH, Stage.LAND, Stage.GO_AROUND]
    t_ga = first_tick(results, Stage.GO_AROUND)
    g = dict(results)[t_ga].guidance
    assert not g.inside_cone and g.lateral_angle > CONE.beta2 / 2
    assert range_at(t_ga) > CONE.no_return_distance_m


def test_approach_outside_the_cone_never_lands(bridge):
    steep = math.radians(15.0)
    results = fly(bridge, lambda t: on_axis(range_at(t), gamma=steep), t_end=5.0)
    assert stages(results) == [Stage.APPROACH]  # tracked from the first tick, never inside the cone
    assert min(range_at(t) for t, _ in results) <= 20.0  # well inside d = 50 m


def test_each_pose_is_sent_once_and_at_most_at_the_rate(bridge):
    fly(bridge, lambda t: on_axis(range_at(t)), t_end=2.0, frame_dt=0.2, ticks_every=1)
    stamps = [s for s, _ in bridge.sender.poses]
    assert len(stamps) == len(set(stamps)) == 11  # 5 Hz poses, 5 Hz ticks: each once
    sender = RecordingSender()
    fast = GcsBridge(CONFIG, sender=sender)
    fast.sender = sender
    fly(fast, lambda t: on_axis(range_at(t)), t_end=2.0, ticks_every=1)  # 30 Hz poses and ticks
    stamps = [s for s, _ in sender.poses]
    assert len(stamps) == 20 or len(stamps) == 21
    assert min(np.diff(stamps)) >= 0.1 - 1e-9


def test_a_timer_a_few_ms_late_does_not_hold_fresh_poses_back(bridge):
    """Ticks at rate_hz, each late by 0–10 ms (an rclpy timer's spread): every tick sends the newest pose."""
    jitter = np.random.default_rng(0).uniform(0.0, 0.01, 100)
    for k in range(100):
        t = 1.0 + k / 30
        feed(bridge, t, on_axis(40.0 - t))
        if k % 3 == 2:
            assert "ODOMETRY" in bridge.tick(t + 0.01 + jitter[k]).sent, k
    assert len(bridge.sender.poses) == 33


def test_stale_and_out_of_order_poses_are_ignored(bridge):
    cam = CONFIG.camera
    p_cam, q_cam = camera_pose_from_truth(cam.position_m, cam.rpy, CONFIG.net_position_m, on_axis(40.0), (0, 0, 0))
    bridge.on_tracker_state(TRACKER_TRACKING, 2.0)
    assert not bridge.on_pose(1.0, p_cam, q_cam, COV, now_s=1.0 + CONFIG.stale_timeout_s + 0.01)
    assert bridge.on_pose(2.0, p_cam, q_cam, COV, now_s=2.0)
    assert not bridge.on_pose(1.5, p_cam, q_cam, COV, now_s=2.0)
    bridge.on_tracker_state(TRACKER_TRACKING, 2.0)  # the first call's clock (1.31 s) dropped the status
    assert bridge.tick(2.01).sent == ("HEARTBEAT", "STATUSTEXT", "ODOMETRY")
    assert not bridge.on_pose(2.0, p_cam, q_cam, COV, now_s=2.2)  # the same frame again (a repeated message)
    bridge.on_tracker_state(TRACKER_TRACKING, 2.0)
    assert "ODOMETRY" not in bridge.tick(2.21).sent and len(bridge.sender.poses) == 1  # sent once


def camera_pose(p_land, rpy=(0.0, 0.0, 0.0)):
    cam = CONFIG.camera
    return camera_pose_from_truth(cam.position_m, cam.rpy, CONFIG.net_position_m, p_land, rpy)


def test_pose_stamped_ahead_of_the_clock_is_refused_and_does_not_shut_out_later_ones(bridge):
    fly(bridge, approach(), t_end=(120.0 - 30.0) / 20.0)  # LAND at 30 m
    assert bridge.stage == Stage.LAND
    p_cam, q_cam = camera_pose(on_axis(30.0))
    with pytest.raises(ValueError, match="ahead of the clock"):
        bridge.on_pose(100.0, p_cam, q_cam, COV, now_s=4.6)
    with pytest.raises(ValueError, match="ahead of the clock"):  # 55 ms: the tolerance is 0.05 s
        bridge.on_pose(4.655, p_cam, q_cam, COV, now_s=4.6)
    assert bridge.on_pose(4.55, p_cam, q_cam, COV, now_s=4.6)  # the next correct pose is taken
    # 40 m to starboard: outside the cone, so LAND ends at the next tick
    p_cam, q_cam = camera_pose(on_axis(30.0, lateral_m=40.0))
    assert bridge.on_pose(4.6, p_cam, q_cam, COV, now_s=4.62)
    bridge.on_tracker_state(TRACKER_TRACKING, 4.6)
    assert bridge.tick(4.63).guidance.stage == Stage.GO_AROUND
    with pytest.raises(ValueError, match="finite time >= 0"):
        bridge.on_pose(-0.05, p_cam, q_cam, COV, now_s=4.7)


def test_a_clock_that_jumps_back_drops_the_held_pose(bridge):
    bridge.on_tracker_state(TRACKER_TRACKING, 500.0)
    p_cam, q_cam = camera_pose(on_axis(40.0))
    assert bridge.on_pose(500.0, p_cam, q_cam, COV, now_s=500.0)
    assert bridge.tick(500.01).guidance.stage == Stage.APPROACH
    assert bridge.tick(10.0).guidance.stage == Stage.LOITER  # replay restarted: no fresh pose
    assert bridge.on_pose(10.0, p_cam, q_cam, COV, now_s=10.0)
    bridge.on_tracker_state(TRACKER_LOST, 10.0)
    bridge.on_tracker_state(TRACKER_TRACKING, 10.0)
    assert bridge.on_pose(9.0, p_cam, q_cam, COV, now_s=9.0)  # the clock is back at 9 s: a new time-line


def test_a_pose_older_than_one_sent_is_not_sent_after_a_loss_and_reacquisition(bridge):
    """The pose of 10.0 s is sent; the track is lost at 10.033 s and back at 10.1 s; a pose stamped
    9.99 s, delayed past both statuses but not yet stale, must not reach the GCS after the newer one
    (an autopilot would take it as a newer fix). The next new pose is sent as usual."""
    p_cam, q_cam = camera_pose(on_axis(40.0))
    bridge.on_tracker_state(TRACKER_TRACKING, 10.0)
    assert bridge.on_pose(10.0, p_cam, q_cam, COV, now_s=10.02)
    assert "ODOMETRY" in bridge.tick(10.03).sent
    bridge.on_tracker_state(TRACKER_LOST, 10.033)
    bridge.on_tracker_state(TRACKER_TRACKING, 10.1)
    assert not bridge.on_pose(9.99, p_cam, q_cam, COV, now_s=10.11)
    assert "ODOMETRY" not in bridge.tick(10.3).sent
    assert bridge.on_pose(10.133, p_cam, q_cam, COV, now_s=10.31)
    bridge.on_tracker_state(TRACKER_TRACKING, 10.133)
    assert "ODOMETRY" in bridge.tick(10.32).sent
    assert [stamp for stamp, _ in bridge.sender.poses] == [10.0, 10.133]


@pytest.mark.parametrize("land_range_m, t0, lost_first", [(20.0, 5.0, True), (14.0, 5.3, False)])
def test_a_loss_or_restart_between_two_ticks_goes_around_even_if_the_track_is_back(bridge, land_range_m, t0,
                                                                                   lost_first):
    """LOST then re-acquired within one tick, or a restart of the tracker's track (new calibration,
    a frame it could not step), which says ACQUIRING for two frames only, 67 ms at 30 fps: whether
    LAND goes around must not depend on whether a 10 Hz tick fell between those statuses, nor may
    the new track's poses extend the old one's run towards NO_RETURN."""
    fly(bridge, approach(), t_end=(120.0 - land_range_m) / 20.0)  # LAND, a full run of in-cone poses
    assert bridge.stage == Stage.LAND
    if lost_first:
        bridge.on_tracker_state(TRACKER_LOST, t0)
    for k, state in enumerate([TRACKER_ACQUIRING, TRACKER_ACQUIRING, TRACKER_TRACKING]):
        t = t0 + (k + 1) / 30
        assert feed(bridge, t, on_axis(range_at(t)), state=state)
    sent = len(bridge.sender.poses)
    result = bridge.tick(t0 + 0.1 + 0.03)
    assert result.guidance.stage == Stage.GO_AROUND and "ODOMETRY" not in result.sent
    assert len(bridge.sender.poses) == sent and math.isnan(result.guidance.range)
    assert bridge.tick(t0 + 0.2).sent == ("ODOMETRY",)  # the next tick sends the new track's pose
    assert bridge.sender.poses[-1][0] == pytest.approx(t0 + 0.1)


def test_a_pose_is_sent_only_once_a_status_of_its_frame_says_tracking(bridge):
    """The tracker publishes each frame's pose before its status; after a silent restart of its
    track (new calibration, new time-line) that status says ACQUIRING, while the latest one the
    bridge holds still says TRACKING."""
    fly(bridge, approach(), t_end=(120.0 - 30.0) / 20.0)  # LAND at 30 m, last pose at 4.5 s
    assert bridge.stage == Stage.LAND
    sent = len(bridge.sender.poses)
    p_cam, q_cam = camera_pose(on_axis(29.0, lateral_m=1.0))
    assert bridge.on_pose(4.6, p_cam, q_cam, COV, now_s=4.61)
    result = bridge.tick(4.64)  # the timer fires before the frame's status comes
    assert "ODOMETRY" not in result.sent and len(bridge.sender.poses) == sent
    assert result.guidance.stamp_s == pytest.approx(4.5) and bridge.stage == Stage.LAND  # the 4.5 s pose is still in use
    bridge.on_tracker_state(TRACKER_ACQUIRING, 4.6)
    assert "ODOMETRY" not in bridge.tick(4.74).sent and bridge.stage == Stage.GO_AROUND
    assert len(bridge.sender.poses) == sent


def test_after_the_clock_jumps_back_a_new_pose_waits_for_its_own_status(bridge):
    bridge.on_tracker_state(TRACKER_TRACKING, 500.0)
    p_cam, q_cam = camera_pose(on_axis(40.0))
    assert bridge.on_pose(500.0, p_cam, q_cam, COV, now_s=500.0)
    assert "ODOMETRY" in bridge.tick(500.01).sent
    assert bridge.on_pose(1.0, p_cam, q_cam, COV, now_s=1.01)  # replay restarted: the track restarts too
    assert "ODOMETRY" not in bridge.tick(1.02).sent  # the TRACKING status at 500 s says nothing of it
    bridge.on_tracker_state(TRACKER_TRACKING, 1.0)
    assert "ODOMETRY" in bridge.tick(1.12).sent and bridge.sender.poses[-1][0] == 1.0


def test_after_the_clock_jumps_back_sending_resumes_at_once(bridge):
    fly(bridge, approach(), t_end=(120.0 - 20.0) / 20.0)  # LAND at 20 m, clock near 5 s
    assert bridge.stage == Stage.LAND
    feed(bridge, 1.0, on_axis(19.0))  # the replay restarts at 1 s: the held pose is dropped ...
    result = bridge.tick(1.03)
    # ... the new pose is taken and sent with a heartbeat, not held back until the clock passes 5 s
    assert result.sent == ("HEARTBEAT", "ODOMETRY") and result.guidance.stage == Stage.LAND


def test_after_the_clock_jumps_back_one_pose_does_not_commit_the_landing(bridge):
    fly(bridge, approach(), t_end=(120.0 - 30.0) / 20.0)  # LAND at 30 m, a full run of in-cone poses
    assert bridge.stage == Stage.LAND
    assert feed(bridge, 1.0, on_axis(8.0))  # the replay restarts at 1 s with a pose at 8 m
    assert bridge.tick(1.03).guidance.stage == Stage.LAND  # the old run does not count
    assert feed(bridge, 1.1, on_axis(7.8))
    assert bridge.tick(1.13).guidance.stage == Stage.LAND  # two poses on the new time-line
    assert feed(bridge, 1.2, on_axis(7.6))
    assert bridge.tick(1.23).guidance.stage == Stage.NO_RETURN  # three


def test_the_go_around_hold_restarts_when_the_clock_jumps_back():
    machine = StageMachine(CONE, go_around_hold_s=10.0)
    machine.update(500.0, geometry_at(30.0), 500.0)
    machine.update(500.1, geometry_at(29.0), 500.1)
    assert machine.update(500.2, None, 500.1) == Stage.GO_AROUND
    assert machine.update(5.0, None, 500.1) == Stage.GO_AROUND  # replay restarted at 5 s
    assert machine.update(14.9, None, 500.1) == Stage.GO_AROUND
    assert machine.update(15.0, None, 500.1) == Stage.LOITER  # 10 s on the new time-line


def test_a_pose_outside_the_cone_never_commits_the_landing(bridge):
    fly(bridge, approach(), t_end=(120.0 - 30.0) / 20.0)
    assert bridge.stage == Stage.LAND
    # one outlier 6.8 m from the net, 63° to starboard: within no-return range, outside the cone
    p_land = np.array([-3.0, 6.0, -1.0])
    bridge.on_tracker_state(TRACKER_TRACKING, 4.6)
    p_cam, q_cam = camera_pose(p_land)
    assert bridge.on_pose(4.6, p_cam, q_cam, COV, now_s=4.61)
    assert bridge.tick(4.62).guidance.stage == Stage.GO_AROUND


def test_a_lone_outlier_within_no_return_range_does_not_commit_the_landing(bridge):
    fly(bridge, approach(), t_end=(120.0 - 20.0) / 20.0)  # LAND at 20 m
    assert bridge.stage == Stage.LAND
    # one pose 8 m from the net, on the glide slope: inside the cone, 12 m nearer within 33 ms
    assert feed(bridge, 5.0 + 1 / 30, on_axis(8.0))
    assert bridge.tick(5.06).guidance.stage == Stage.LAND
    # the track goes on from 19.3 m and commits once it is itself within 10 m
    results = fly_from(bridge, 5.0 + 2 / 30, t_end=5.9)
    assert stages(results) == [Stage.LAND, Stage.NO_RETURN]
    assert 10.0 - 20.0 * 0.1 <= range_at(first_tick(results, Stage.NO_RETURN)) <= 10.0


def fly_from(bridge, t0, t_end, frame_dt=1 / 30, ticks_every=3, latency=0.03):
    """:func:`fly`'s straight-in approach from time ``t0`` on."""
    out = []
    for k in range(int(round((t_end - t0) / frame_dt)) + 1):
        t = t0 + k * frame_dt
        feed(bridge, t, on_axis(range_at(t)))
        if k % ticks_every == 0:
            out.append((t, bridge.tick(t + latency)))
    return out


def test_no_return_needs_successive_plausible_poses_with_distinct_stamps():
    machine = StageMachine(CONE, go_around_hold_s=1.0)
    at = lambda rng: cone_geometry(on_axis(rng), CONE)  # noqa: E731
    for k, rng in enumerate([30.0, 29.0, 28.0]):  # APPROACH, then LAND
        machine.update(0.1 * k, at(rng), 0.1 * k)
    assert machine.stage == Stage.LAND
    # two poses jump to 9 m and 8.5 m: the first breaks the run (19 m in 0.1 s), so 2 < 3 poses
    assert machine.update(0.3, at(9.0), 0.3) == Stage.LAND
    assert machine.update(0.4, at(8.5), 0.4) == Stage.LAND
    assert machine.update(0.5, at(8.5), 0.4) == Stage.LAND  # the same pose ticked again
    assert machine.update(0.6, at(8.0), 0.5) == Stage.NO_RETURN  # a third consistent pose


def test_an_outlier_commits_at_most_the_range_rate_bound_early():
    machine = StageMachine(CONE, go_around_hold_s=1.0)
    at = lambda rng: cone_geometry(on_axis(rng), CONE)  # noqa: E731
    for k, rng in enumerate([16.0, 15.0, 14.0]):
        machine.update(0.1 * k, at(rng), 0.1 * k)
    assert machine.stage == Stage.LAND
    step = CONE.max_range_rate_mps * 0.1  # 4 m in 0.1 s
    assert machine.update(0.3, at(14.0 - step - 0.01), 0.3) == Stage.LAND  # beyond the bound: run restarts
    machine.update(0.4, at(13.0), 0.4)
    machine.update(0.5, at(12.0), 0.5)
    assert machine.update(0.6, at(12.0 - step + 0.01), 0.6) == Stage.NO_RETURN  # within it: commits


def test_values_mavlink_cannot_carry_are_refused(bridge):
    bridge.on_tracker_state(TRACKER_TRACKING, 1.0)
    p_cam, q_cam = camera_pose(on_axis(40.0))
    with pytest.raises(ValueError, match="float32"):
        bridge.on_pose(1.0, p_cam * 1e38, q_cam, COV, now_s=1.0)
    with pytest.raises(ValueError, match="float32"):
        bridge.on_pose(1.0, p_cam, q_cam, COV * 1e40, now_s=1.0)
    cam = CONFIG.camera  # pitched up to 89.9999°: the Euler covariance of a huge one overflows to NaN, which max() let by
    p_cam, q_cam = camera_pose_from_truth(cam.position_m, cam.rpy, CONFIG.net_position_m, on_axis(40.0),
                                          (0.0, math.radians(89.9999), 0.0))
    with pytest.raises(ValueError, match="float32"):
        bridge.on_pose(1.0, p_cam, q_cam, np.eye(6) * 1e306, now_s=1.0)
    assert bridge.tick(1.01).sent == ("HEARTBEAT",) and not bridge.sender.poses


def test_bad_pose_is_rejected_and_nothing_is_sent(bridge):
    cam = CONFIG.camera
    p_cam, q_cam = camera_pose_from_truth(cam.position_m, cam.rpy, CONFIG.net_position_m, on_axis(40.0), (0, 0, 0))
    bridge.on_tracker_state(TRACKER_TRACKING, 1.0)
    for args in [
        (1.0, p_cam * np.nan, q_cam, COV),
        (1.0, p_cam, q_cam * 1.5, COV),
        (1.0, p_cam, q_cam, -COV),
        (math.nan, p_cam, q_cam, COV),
    ]:
        with pytest.raises(ValueError):
            bridge.on_pose(*args, now_s=1.0)
    result = bridge.tick(1.01)
    assert result.sent == ("HEARTBEAT",) and not bridge.sender.poses
    with pytest.raises(ValueError, match="tracker state"):
        bridge.on_tracker_state(7, 1.0)
    with pytest.raises(ValueError, match="status stamp"):
        bridge.on_tracker_state(TRACKER_TRACKING, math.nan)


def test_stage_machine_needs_a_track_to_leave_loiter():
    machine = StageMachine(CONE, go_around_hold_s=1.0)
    assert machine.update(0.0, None, -math.inf) == Stage.LOITER
    assert machine.update(0.1, cone_geometry(on_axis(40.0), CONE), 0.05) == Stage.APPROACH
    assert machine.update(0.2, None, 0.05) == Stage.LOITER  # lost before the descent: loiter again


def geometry_at(rng, inside=True):
    return ConeGeometry(rng, GAMMA, 0.0, 0.0, inside)


def test_stage_machine_holds_go_around_from_the_moment_it_began():
    machine = StageMachine(CONE, go_around_hold_s=10.0)
    for t in (100.0, 100.1):
        machine.update(t, geometry_at(30.0), t)
    assert machine.stage == Stage.LAND
    assert machine.update(100.2, None, 100.1) == Stage.GO_AROUND
    assert machine.update(110.1, geometry_at(30.0), 110.1) == Stage.GO_AROUND  # 9.9 s: still held
    assert machine.update(110.2, geometry_at(30.0), 110.2) == Stage.LOITER


def test_stage_machine_commits_at_the_no_return_distance():
    machine = StageMachine(CONE, go_around_hold_s=1.0)
    for k, rng in enumerate([12.0, 11.0]):
        machine.update(0.1 * k, geometry_at(rng), 0.1 * k)
    assert machine.update(0.2, geometry_at(CONE.no_return_distance_m), 0.2) == Stage.NO_RETURN
    assert machine.update(0.3, geometry_at(9.0, inside=False), 0.3) == Stage.NO_RETURN


def test_poses_outside_the_cone_do_not_count_towards_no_return():
    machine = StageMachine(CONE, go_around_hold_s=1.0)
    for k, rng in enumerate([12.0, 11.0]):  # APPROACH outside the cone, already within no-return range
        machine.update(0.1 * k, geometry_at(rng, inside=False), 0.1 * k)
    assert machine.update(0.2, geometry_at(9.8), 0.2) == Stage.LAND
    assert machine.update(0.3, geometry_at(9.6), 0.3) == Stage.LAND  # two in-cone poses of three
    assert machine.update(0.4, geometry_at(9.4), 0.4) == Stage.NO_RETURN


def test_after_a_reset_no_return_needs_a_new_run_of_poses():
    """The poses before an operator reset (which committed the last landing) do not count
    towards the next one: with five confirming poses, the new track commits at its fifth."""
    machine = StageMachine(dataclasses.replace(CONE, no_return_confirm_poses=5), go_around_hold_s=1.0)
    ranges = iter(np.arange(9.9, 0.0, -0.1))
    stages_seen = [machine.update(0.1 * k, geometry_at(next(ranges)), 0.1 * k) for k in range(6)]
    assert stages_seen[-1] == Stage.NO_RETURN
    machine.reset()
    stages_seen = [machine.update(0.1 * k, geometry_at(next(ranges)), 0.1 * k) for k in range(6, 11)]
    assert stages_seen == [Stage.APPROACH, Stage.LAND, Stage.LAND, Stage.LAND, Stage.NO_RETURN]


def test_dataclass_config_is_what_the_bridge_uses():
    cfg = dataclasses.replace(CONFIG, cone=dataclasses.replace(CONE, distance_m=30.0))
    sender = RecordingSender()
    b = GcsBridge(cfg, sender=sender)
    fly(b, lambda t: on_axis(40.0), t_end=0.5)
    assert b.stage == Stage.APPROACH  # 40 m is outside a 30 m cone


def test_one_pose_seen_at_several_ticks_counts_once_towards_no_return(bridge):
    """The stage machine takes the pose's stamp, not the tick's: a lone in-cone outlier at 8 m,
    the last pose before the tracker stalls, stays fresh for three ticks and must not count as
    three confirming poses."""
    fly(bridge, approach(), t_end=(120.0 - 20.0) / 20.0)  # LAND at 20 m
    assert bridge.stage == Stage.LAND
    feed(bridge, 5.05, on_axis(8.0))
    seen = [bridge.tick(t).guidance.stage for t in (5.06, 5.16, 5.26, 5.36)]
    assert Stage.NO_RETURN not in seen and seen[-1] == Stage.GO_AROUND, seen


def test_an_outward_range_jump_breaks_the_run_towards_no_return():
    m = StageMachine(CONE, go_around_hold_s=1.0)
    for k, r in enumerate([16.0, 15.0, 14.0]):
        m.update(0.1 * k, geometry_at(r), 0.1 * k)
    assert m.stage == Stage.LAND
    assert m.update(0.3, geometry_at(2.0), 0.3) == Stage.LAND  # 12 m in: the run restarts at 2 m
    assert m.update(0.4, geometry_at(9.0), 0.4) == Stage.LAND  # 7 m out, beyond the rate bound: restarts at 9 m
    assert m.update(0.5, geometry_at(8.8), 0.5) == Stage.LAND  # two poses of three


def test_a_range_change_exactly_at_the_rate_bound_is_plausible():
    m = StageMachine(CONE, go_around_hold_s=1.0)  # 40 m/s × 0.25 s = 10 m, exact in binary
    for k, r in enumerate([19.0, 18.0, 17.0]):
        m.update(0.25 * k, geometry_at(r), 0.25 * k)
    assert m.update(0.75, geometry_at(7.0), 0.75) == Stage.NO_RETURN


def _tracked_pose_at(bridge, t=1.0):
    """TRACKING before and at ``t``, with the pose of the frame at ``t`` (40 m out)."""
    bridge.on_tracker_state(TRACKER_TRACKING, t - 0.1)
    p_cam, q_cam = camera_pose(on_axis(40.0))
    assert bridge.on_pose(t, p_cam, q_cam, COV, now_s=t)


def test_a_pose_of_an_abandoned_track_is_never_sent_while_acquiring(bridge):
    _tracked_pose_at(bridge)
    bridge.on_tracker_state(TRACKER_TRACKING, 1.0)
    bridge.on_tracker_state(TRACKER_ACQUIRING, 1.03)  # the track restarts, no pose from it yet
    first, second = bridge.tick(1.05), bridge.tick(1.15)  # still ACQUIRING at the second tick
    assert "ODOMETRY" not in first.sent and "ODOMETRY" not in second.sent
    assert math.isnan(second.guidance.range) and second.guidance.stage == Stage.LOITER


def test_a_pose_whose_own_status_says_acquiring_is_not_sent_on_a_later_tracking(bridge):
    """The next frame's TRACKING arrives without its pose (lost in transit): the held pose was
    flagged by its own frame's status and stays unsent."""
    _tracked_pose_at(bridge)
    bridge.on_tracker_state(TRACKER_ACQUIRING, 1.0)
    assert "ODOMETRY" not in bridge.tick(1.05).sent
    bridge.on_tracker_state(TRACKER_TRACKING, 1.1)
    result = bridge.tick(1.15)
    assert "ODOMETRY" not in result.sent and math.isnan(result.guidance.range)


def test_lost_drops_the_held_pose_even_when_the_track_is_soon_back(bridge):
    _tracked_pose_at(bridge)
    bridge.on_tracker_state(TRACKER_TRACKING, 1.0)
    bridge.on_tracker_state(TRACKER_LOST, 1.03)
    assert "ODOMETRY" not in bridge.tick(1.05).sent
    bridge.on_tracker_state(TRACKER_TRACKING, 1.1)  # re-acquired; that frame's pose not here yet
    result = bridge.tick(1.15)
    assert "ODOMETRY" not in result.sent and math.isnan(result.guidance.range)


def test_lost_of_an_earlier_frame_drops_a_pose_waiting_for_its_status(bridge):
    p_cam, q_cam = camera_pose(on_axis(40.0))
    assert bridge.on_pose(1.0, p_cam, q_cam, COV, now_s=1.0)
    bridge.on_tracker_state(TRACKER_LOST, 0.97)
    bridge.on_tracker_state(TRACKER_TRACKING, 1.0)
    assert "ODOMETRY" not in bridge.tick(1.05).sent
    assert "ODOMETRY" not in bridge.tick(1.15).sent


def test_an_older_fresh_pose_does_not_replace_the_one_waiting_for_its_status(bridge):
    p_cam, q_cam = camera_pose(on_axis(40.0))
    assert bridge.on_pose(2.0, p_cam, q_cam, COV, now_s=2.0)  # waits: no status yet
    assert not bridge.on_pose(1.9, p_cam, q_cam, COV, now_s=2.0)  # older, still fresh
    bridge.on_tracker_state(TRACKER_TRACKING, 2.0)
    assert "ODOMETRY" in bridge.tick(2.01).sent and bridge.sender.poses[-1][0] == 2.0


def test_a_waiting_pose_ahead_of_a_clock_that_jumped_back_is_forgotten(bridge):
    """A replay restarted: the pose of the old time-line would refuse every new one until the
    clock passed it."""
    p_cam, q_cam = camera_pose(on_axis(40.0))
    bridge.on_tracker_state(TRACKER_TRACKING, 499.9)
    assert bridge.on_pose(500.0, p_cam, q_cam, COV, now_s=500.0)  # waits for its status
    assert bridge.on_pose(1.0, p_cam, q_cam, COV, now_s=1.01)
    bridge.on_tracker_state(TRACKER_TRACKING, 1.0)
    assert "ODOMETRY" in bridge.tick(1.02).sent


def test_a_pose_a_little_ahead_of_the_clock_is_used(bridge):
    """A camera clock 45 ms ahead of the bridge's, within the tolerance (0.05 s): the pose guides."""
    fly(bridge, approach(), t_end=(120.0 - 30.0) / 20.0)  # LAND at 30 m
    p_cam, q_cam = camera_pose(on_axis(29.0))
    assert bridge.on_pose(4.675, p_cam, q_cam, COV, now_s=4.63)
    bridge.on_tracker_state(TRACKER_TRACKING, 4.675)
    result = bridge.tick(4.64)
    assert "ODOMETRY" in result.sent and result.guidance.stage == Stage.LAND and result.guidance.stamp_s == 4.675


def test_a_pose_exactly_the_stale_timeout_old_is_still_fresh():
    """Fresh while now − stamp <= stale_timeout_s, on arrival as at the tick (binary-exact times)."""
    cfg = dataclasses.replace(CONFIG, stale_timeout_s=0.25, mavlink=dataclasses.replace(CONFIG.mavlink, rate_hz=4.0))
    bridge = GcsBridge(cfg, sender=RecordingSender())
    bridge.on_tracker_state(TRACKER_TRACKING, 0.5)
    p_cam, q_cam = camera_pose(on_axis(40.0))
    assert bridge.on_pose(0.5, p_cam, q_cam, COV, now_s=0.75)
    assert "ODOMETRY" in bridge.tick(0.75).sent
    assert not bridge.on_pose(1.0, p_cam, q_cam, COV, now_s=1.25 + 2.0**-20)  # just past it: stale


def test_the_approach_course_is_in_degrees():
    cone = dataclasses.replace(CONE, approach_course_deg=90.0)  # flying to starboard: in from port (−y)
    g = cone_geometry(np.array([0.0, -30.0 * math.cos(GAMMA), -30.0 * math.sin(GAMMA)]), cone)
    assert g.inside_cone and g.lateral_angle == pytest.approx(0.0, abs=1e-12)


def test_guidance_says_when_a_tracked_pose_is_outside_the_cone(bridge):
    feed(bridge, 1.0, on_axis(30.0, gamma=math.radians(15.0)))
    g = bridge.tick(1.03).guidance
    assert g.stage == Stage.APPROACH and not g.inside_cone and not math.isnan(g.range)


def test_a_heartbeat_every_second_and_at_once_when_the_link_is_back(bridge):
    assert bridge.tick(0.0).sent == ("HEARTBEAT",)
    assert bridge.tick(0.5).sent == ()
    assert bridge.tick(1.0).sent == ("HEARTBEAT",)
    bridge.sender.poll = lambda: True
    assert bridge.tick(1.3).sent == ("HEARTBEAT", "STATUSTEXT")


def test_a_go_around_starts_the_run_towards_no_return_afresh():
    """In-cone poses from before a track loss do not count towards the next commit: back in LAND,
    the landing commits only once enough in-cone poses have come since."""
    machine = StageMachine(CONE, go_around_hold_s=1.0)
    assert machine.update(0.0, geometry_at(12.0), 0.0) == Stage.APPROACH
    assert machine.update(0.1, geometry_at(11.0), 0.1) == Stage.LAND
    assert machine.update(0.2, None, 0.1) == Stage.GO_AROUND  # the track is lost
    assert machine.update(1.2, None, 0.1) == Stage.LOITER
    assert machine.update(1.3, geometry_at(10.5, inside=False), 1.3) == Stage.APPROACH
    assert machine.update(1.4, geometry_at(9.8), 1.4) == Stage.LAND
    assert machine.update(1.5, geometry_at(9.6), 1.5) == Stage.LAND  # two in-cone poses since the loss
    assert machine.update(1.6, geometry_at(9.4), 1.6) == Stage.NO_RETURN


def test_no_return_holds_however_long_the_track_is_gone_or_outside_the_cone():
    """A committed landing is never undone by time: NO_RETURN lasts until the operator's reset."""
    machine = StageMachine(CONE, go_around_hold_s=1.0)
    for k, rng in enumerate([12.0, 11.0, 10.0]):
        machine.update(0.1 * k, geometry_at(rng), 0.1 * k)
    assert machine.stage == Stage.NO_RETURN
    assert machine.update(100.0, None, 0.2) == Stage.NO_RETURN
    assert machine.update(1000.0, geometry_at(30.0, inside=False), 1000.0) == Stage.NO_RETURN


def test_poses_anywhere_in_the_cone_count_towards_no_return():
    """The run of confirming poses may begin far out in the cone: poses at 40 m and 30 m, then one
    at 9.9 m 0.75 s later (27 m/s, within the range-rate bound), commit the landing."""
    machine = StageMachine(CONE, go_around_hold_s=1.0)
    assert machine.update(0.0, geometry_at(40.0), 0.0) == Stage.APPROACH
    assert machine.update(0.5, geometry_at(30.0), 0.5) == Stage.LAND
    assert machine.update(1.25, geometry_at(9.9), 1.25) == Stage.NO_RETURN


def test_after_the_clock_jumps_back_half_a_second_a_new_pose_is_taken_and_waits_for_its_own_status(bridge):
    """A jump back smaller than the staleness window still starts a new time-line: the pose held
    (stamped ahead of the clock now) neither shuts out the new one nor vouches for it, and neither
    does the TRACKING status of the old time-line."""
    bridge.on_tracker_state(TRACKER_TRACKING, 10.0)
    p_cam, q_cam = camera_pose(on_axis(40.0))
    assert bridge.on_pose(10.0, p_cam, q_cam, COV, now_s=10.0)
    assert "ODOMETRY" in bridge.tick(10.01).sent
    assert bridge.on_pose(9.5, p_cam, q_cam, COV, now_s=9.51)  # the clock is back 0.5 s
    assert "ODOMETRY" not in bridge.tick(9.52).sent  # no status of its frame yet
    bridge.on_tracker_state(TRACKER_TRACKING, 9.5)
    assert "ODOMETRY" in bridge.tick(9.62).sent and bridge.sender.poses[-1][0] == 9.5


def test_after_the_clock_jumps_back_heartbeats_go_on_at_once(bridge):
    """No pose was ever sent (no track): a replay restart must not stop the heartbeat until the
    clock is back where it was."""
    assert bridge.tick(500.0).sent == ("HEARTBEAT",)
    assert bridge.tick(501.0).sent == ("HEARTBEAT",)
    assert bridge.tick(10.0).sent == ("HEARTBEAT",)
    assert bridge.tick(10.5).sent == ()
    assert bridge.tick(11.0).sent == ("HEARTBEAT",)


def test_after_the_clock_jumps_back_behind_the_last_send_the_new_pose_is_sent_at_once(bridge):
    """The last position message went out after the last heartbeat; the clock then jumps back to
    between the two: the new time-line's pose goes out at its first tick, with a heartbeat."""
    assert bridge.tick(4.0).sent == ("HEARTBEAT",)
    p_cam, q_cam = camera_pose(on_axis(40.0))
    bridge.on_tracker_state(TRACKER_TRACKING, 4.4)
    assert bridge.on_pose(4.4, p_cam, q_cam, COV, now_s=4.45)
    assert bridge.tick(4.5).sent == ("STATUSTEXT", "ODOMETRY")
    assert bridge.on_pose(4.15, p_cam, q_cam, COV, now_s=4.2)  # the clock is back at 4.2 s
    bridge.on_tracker_state(TRACKER_TRACKING, 4.15)
    assert bridge.tick(4.2).sent == ("HEARTBEAT", "STATUSTEXT", "ODOMETRY")  # STATUSTEXT: APPROACH → LAND
    assert bridge.sender.poses[-1][0] == 4.15


def test_a_position_whose_distance_exceeds_float32_is_refused_even_if_each_coordinate_fits(bridge):
    """Each coordinate 0.7 × the float32 maximum, the distance 1.2 ×: LANDING_TARGET's distance (and
    its body-frame coordinates, for most attitudes) would overflow."""
    big = 0.7 * float(np.finfo(np.float32).max)
    bridge.on_tracker_state(TRACKER_TRACKING, 1.0)
    p_cam, q_cam = camera_pose(np.array([-big, big, -big]))
    with pytest.raises(ValueError, match="float32"):
        bridge.on_pose(1.0, p_cam, q_cam, COV, now_s=1.0)
    assert bridge.tick(1.01).sent == ("HEARTBEAT",) and not bridge.sender.poses


def test_guidance_without_a_fresh_pose_carries_the_tick_time(bridge):
    """With no track yet, and once the pose has gone stale, the guidance is stamped with the tick's
    time, not with a stale (or no) pose stamp."""
    assert bridge.tick(3.0).guidance.stamp_s == 3.0
    _tracked_pose_at(bridge, t=5.0)
    bridge.on_tracker_state(TRACKER_TRACKING, 5.0)
    assert bridge.tick(5.01).guidance.stamp_s == 5.0
    g = bridge.tick(5.5).guidance  # 0.5 s old: stale
    assert g.stamp_s == 5.5 and math.isnan(g.range)


def test_position_messages_exactly_three_quarters_of_a_period_apart_are_sent():
    """At 4 Hz the spacing is 0.1875 s (binary-exact): a tick that far after the last send sends the
    new pose; one a hair sooner holds it back."""
    cfg = dataclasses.replace(CONFIG, stale_timeout_s=0.25, mavlink=dataclasses.replace(CONFIG.mavlink, rate_hz=4.0))
    sender = RecordingSender()
    bridge = GcsBridge(cfg, sender=sender)
    p_cam, q_cam = camera_pose(on_axis(40.0))
    for stamp in (1.0, 1.125):
        bridge.on_tracker_state(TRACKER_TRACKING, stamp)
        assert bridge.on_pose(stamp, p_cam, q_cam, COV, now_s=stamp)
        if stamp == 1.0:
            assert "ODOMETRY" in bridge.tick(1.0).sent
    assert "ODOMETRY" not in bridge.tick(1.1875 - 2.0**-20).sent
    assert "ODOMETRY" in bridge.tick(1.1875).sent and sender.poses[-1][0] == 1.125


def test_a_pose_already_sent_is_not_sent_again_when_the_link_is_back(bridge):
    """After an outage the heartbeat and the stage go out again, not a position already sent."""
    _tracked_pose_at(bridge)
    bridge.on_tracker_state(TRACKER_TRACKING, 1.0)
    assert "ODOMETRY" in bridge.tick(1.01).sent
    bridge.sender.poll = lambda: True
    assert bridge.tick(1.2).sent == ("HEARTBEAT", "STATUSTEXT")  # the pose is still fresh
    assert len(bridge.sender.poses) == 1


def test_a_pose_exactly_the_clock_lead_tolerance_ahead_is_taken(bridge):
    """Refused only when more than 0.05 s ahead of the clock (0.05 − 0 is exact)."""
    p_cam, q_cam = camera_pose(on_axis(40.0))
    assert bridge.on_pose(0.05, p_cam, q_cam, COV, now_s=0.0)
