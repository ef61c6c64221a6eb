"""Error statistics, scoring, lost frames and the JSON summary against direct numpy computations,
scipy and hand-made cases."""

import json

import numpy as np
import pytest
from matplotlib.cbook import boxplot_stats
from scipy.spatial.transform import Rotation

from uav_landing_vision.evaluation import (
    STAT_KEYS,
    TRANSLATION_COLUMNS,
    SummaryError,
    align,
    error_statistics,
    format_errors_by_depth,
    format_table,
    load_summary,
    make_summary,
    plot_errors,
    pose_errors,
    save_summary,
    score,
    score_files,
    statistics_table,
    validate_summary,
    variant_summary,
    write_report,
)
from uav_landing_vision.evaluation.report import lost_frames_pct
from uav_landing_vision.geometry import euler_zyx_to_quat
from uav_landing_vision.sim import Poses


def test_statistics_match_numpy():
    v = np.random.default_rng(0).standard_normal(1001) * 2.0 + 0.5
    s = error_statistics(v)
    q1, q3 = np.percentile(v, [25, 75])
    assert s["p5"] == pytest.approx(np.percentile(v, 5))
    assert s["median"] == pytest.approx(np.median(v))
    assert s["p95"] == pytest.approx(np.percentile(v, 95))
    assert s["mae"] == pytest.approx(np.abs(v).mean())
    assert s["rmse"] == pytest.approx(np.sqrt(np.mean(v**2)))
    assert s["sd"] == pytest.approx(np.std(v, ddof=1))
    assert (s["p25"], s["p75"]) == pytest.approx((q1, q3))
    assert s["outlier_pct"] == pytest.approx(100 * len(boxplot_stats(v)[0]["fliers"]) / len(v))  # Tukey's fences
    assert s["outlier_pct"] > 0 and s["rmse"] >= s["mae"]


def test_values_on_the_fences_are_not_outliers():
    """Tukey's fences (matplotlib's box-plot whiskers): outliers lie beyond q1 − 1.5 IQR or q3 + 1.5 IQR."""
    on = [-1.0, 2.0, 3.0, 4.0, 7.0]  # q1 = 2, q3 = 4: the fences are −1 and 7
    assert len(boxplot_stats(on)[0]["fliers"]) == 0 and error_statistics(on)["outlier_pct"] == 0.0
    beyond = [-1.001, 2.0, 3.0, 4.0, 7.001]
    assert len(boxplot_stats(beyond)[0]["fliers"]) == 2 and error_statistics(beyond)["outlier_pct"] == 40.0


def test_hand_made_outliers_and_values():
    s = error_statistics([1, 2, 3, 4, 100])  # q1=2, q3=4 → fences −1, 7: one outlier of five
    assert s["outlier_pct"] == pytest.approx(20.0)
    assert s["median"] == 3.0
    assert s["mae"] == pytest.approx(22.0)
    assert s["rmse"] == pytest.approx(np.sqrt((1 + 4 + 9 + 16 + 10000) / 5))
    assert s["sd"] == pytest.approx(np.std([1, 2, 3, 4, 100], ddof=1))


def test_nan_values_are_dropped_and_all_nan_gives_nan():
    assert error_statistics([1.0, np.nan, 3.0])["median"] == 2.0
    assert np.isnan(error_statistics([np.nan])["mae"])


def test_pose_errors_flip_antipodal_and_translation():
    q = euler_zyx_to_quat(np.radians([[10, 20, 30], [0, 0, 0], [0, 0, 0]]))
    flip = np.array([[0, 0, 1.0, 0]])  # 180° about z
    q_est = np.concatenate([-q[:1], flip, euler_zyx_to_quat(np.radians([[0, 0, 5]]))])
    t = np.zeros((3, 3))
    t_est = np.array([[3.0, 4.0, 0.0], [0, 0, 0], [0, 0, -1.0]])
    e = pose_errors(t, q, t_est, q_est)
    assert e["geodesic"][0] == pytest.approx(0.0, abs=1e-6)  # antipodal quaternion: same rotation
    assert e["geodesic"][1] == pytest.approx(180.0)
    assert abs(e["gamma"][1]) == pytest.approx(180.0)
    assert e["geodesic"][2] == pytest.approx(5.0)
    assert e["gamma"][2] == pytest.approx(-5.0)  # q_e = q_g ⊗ q̄_r (6.4)
    assert e["euclidean"].tolist() == pytest.approx([5.0, 0.0, 1.0])
    assert e["z"][2] == -1.0


def test_score_aligns_by_stamp_and_counts_lost_frames():
    truth = Poses(np.array([10, 20, 30, 40]), np.zeros((4, 3)), np.tile([0, 0, 0, 1.0], (4, 1)))
    est = Poses(np.array([40, 20, 99]), np.array([[1.0, 0, 0], [0, 2.0, 0], [9, 9, 9]]),
                euler_zyx_to_quat(np.radians([[0, 0, 10], [0, 0, 20], [0, 0, 30]])))
    assert np.isnan(align(truth, est).trans[0]).all()
    err = score(truth, est)
    assert np.isnan(err["euclidean"][[0, 2]]).all()
    assert err["euclidean"][[1, 3]].tolist() == [2.0, 1.0]
    np.testing.assert_allclose(err["geodesic"][[1, 3]], [20.0, 10.0])  # each pose's own orientation
    summary = variant_summary(err, 12.5)
    assert summary["lost_frames_pct"] == 50.0
    assert summary["translation_m"]["median"] == 1.5


def test_a_pose_without_a_finite_orientation_is_lost_in_every_column():
    q = np.tile([0, 0, 0, 1.0], (3, 1))
    q_est = q.copy()
    q_est[1] = np.nan
    t_est = np.ones((3, 3))
    t_est[1] = [10.0, 0.0, 0.0]
    e = pose_errors(np.zeros((3, 3)), q, t_est, q_est)
    assert all(np.isnan(e[c][1]) and np.isfinite(e[c][0]) for c in e)
    summary = variant_summary(e)
    assert summary["lost_frames_pct"] == pytest.approx(100 / 3)
    assert summary["translation_m"]["p5"] == summary["translation_m"]["p95"] == pytest.approx(np.sqrt(3))


def test_unusable_poses_and_times_are_refused_naming_where(tmp_path):
    from uav_landing_vision.evaluation.score import mean_ms_per_frame

    quat = np.tile([0, 0, 0, 1.0], (3, 1))
    truth = Poses(np.array([10, 20, 30]), np.zeros((3, 3)), quat)
    zero = quat.copy()
    zero[1] = 0.0
    with pytest.raises(ValueError, match=r"the estimate has no usable pose .* at stamp\(s\) \[20\]"):
        score(truth, Poses(truth.stamps_ns, np.zeros((3, 3)), zero))
    with pytest.raises(ValueError, match=r"the ground truth has no usable pose .* at stamp\(s\) \[20\]"):
        score(Poses(truth.stamps_ns, np.array([[0, 0, 1.0], [np.nan, 0, 1], [0, 0, 1]]), quat), truth)
    lost = quat.copy()
    lost[1] = np.nan
    assert np.isnan(score(truth, Poses(truth.stamps_ns, np.zeros((3, 3)), lost))["geodesic"][1])
    with pytest.raises(ValueError, match=r"none of the estimate's 3 stamps is a ground-truth stamp \(first 15 ns"):
        score(truth, Poses(truth.stamps_ns + 5, np.zeros((3, 3)), quat))  # a clock 5 ns off
    assert np.isnan(score(truth, Poses(np.array([20, 35]), np.zeros((2, 3)), quat[:2]))["geodesic"][[0, 2]]).all()
    path = tmp_path / "est.csv"
    path.write_text("stamp_ns,x,y,z,qx,qy,qz,qw,ms\n10,0,0,5,0,0,0,1,12.5\n20,0,0,5,0,0,0,1,slow\n")
    with pytest.raises(ValueError, match=r"est.csv: line 3: ms 'slow' is not a number"):
        mean_ms_per_frame(path)
    path.write_text("stamp_ns,x,y,z,qx,qy,qz,qw,ms\n10,0,0,5,0,0,0,1,10\n20,0,0,5,0,0,0,1,\n30,0,0,5,0,0,0,1,20\n"
                    "40,0,0,5,0,0,0,1,60\n")
    assert mean_ms_per_frame(path) == 30.0  # the mean of the frames that give one
    assert mean_ms_per_frame(tmp_path / "est.bag") is None  # a bag holds no times


def test_align_takes_an_empty_truth_and_refuses_repeated_estimate_stamps():
    quat = np.tile([0, 0, 0, 1.0], (2, 1))
    est = Poses(np.array([10, 20]), np.zeros((2, 3)), quat)
    empty = align(Poses(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 4))), est)
    assert empty.trans.shape == (0, 3) and empty.quat.shape == (0, 4)
    with pytest.raises(ValueError, match=r"more than one pose at stamp\(s\) \[20\]"):
        align(Poses(np.array([10, 20]), np.zeros((2, 3)), quat), Poses(np.array([20, 10, 20]), np.zeros((3, 3)),
                                                                        np.tile([0, 0, 0, 1.0], (3, 1))))


def test_summary_schema_roundtrip_and_rejection(tmp_path):
    err = pose_errors(np.zeros((5, 3)), np.tile([0, 0, 0, 1.0], (5, 1)), np.ones((5, 3)), np.tile([0, 0, 0, 1.0], (5, 1)))
    doc = make_summary("seq", 5, {"C4N2": variant_summary(err)})
    save_summary(tmp_path / "s.json", doc)
    assert load_summary(tmp_path / "s.json") == json.loads((tmp_path / "s.json").read_text()) == doc
    assert set(doc["variants"]["C4N2"]["translation_m"]) == set(STAT_KEYS)
    bad = json.loads(json.dumps(doc))
    del bad["variants"]["C4N2"]["rotation_deg"]["sd"]
    with pytest.raises(SummaryError):
        validate_summary(bad)
    for frames in ("5", True, -1, 5.0):
        with pytest.raises(SummaryError, match="frames: a non-negative int"):
            validate_summary({"sequence": "s", "frames": frames, "variants": {}})
    for change in (lambda d: d.update(extra=1), lambda d: d["variants"]["C4N2"]["translation_m"].update(median="x"),
                   lambda d: d["variants"]["C4N2"].update(ms_per_frame="5")):
        bad = json.loads(json.dumps(doc))
        change(bad)
        with pytest.raises(SummaryError):
            validate_summary(bad)


def test_tables_csv_and_plots(tmp_path):
    rng = np.random.default_rng(1)
    errs = {name: pose_errors(np.zeros((50, 3)), np.tile([0, 0, 0, 1.0], (50, 1)), rng.normal(size=(50, 3)),
                              euler_zyx_to_quat(rng.normal(0, 0.1, (50, 3)))) for name in ("C4N2", "C5N5")}
    text = format_table(statistics_table(errs, ("euclidean",)), "title")
    assert "Outlier %" in text and "C5N5" in text
    errs["C5N5"]["euclidean"][:10] = np.nan  # ten lost frames: left out of the statistics, and said so
    errs["C5N5"]["geodesic"][:10] = np.nan
    report = write_report(tmp_path, "seq", errs)
    assert "rotation error (deg)" in report
    assert "C4N2: statistics over 50 of 50 frames (0.0 % lost)" in report
    assert "C5N5: statistics over 40 of 50 frames (20.0 % lost)" in report
    for name in ("translation_error.csv", "rotation_error.csv", "translation_error.png", "rotation_error.png"):
        assert (tmp_path / name).stat().st_size > 0
    header = (tmp_path / "translation_error.csv").read_text().splitlines()[0]
    assert header.split(",")[:3] == ["statistic", "C4N2 Euclidean", "C4N2 X"]


def test_absurd_errors_are_left_out_of_the_plots(tmp_path):
    """Errors of ±1e308 (a diverged estimate) made matplotlib fail, and the evaluator lost its report."""
    err = {"C4N2": {col: np.array([1e308, -1e308, 1.0]) for col in TRANSLATION_COLUMNS}}
    plot_errors(tmp_path / "t.png", err, TRANSLATION_COLUMNS, "m")
    assert (tmp_path / "t.png").stat().st_size > 0


def test_a_name_with_dollar_signs_is_drawn_as_written(tmp_path):
    """A variant named ``a$\\bad$`` (the evaluator's free-text parameter) failed as TeX in the
    legend, and the evaluator lost its report; a bag so named failed eval-detector's curve."""
    from uav_landing_vision.detection.evaluation import plot_pr

    err = {"a$\\bad$": {col: np.array([0.5, 1.0]) for col in TRANSLATION_COLUMNS}}
    plot_errors(tmp_path / "t.png", err, TRANSLATION_COLUMNS, "m")
    plot_pr({"curve": {"recall": [0.0, 1.0], "precision": [1.0, 0.5]}, "ap50": 0.75}, tmp_path / "pr.png", "b$\\x$")
    assert (tmp_path / "t.png").stat().st_size > 0 and (tmp_path / "pr.png").stat().st_size > 0
    import matplotlib.pyplot as plt

    from uav_landing_vision.evaluation.report import plot_text

    fig, ax = plt.subplots()  # matplotlib leaves a label starting with "_" out of the legend
    for name in ("_baseline", "C4N2"):
        ax.plot([0, 1], label=plot_text(name))
    assert [t.get_text().lstrip("\u200b") for t in ax.legend().get_texts()] == ["_baseline", "C4N2"]
    plt.close(fig)


def test_median_errors_by_depth_hand_made():
    depth = np.array([5.0, 6.0, 7.0, 20.0, 25.0, 70.0])
    a = {"euclidean": np.array([0.1, 0.3, 0.2, 1.0, np.nan, 4.0]),
         "geodesic": np.array([1.0, 3.0, 2.0, 5.0, 7.0, 9.0])}  # frame 4 lost (no position)
    b = {"euclidean": np.full(6, np.nan), "geodesic": np.full(6, np.nan)}  # lost throughout
    text = format_errors_by_depth({"C4N2": a, "C3N0": b}, depth, "seq", bins=(0.0, 8.0, 60.0, np.inf))
    rows = {line[:16].strip(): line[16:] for line in text.splitlines()[2:]}
    assert list(rows) == ["0-8 m", "8-60 m", "60+ m", "all"]
    assert rows["0-8 m"].split("- (0)")[0].strip() == "0.20 | 2.00 (3)"
    assert "1.00 | 5.00 (1)" in rows["8-60 m"] and "4.00 | 9.00 (1)" in rows["60+ m"]
    assert "0.30 | 3.00 (5)" in rows["all"] and rows["all"].rstrip().endswith("- (0)")


def test_undefined_statistics_are_null_in_the_file_and_nan_when_read_back(tmp_path):
    """The file was written with bare NaN tokens, which JSON.parse, jq and strict parsers refuse."""
    one = pose_errors(np.zeros((1, 3)), np.tile([0, 0, 0, 1.0], (1, 1)), np.ones((1, 3)), np.tile([0, 0, 0, 1.0], (1, 1)))
    lost = pose_errors(np.zeros((1, 3)), np.tile([0, 0, 0, 1.0], (1, 1)), np.full((1, 3), np.nan), np.full((1, 4), np.nan))
    doc = make_summary("seq", 1, {"one": variant_summary(one), "lost": variant_summary(lost)})
    save_summary(tmp_path / "s.json", doc)
    strict = json.loads((tmp_path / "s.json").read_text(), parse_constant=lambda c: pytest.fail(f"non-JSON {c}"))
    assert strict["variants"]["one"]["translation_m"]["sd"] is None
    assert strict["variants"]["one"]["translation_m"]["median"] == pytest.approx(np.sqrt(3))
    assert all(x is None for x in strict["variants"]["lost"]["rotation_deg"].values())
    back = load_summary(tmp_path / "s.json")
    assert np.isnan(back["variants"]["one"]["translation_m"]["sd"]) and np.isnan(back["variants"]["lost"]["translation_m"]["mae"])
    assert back["variants"]["lost"]["lost_frames_pct"] == 100.0
    doc["variants"]["one"]["ms_per_frame"] = float("nan")  # a times column with a NaN: the file was not written
    save_summary(tmp_path / "t.json", doc)
    assert json.loads((tmp_path / "t.json").read_text())["variants"]["one"]["ms_per_frame"] is None


def test_an_overflowing_statistic_is_null_in_the_file_and_infinite_errors_are_left_out(tmp_path):
    """Errors near 1e200 m overflow the RMSE to inf: the summary must still be written."""
    huge = pose_errors(np.zeros((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1)), np.array([[1e200, 0, 0], [2e200, 0, 0]]),
                       np.tile([0, 0, 0, 1.0], (2, 1)))
    doc = make_summary("seq", 2, {"far": variant_summary(huge)})
    assert not np.isfinite(doc["variants"]["far"]["translation_m"]["rmse"])
    save_summary(tmp_path / "s.json", doc)
    assert json.loads((tmp_path / "s.json").read_text())["variants"]["far"]["translation_m"]["rmse"] is None
    assert error_statistics([1.0, 2.0, 3.0, np.inf]) == error_statistics([1.0, 2.0, 3.0])


def test_a_frame_without_a_position_has_no_error_in_any_column():
    t_est = np.zeros((2, 3))
    t_est[0, 0] = np.nan
    err = pose_errors(np.zeros((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1)), t_est, np.tile([0, 0, 0, 1.0], (2, 1)))
    assert all(np.isnan(err[c][0]) and np.isfinite(err[c][1]) for c in err)


def test_one_value_has_no_sample_standard_deviation():
    """SD (n − 1) of a single error is undefined, not a spread of zero (numpy gives NaN too)."""
    s = error_statistics([np.nan, 2.5])
    assert s["median"] == s["mae"] == s["rmse"] == 2.5
    assert np.isnan(s["sd"])
    assert error_statistics([2.5, 3.5])["sd"] == pytest.approx(np.std([2.5, 3.5], ddof=1))


def test_pose_errors_and_statistics_match_scipy():
    from scipy import stats
    from scipy.spatial.transform import Rotation

    from uav_landing_vision.evaluation.consistency import depth_bins

    rng = np.random.default_rng(4)
    q_true, q_est = Rotation.random(40, random_state=5), Rotation.random(40, random_state=6)
    t_true = rng.normal(size=(40, 3)) * 10.0
    t_est = t_true + rng.normal(size=(40, 3))
    err = pose_errors(t_true, q_true.as_quat(), t_est, q_est.as_quat())
    np.testing.assert_allclose(err["geodesic"], np.degrees((q_true.inv() * q_est).magnitude()), atol=1e-9)
    euler = np.degrees((q_true * q_est.inv()).as_euler("ZYX"))  # (6.4): q_e = q_g ⊗ q̄_r, [γ, β, α]
    np.testing.assert_allclose(np.c_[err["alpha"], err["beta"], err["gamma"]], euler[:, ::-1], atol=1e-9)
    np.testing.assert_allclose(err["euclidean"], np.linalg.norm(t_est - t_true, axis=1))
    s = error_statistics(err["x"])
    np.testing.assert_allclose([s[k] for k in ("p5", "p25", "median", "p75", "p95")],
                               stats.scoreatpercentile(err["x"], [5, 25, 50, 75, 95]))
    np.testing.assert_allclose([s["sd"], s["rmse"]], [stats.tstd(err["x"]), np.sqrt(np.mean(err["x"] ** 2))])
    depth = np.array([0.0, 7.999, 8.0, 15.0, 29.99, 30.0, 60.0, 1e9])
    assert [depth[m].tolist() for _, m in depth_bins(depth)] == [
        [0.0, 7.999], [8.0], [15.0, 29.99], [30.0], [60.0, 1e9], depth.tolist()]  # bins are [lo, hi)


# --- scoring, lost frames and the summary, case by case -------------------------------------------

IDENTITY = [0.0, 0.0, 0.0, 1.0]


def _summary_doc():
    err = pose_errors(np.zeros((3, 3)), np.tile(IDENTITY, (3, 1)), np.ones((3, 3)), np.tile(IDENTITY, (3, 1)))
    return make_summary("seq", 3, {"C4N2": variant_summary(err, 10.0)})


# --- score -----------------------------------------------------------------------------------


def test_score_refuses_a_ground_truth_without_a_finite_orientation():
    """A ground-truth pose whose quaternion is not finite is no reference: it is refused, not
    counted as a frame the tracker lost."""
    quat = np.tile(IDENTITY, (3, 1))
    bad = quat.copy()
    bad[1] = [np.nan, 0.0, 0.0, 1.0]
    truth = Poses(np.array([10, 20, 30]), np.zeros((3, 3)), bad)
    with pytest.raises(ValueError, match=r"the ground truth has no usable pose .* at stamp\(s\) \[20\]"):
        score(truth, Poses(truth.stamps_ns, np.zeros((3, 3)), quat))
    bad[1] = [np.inf, 0.0, 0.0, 1.0]
    with pytest.raises(ValueError, match=r"the ground truth has no usable pose .* at stamp\(s\) \[20\]"):
        score(Poses(truth.stamps_ns, np.zeros((3, 3)), bad), Poses(truth.stamps_ns, np.zeros((3, 3)), quat))


def test_score_of_an_empty_ground_truth_has_no_frames():
    """No ground-truth frame: no per-frame error, whatever the estimate holds."""
    est = Poses(np.array([10, 20]), np.zeros((2, 3)), np.tile(IDENTITY, (2, 1)))
    err = score(Poses(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 4))), est)
    assert all(v.shape == (0,) for v in err.values())


def test_score_files_returns_the_mean_time_per_frame_of_an_estimate_csv(tmp_path):
    (tmp_path / "truth.csv").write_text("stamp_ns,x,y,z,qx,qy,qz,qw\n10,0,0,5,0,0,0,1\n20,0,0,6,0,0,0,1\n")
    (tmp_path / "est.csv").write_text("stamp_ns,x,y,z,qx,qy,qz,qw,ms\n10,0,0,5.5,0,0,0,1,10\n20,0,0,6,0,0,0,1,30\n")
    err, ms = score_files(tmp_path / "truth.csv", tmp_path / "est.csv")
    assert ms == pytest.approx(20.0)
    np.testing.assert_allclose(err["euclidean"], [0.5, 0.0])


def test_score_files_reads_the_estimate_of_a_bag_from_the_uav_pose_topic_by_default(tmp_path):
    """One bag holding the ground truth (/uav/ground_truth) and the tracker's output (/uav/pose):
    without a topic, the estimate is /uav/pose, not the ground truth scored against itself."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    m = ts.types

    def pose_msg(stamp_ns, z):
        header = m["std_msgs/msg/Header"](stamp=m["builtin_interfaces/msg/Time"](sec=0, nanosec=stamp_ns),
                                          frame_id="camera")
        pose = m["geometry_msgs/msg/Pose"](position=m["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=z),
                                           orientation=m["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
        return m["geometry_msgs/msg/PoseStamped"](header=header, pose=pose)

    bag = tmp_path / "run"
    with Writer(bag, version=9) as writer:
        conns = {t: writer.add_connection(t, "geometry_msgs/msg/PoseStamped", typestore=ts)
                 for t in ("/uav/ground_truth", "/uav/pose")}
        for k, stamp in enumerate((1000, 2000)):
            writer.write(conns["/uav/ground_truth"], stamp, ts.serialize_cdr(pose_msg(stamp, 10.0 + k), "geometry_msgs/msg/PoseStamped"))
            writer.write(conns["/uav/pose"], stamp, ts.serialize_cdr(pose_msg(stamp, 10.5 + k), "geometry_msgs/msg/PoseStamped"))
    err, ms = score_files(bag, bag)
    np.testing.assert_allclose(err["z"], [0.5, 0.5])
    assert ms is None  # a bag holds no times


# --- per-frame errors and statistics -----------------------------------------------------------


def test_pose_errors_give_each_signed_coordinate_difference_its_own_column():
    t_true = np.array([[1.0, 2.0, 3.0]])
    t_est = np.array([[1.5, 4.0, 2.0]])
    err = pose_errors(t_true, np.array([IDENTITY]), t_est, np.array([IDENTITY]))
    assert (err["x"][0], err["y"][0], err["z"][0]) == pytest.approx((0.5, 2.0, -1.0))
    assert err["euclidean"][0] == pytest.approx(np.sqrt(0.25 + 4.0 + 1.0))


def test_an_orientation_with_one_missing_component_is_lost_in_every_column():
    q = np.tile(IDENTITY, (2, 1))
    q_est = q.copy()
    q_est[0] = [0.0, np.nan, 0.0, 1.0]
    err = pose_errors(np.zeros((2, 3)), q, np.ones((2, 3)), q_est)
    assert all(np.isnan(err[c][0]) and np.isfinite(err[c][1]) for c in err)


def test_outlier_share_is_over_the_scored_values_not_the_lost_ones():
    """Tukey's fences over the finite values: one outlier of five is 20 %, however many NaNs
    (lost frames) the series also holds."""
    values = [1.0, 2.0, 3.0, 4.0, 100.0]
    assert error_statistics(values + [np.nan] * 5)["outlier_pct"] == pytest.approx(20.0)
    assert error_statistics(values + [np.nan] * 5) == error_statistics(values)


def test_a_one_column_table_is_named_by_the_variant_alone_and_several_by_variant_and_axis():
    err = pose_errors(np.zeros((2, 3)), np.tile(IDENTITY, (2, 1)), np.ones((2, 3)), np.tile(IDENTITY, (2, 1)))
    errs = {"C4N2": err, "C5N5": err}
    assert list(statistics_table(errs, ("euclidean",))) == ["C4N2", "C5N5"]
    assert list(statistics_table(errs, ("euclidean", "x"))) == ["C4N2 Euclidean", "C4N2 X", "C5N5 Euclidean", "C5N5 X"]


# --- lost frames ---------------------------------------------------------------------------


def test_a_frame_without_either_error_counts_as_lost():
    """Lost: no translation error or no rotation error (either one missing is enough)."""
    errors = {"euclidean": np.array([1.0, np.nan, 1.0, np.nan]), "geodesic": np.array([2.0, 2.0, np.nan, np.nan])}
    assert lost_frames_pct(errors) == pytest.approx(75.0)
    assert variant_summary(errors)["lost_frames_pct"] == pytest.approx(75.0)


def test_no_frames_means_no_lost_frames_and_the_summary_is_still_written(tmp_path):
    empty = pose_errors(np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 3)), np.zeros((0, 4)))
    assert lost_frames_pct(empty) == 0.0
    save_summary(tmp_path / "s.json", make_summary("seq", 0, {"C4N2": variant_summary(empty)}))
    assert json.loads((tmp_path / "s.json").read_text())["variants"]["C4N2"]["lost_frames_pct"] == 0.0


def test_median_by_depth_leaves_out_a_frame_without_a_rotation_error():
    depth = np.array([5.0, 6.0, 7.0])
    err = {"euclidean": np.array([0.1, 0.2, 9.0]), "geodesic": np.array([1.0, 3.0, np.nan])}
    text = format_errors_by_depth({"C4N2": err}, depth, "seq", bins=(0.0, 8.0, np.inf))
    row = next(line for line in text.splitlines() if line.startswith("0-8 m"))
    assert row[16:].strip() == "0.15 | 2.00 (2)"


# --- JSON summary ------------------------------------------------------------------------------


def test_the_summary_rotation_is_the_geodesic_error():
    """rotation_deg: the geodesic angle (3.3), not one Euler component."""
    q_est = Rotation.from_euler("ZYX", [[0.0, 0.0, 10.0], [0.0, 0.0, 20.0], [0.0, 0.0, 30.0]], degrees=True).as_quat()
    err = pose_errors(np.zeros((3, 3)), np.tile(IDENTITY, (3, 1)), np.zeros((3, 3)), q_est)
    summary = variant_summary(err)
    assert summary["rotation_deg"]["median"] == pytest.approx(20.0)
    assert summary["rotation_deg"]["mae"] == pytest.approx(20.0)


def test_the_summary_carries_the_time_per_frame_given():
    err = pose_errors(np.zeros((1, 3)), np.array([IDENTITY]), np.ones((1, 3)), np.array([IDENTITY]))
    assert variant_summary(err, 12.5)["ms_per_frame"] == 12.5
    assert variant_summary(err)["ms_per_frame"] is None


@pytest.mark.parametrize("change", [
    lambda d: d.update(sequence=5),
    lambda d: d.update(variants=[]),
    lambda d: d["variants"]["C4N2"].update(lost_frames_pct="5"),
    lambda d: d["variants"]["C4N2"].update(lost_frames_pct=5),
    lambda d: d["variants"]["C4N2"].update(extra=1.0),
], ids=["sequence-not-str", "variants-not-mapping", "lost-str", "lost-int", "extra-variant-key"])
def test_a_summary_off_the_schema_is_refused(change):
    bad = json.loads(json.dumps(_summary_doc()))
    validate_summary(json.loads(json.dumps(bad)))  # valid before the change
    change(bad)
    with pytest.raises(SummaryError):
        validate_summary(bad)


def test_save_summary_refuses_a_document_off_the_schema_and_writes_nothing(tmp_path):
    bad = _summary_doc()
    bad["variants"]["C4N2"]["lost_frames_pct"] = "none"
    with pytest.raises(SummaryError):
        save_summary(tmp_path / "s.json", bad)
    assert not (tmp_path / "s.json").exists()


def test_strict_json_writes_every_non_finite_float_as_null_in_mappings_lists_and_tuples():
    from uav_landing_vision.evaluation.report import strict_json

    doc = {"a": float("nan"), "b": (1.5, float("inf")), "c": [float("-inf"), {"d": float("nan")}], "e": 2}
    assert json.loads(strict_json(doc)) == {"a": None, "b": [1.5, None], "c": [None, {"d": None}], "e": 2}


# --- report files ------------------------------------------------------------------------------


def test_write_report_ends_the_tables_with_the_appendix(tmp_path):
    from uav_landing_vision.evaluation import write_report

    err = pose_errors(np.zeros((4, 3)), np.tile(IDENTITY, (4, 1)), np.ones((4, 3)), np.tile(IDENTITY, (4, 1)))
    text = write_report(tmp_path, "seq", {"C4N2": err}, appendix="coverage table here")
    assert text.endswith("coverage table here")
    assert (tmp_path / "tables.txt").read_text().rstrip().endswith("coverage table here")


def test_plots_leave_out_errors_beyond_the_limit_on_either_side_and_say_how_many(monkeypatch, tmp_path):
    import matplotlib.figure

    from uav_landing_vision.evaluation import plot_errors

    drawn = {}

    def record(fig, path, *args, **kwargs):
        ax = fig.axes[0]
        drawn["title"] = ax.get_title()
        drawn["y"] = np.asarray(ax.lines[0].get_ydata(), float)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", record)
    plot_errors(tmp_path / "t.png", {"C4N2": {"x": np.array([1e7, -1e7, 2.0, -3.0])}}, ("x",), "m")
    assert "(2 beyond" in drawn["title"]
    np.testing.assert_array_equal(np.isnan(drawn["y"]), [True, True, False, False])


@pytest.mark.parametrize("text", ["5", "null", "[1, 2]"])
def test_a_summary_file_that_is_not_an_object_is_refused_as_off_the_schema(tmp_path, text):
    from uav_landing_vision.evaluation import load_summary

    (tmp_path / "s.json").write_text(text)
    with pytest.raises(SummaryError):
        load_summary(tmp_path / "s.json")


def test_align_gives_one_row_per_ground_truth_stamp_in_the_truth_s_order():
    """Rows follow the ground truth, stamps included: an estimate in another order and with a
    frame missing is put under the truth's stamps, NaN where it has none."""
    truth = Poses(np.array([10, 20, 30]), np.zeros((3, 3)), np.tile(IDENTITY, (3, 1)))
    est = Poses(np.array([30, 10]), np.array([[3.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), np.tile(IDENTITY, (2, 1)))
    aligned = align(truth, est)
    assert aligned.stamps_ns.tolist() == [10, 20, 30]
    np.testing.assert_array_equal(aligned.trans[[0, 2], 0], [1.0, 3.0])
    assert np.all(np.isnan(aligned.trans[1])) and np.all(np.isnan(aligned.quat[1]))


def test_refusals_name_the_first_three_offending_stamps():
    """Repeated estimate stamps and unusable poses are named, up to three of them."""
    quat = np.tile(IDENTITY, (4, 1))
    stamps = np.array([10, 20, 30, 40])
    with pytest.raises(ValueError, match=r"more than one pose at stamp\(s\) \[10, 20, 30\]; give one"):
        align(Poses(stamps, np.zeros((4, 3)), quat), Poses(np.repeat(stamps, 2), np.zeros((8, 3)), np.tile(IDENTITY, (8, 1))))
    with pytest.raises(ValueError, match=r"the estimate has no usable pose .* at stamp\(s\) \[10, 20, 30\]$"):
        score(Poses(stamps, np.zeros((4, 3)), quat), Poses(stamps, np.zeros((4, 3)), np.zeros((4, 4))))


def test_a_vanishing_quaternion_is_refused_like_a_zero_one():
    """A quaternion of norm 1e-13 is a zero one up to rounding (no estimator writes a unit
    quaternion so short): no usable pose, though it would normalise to a rotation."""
    quat = np.tile(IDENTITY, (2, 1))
    tiny = quat.copy()
    tiny[1] = [0.0, 0.0, 1e-13, 0.0]
    with pytest.raises(ValueError, match=r"the estimate has no usable pose .* at stamp\(s\) \[20\]"):
        score(Poses(np.array([10, 20]), np.zeros((2, 3)), quat), Poses(np.array([10, 20]), np.zeros((2, 3)), tiny))


def test_an_estimate_pose_at_a_stamp_without_ground_truth_is_not_scored_however_unusable():
    """Only the ground-truth frames are scored: a zero quaternion at an extra stamp of the
    estimate (a frame the truth does not cover) neither stops scoring nor changes the errors."""
    truth = Poses(np.array([10, 20]), np.zeros((2, 3)), np.tile(IDENTITY, (2, 1)))
    quat = np.array([IDENTITY, [0.0, 0.0, 0.0, 0.0], IDENTITY])
    est = Poses(np.array([10, 15, 20]), np.array([[1.0, 0.0, 0.0], [9.0, 9.0, 9.0], [0.0, 2.0, 0.0]]), quat)
    assert score(truth, est)["euclidean"].tolist() == [1.0, 2.0]


def test_an_estimate_csv_without_times_has_no_mean_time(tmp_path):
    """No ``ms`` column, or one left empty on every row: the time per frame is unknown (None), not 0 ms."""
    from uav_landing_vision.evaluation.score import mean_ms_per_frame

    path = tmp_path / "est.csv"
    path.write_text("stamp_ns,x,y,z,qx,qy,qz,qw\n10,0,0,5,0,0,0,1\n")
    assert mean_ms_per_frame(path) is None
    path.write_text("stamp_ns,x,y,z,qx,qy,qz,qw,ms\n10,0,0,5,0,0,0,1,\n20,0,0,5,0,0,0,1,\n")
    assert mean_ms_per_frame(path) is None
