"""User mistakes on the command line: a one-line ``uav-landing <command>: <message>``, no traceback,
and nothing left behind that looks like a result."""

import dataclasses
import os
import re
import subprocess
import sys

import numpy as np
import pytest
import trimesh
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from uav_landing_vision.cli import main
from uav_landing_vision.model import fixed_wing_mesh
from uav_landing_vision.sim import load_scenario, simulate

_TS = get_typestore(Stores.ROS2_JAZZY)


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    """A one-frame simulated bag, the same without its ground truth, and one without messages."""
    root = tmp_path_factory.mktemp("bags")
    s = load_scenario("normal")
    s = dataclasses.replace(s, approach=dataclasses.replace(s.approach, start_range_m=(12.0, 14.0)))
    simulate(s, root / "full", frames=1, progress=False, mesh=fixed_wing_mesh("low"))
    for name, dropped, messages in (("no_truth", "/uav/ground_truth", True), ("empty", "", False)):
        writer = Writer(root / name, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP)
        writer.open()
        with Reader(root / "full") as reader:
            conns = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=_TS)
                     for c in reader.connections if c.topic != dropped}
            for conn, stamp, raw in reader.messages() if messages else ():
                if conn.id in conns:
                    writer.write(conns[conn.id], stamp, raw)
        writer.close()
    return root


def _refused(argv, message):
    with pytest.raises(SystemExit, match=f"^uav-landing {argv[0]}: {message}"):
        main(argv)


def test_simulate_refuses_bad_options_and_camera_files(tmp_path, monkeypatch):
    out = tmp_path / "bag"
    (tmp_path / "png").mkdir()
    with monkeypatch.context() as patch:  # the options are checked before the run; the camera files by it
        _never_run(patch)
        _refused(["simulate", "--out", str(tmp_path / "png")],
                 re.escape(f"--out {tmp_path / 'png'} exists already; give a new directory"))
        _refused(["simulate", "--out", str(out), "--frames", "0"], "--frames must be at least 1")
        _refused(["simulate", "--out", str(out), "--frames", "1", "--png-dir", str(tmp_path / "png")],
                 re.escape(f"--png-dir {tmp_path / 'png'} exists already"))
        _refused(["simulate", "--out", str(out), "--frames", "1", "--seed", "-1"], "--seed must be non-negative")
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text(f"approach: {{}}\ncamera_info: {tmp_path / 'nosuch.yaml'}\n")
    _refused(["simulate", "--scenario", str(scenario), "--out", str(out), "--frames", "1"],
             "config file '.*nosuch.yaml' not found")
    (tmp_path / "bad_camera.yaml").write_text("image_width: abc\n")
    scenario.write_text(f"approach: {{}}\ncamera_info: {tmp_path / 'bad_camera.yaml'}\n")
    _refused(["simulate", "--scenario", str(scenario), "--out", str(out), "--frames", "1"],
             ".*bad_camera.yaml: 'camera_matrix' must be a mapping")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad_camera.yaml", "png", "scenario.yaml"]


def test_boosting_commands_refuse_missing_and_degenerate_inputs(tmp_path):
    out = str(tmp_path / "db.npz")
    _refused(["build-database", "--out", out, "--count", "2", "--camera", str(tmp_path / "nosuch.yaml")],
             "cannot read camera calibration")
    (tmp_path / "line.obj").write_text("v -0.5 0 0\nv 0.5 0 0\nv 1.0 0 0\nf 1 2 3\n")
    _refused(["build-database", "--out", out, "--count", "2", "--model", str(tmp_path / "line.obj")], ".*no surface")
    _refused(["build-database", "--out", out, "--count", "0"], "database count must be positive")
    mm = tmp_path / "uav_mm.stl"
    trimesh.Trimesh(fixed_wing_mesh("low").vertices * 1000.0, fixed_wing_mesh("low").faces).export(mm)
    _refused(["build-database", "--out", out, "--count", "2", "--model", str(mm)], ".*probably in 'mm'")
    _refused(["build-database", "--out", out, "--count", "2", "--model", str(mm), "--unit", "inch"],
             "unknown unit 'inch'")
    _refused(["eval-boosting", "--database", str(tmp_path / "nosuch.npz"), "--samples", "1", "--distances", "5",
              "--top", "1"], "pose database .*nosuch.npz not found")
    assert not list(tmp_path.glob("*.npz"))


def test_build_database_reads_a_cad_file_in_its_unit(tmp_path):
    """A CAD file in millimetres is usable (the size check's hint names ``--unit mm``) and gives
    the database of the same file in metres."""
    from uav_landing_vision.boosting.database import PoseDatabase

    mesh = fixed_wing_mesh("low")
    databases = []
    for unit, scale in (("mm", 1000.0), ("m", 1.0)):
        trimesh.Trimesh(mesh.vertices * scale, mesh.faces).export(tmp_path / f"uav_{unit}.stl")
        out = tmp_path / f"db_{unit}.npz"
        assert main(["build-database", "--out", str(out), "--count", "3", "--model", str(tmp_path / f"uav_{unit}.stl"),
                     "--unit", unit, "--quiet"]) == 0
        databases.append(PoseDatabase.load(out))
    np.testing.assert_allclose(databases[0].obbs, databases[1].obbs, rtol=1e-4, atol=1e-3)


def test_eval_detector_refuses_unusable_bags_and_models(tmp_path, bags):
    def refused(bag, message, *extra):
        _refused(["eval-detector", "--bag", str(bag), "--json", str(tmp_path / "m.json"), *extra], message)

    refused(tmp_path / "missing", "cannot read /camera/camera_info of bag .*missing")
    refused(bags / "no_truth", ".*no_truth: no topic /uav/ground_truth")
    refused(bags / "empty", ".*empty: no message on /camera/camera_info")
    refused(bags / "full", "models file 'nosuch.onnx' not found", "--model", "nosuch.onnx")


def test_score_refuses_a_missing_or_empty_truth(tmp_path, bags):
    (tmp_path / "est.csv").write_text("stamp_ns,x,y,z,qx,qy,qz,qw\n1,0,0,5,0,0,0,1\n")
    _refused(["score", "--truth", str(tmp_path / "nosuch"), "--estimate", str(tmp_path / "est.csv"),
              "--json", str(tmp_path / "s.json")], "--truth .*nosuch does not exist$")
    _refused(["score", "--truth", str(bags / "empty"), "--estimate", str(tmp_path / "est.csv"),
              "--json", str(tmp_path / "s.json")], ".*empty holds no ground-truth pose")
    assert not (tmp_path / "s.json").exists()


def test_score_refuses_a_stamp_beyond_64_bits(tmp_path, bags):
    """An OverflowError traceback before."""
    (tmp_path / "est.csv").write_text("stamp_ns,x,y,z,qx,qy,qz,qw\n99999999999999999999999,1,2,3,0,0,0,1\n")
    _refused(["score", "--truth", str(bags / "full"), "--estimate", str(tmp_path / "est.csv"),
              "--json", str(tmp_path / "s.json")], ".*est.csv: line 2: stamp_ns 99999999999999999999999 does not fit 64 bits")
    assert not (tmp_path / "s.json").exists()


def test_make_detection_data_refuses_a_missing_camera(tmp_path):
    _refused(["make-detection-data", "--out", str(tmp_path / "data"), "--count", "1", "--camera", "nosuch.yaml"],
             "config file 'nosuch.yaml' not found")
    assert not (tmp_path / "data").exists()


def test_eval_detector_and_training_check_their_outputs_before_the_work(tmp_path, bags, monkeypatch):
    """Checked after the whole bag or the whole training before (--png xyz left the JSON behind)."""
    from uav_landing_vision.detection import evaluation, train

    def no_work(*args, **kwargs):
        raise AssertionError("the work started")

    monkeypatch.setattr(evaluation, "evaluate_bag", no_work)
    monkeypatch.setattr(train, "train", no_work)
    (tmp_path / "afile").write_text("")
    (tmp_path / "adir").mkdir()
    base = ["eval-detector", "--bag", str(bags / "full")]
    _refused([*base, "--json", str(tmp_path / "m.json"), "--png", str(tmp_path / "m.xyz")], "--png .*m.xyz: give a file name ending in .png")
    _refused([*base, "--json", str(tmp_path / "adir")], "--json .*adir is a folder")
    _refused([*base, "--json", str(tmp_path / "m.png")], "--png .*m.png is the --json file")  # the curve, then the JSON over it
    _refused([*base, "--json", str(tmp_path / "m.json"), "--png", str(tmp_path / "afile" / "m.png")], "--png .*is not a writable folder")
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "dataset.json").write_text('{"images": 1}')
    _refused(["train-detector", "--data", str(tmp_path / "data"), "--out", str(tmp_path / "run"),
              "--export", str(tmp_path / "afile" / "d.onnx")], "--export .*is not a writable folder")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["adir", "afile", "data"]


def test_train_verifier_fails_at_once_without_its_detector(tmp_path, monkeypatch):
    """The detector is loaded before the mining pool starts (whose failing workers would be
    restarted for ever)."""
    import multiprocessing

    def no_pool(*args):
        raise AssertionError("the mining pool was started")

    monkeypatch.setattr(multiprocessing, "get_context", no_pool)
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "dataset.json").write_text('{"images": 1}')
    _refused(["train-verifier", "--data", str(tmp_path / "data"), "--detector", "nosuch.onnx", "--out",
              str(tmp_path / "run")], "models file 'nosuch.onnx' not found")


def test_unreported_input_errors_are_one_line_and_programming_errors_are_not_hidden(tmp_path, monkeypatch, capsys):
    import importlib

    score = importlib.import_module("uav_landing_vision.evaluation.score")
    for path in ("truth", "est.csv"):
        (tmp_path / path).touch()
    argv = ["score", "--truth", str(tmp_path / "truth"), "--estimate", str(tmp_path / "est.csv"),
            "--json", str(tmp_path / "s.json")]

    def raising(error):
        def score_files(*args):
            raise error
        return score_files

    monkeypatch.setattr(score, "score_files", raising(OSError("disk unreadable")))
    assert main(argv) == 1
    assert capsys.readouterr().err == "uav-landing score: disk unreadable\n"
    monkeypatch.setattr(score, "score_files", raising(MemoryError("Unable to allocate 2.18 TiB")))
    assert main(argv) == 1  # as eval-optimisers --samples 100000000000 did, in a traceback
    assert capsys.readouterr().err == "uav-landing score: not enough memory for these settings (Unable to allocate 2.18 TiB)\n"
    monkeypatch.setattr(score, "score_files", raising(TypeError("a bug")))
    with pytest.raises(TypeError, match="a bug"):
        main(argv)


def test_no_opengl_is_one_line_naming_what_to_install(tmp_path):
    env = {**os.environ, "__EGL_VENDOR_LIBRARY_FILENAMES": str(tmp_path / "none.json")}
    run = subprocess.run([sys.executable, "-m", "uav_landing_vision.cli", "simulate", "--frames", "1", "--out",
                          str(tmp_path / "bag")], env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 1 and "Traceback" not in run.stderr
    assert run.stderr.startswith("uav-landing simulate: cannot create a headless OpenGL 4.3 context")
    assert "apt-get install libegl1 libgl1" in run.stderr and not (tmp_path / "bag").exists()


def _never_run(monkeypatch):
    """Every evaluation's or simulation's long run fails the test: a refusal must come before it."""
    import importlib

    def ran(*args, **kwargs):
        raise AssertionError("the run started before its arguments were checked")

    for module, name in (("uav_landing_vision.tracking.evaluate", "evaluate_bag"),
                         ("uav_landing_vision.tracking.metric_sweep", "run_sweep"),
                         ("uav_landing_vision.tracking.optimiser_evaluation", "evaluate_optimisers"),
                         ("uav_landing_vision.boosting.evaluation", "evaluate_boosting"),
                         ("uav_landing_vision.boosting.database", "build_database"),
                         ("uav_landing_vision.evaluation.score", "score_files"),
                         ("uav_landing_vision.sim.simulate", "simulate")):
        monkeypatch.setattr(importlib.import_module(module), name, ran)


def test_evaluation_commands_refuse_an_unwritable_output_before_running(tmp_path, monkeypatch, bags):
    """Not once the run is over and its results lost."""
    _never_run(monkeypatch)
    blocker = tmp_path / "file"
    blocker.write_text("")
    under_file = str(blocker / "sub" / "x.json")
    score = ["score", "--truth", str(bags / "full"), "--estimate", str(blocker)]
    for argv, message in (
            ([*score, "--json", under_file], f"--json {re.escape(under_file)}: {blocker} is not a writable folder"),
            ([*score, "--json", str(tmp_path)], f"--json {tmp_path} is a folder"),
            ([*score, "--json", str(tmp_path / "s.json"), "--report-dir", str(blocker)],
             f"--report-dir {blocker} is not a folder"),
            ([*score, "--json", str(blocker)], f"--json {blocker} is the --estimate file"),  # overwritten before
            (["score", "--truth", str(blocker), "--estimate", str(bags / "full"), "--json", str(blocker)],
             f"--json {blocker} is the --truth file"),  # a ground-truth CSV replaced by the summary
            (["evaluate", "--bag", str(bags / "full"), "--config", str(blocker), "--json", str(blocker)],
             f"--json {blocker} is the --config file"),
            (["eval-boosting", "--database", str(blocker), "--json", str(blocker)], f"--json {blocker} is the --database file"),
            (["eval-boosting", "--camera", str(blocker), "--json", str(blocker)], f"--json {blocker} is the --camera file"),
            (["build-database", "--model", str(blocker), "--out", str(blocker)], f"--out {blocker} is the --model file"),
            (["evaluate", "--bag", str(bags / "full"), "--json", under_file], "--json .* is not a writable folder"),
            (["evaluate", "--bag", str(bags / "full"), "--plots", str(blocker)], "--plots .* is not a folder"),
            (["eval-metrics", "--out", str(blocker)], "--out .* is not a folder"),
            (["eval-optimisers", "--json", under_file], "--json .* is not a writable folder"),
            (["eval-boosting", "--json", str(tmp_path)], "--json .* is a folder"),
            (["build-database", "--out", under_file], "--out .* is not a writable folder")):
        _refused(argv, message)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_evaluation_commands_name_the_option_of_a_bad_number(tmp_path, monkeypatch, bags):
    _never_run(monkeypatch)
    for argv, message in (
            (["evaluate", "--bag", str(bags / "full"), "--seed", "-1"], "--seed must be non-negative, got -1"),
            (["eval-metrics", "--out", str(tmp_path), "--seed", "-1"], "--seed must be non-negative, got -1"),
            (["eval-metrics", "--out", str(tmp_path), "--distance", "inf"], "--distance must be finite"),
            (["eval-optimisers", "--seed", "-1"], "seed must be a non-negative integer, got -1"),
            (["eval-optimisers", "--distances", "5", "inf"],
             r"distances must be finite and positive, got \(5.0, inf\)"),
            (["eval-boosting", "--seed", "-1"], "seed must be a non-negative integer, got -1"),
            (["eval-boosting", "--distances", "nan"], r"distances must be finite and positive, got \(nan,\)"),
            (["eval-boosting", "--aspect-weight", "0"], "aspect_weight must be positive and at most 10000, got 0.0"),
            (["eval-boosting", "--aspect-weight", "nan"], "aspect_weight must be positive and at most 10000, got nan"),
            (["build-database", "--out", str(tmp_path / "db.npz"), "--seed", "-1"],
             "--seed must be non-negative, got -1")):
        _refused(argv, message)


def test_detection_commands_refuse_a_negative_seed_at_once(tmp_path, monkeypatch):
    """numpy's "expected non-negative integer" before, after mining or an epoch had started."""
    from uav_landing_vision.detection import dataset, train, verifier_train

    def ran(*args, **kwargs):
        raise AssertionError("the work started before the seed was checked")

    for module, name in ((dataset, "generate"), (train, "train"), (verifier_train, "train_verifier")):
        monkeypatch.setattr(module, name, ran)
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "dataset.json").write_text('{"images": 1}')
    for argv in (["make-detection-data", "--out", str(tmp_path / "new"), "--seed", "-1"],
                 ["train-detector", "--data", str(tmp_path / "data"), "--out", str(tmp_path / "run"), "--seed", "-1"],
                 ["train-verifier", "--data", str(tmp_path / "data"), "--out", str(tmp_path / "run"), "--seed", "-1"]):
        _refused(argv, "seed must be a non-negative integer, got -1")


def test_evaluations_refuse_distances_that_share_a_table(monkeypatch):
    """Each distance has its own table, keyed by its printed value: a repeat would silently replace one."""
    _never_run(monkeypatch)
    _refused(["eval-boosting", "--distances", "5", "15", "5.0"], r"distances must differ, got \(5.0, 15.0, 5.0\)")
    _refused(["eval-optimisers", "--distances", "5", "5.0000001"], r"distances must differ, got \(5.0, 5.0000001\)")
