"""What each ``uav-landing`` subcommand passes on to its core: every option reaches the core's
configuration (stand-ins record it instead of running the long job), defaults are those the
help and the thesis give, and the printed units are the ones the numbers are in."""

import importlib
import types
from pathlib import Path

import numpy as np
import pytest

from uav_landing_vision.boosting import database
from uav_landing_vision.boosting import evaluation as boosting_evaluation
from uav_landing_vision.cli import build_parser, main
from uav_landing_vision.detection import dataset, export, train, verifier_train
from uav_landing_vision.detection import evaluation as detection_evaluation
from uav_landing_vision.model import fixed_wing_mesh
from uav_landing_vision.render import context, selftest
from uav_landing_vision.tracking import metric_sweep, optimiser_evaluation


def _recorder(seen, key, result=None):
    """A stand-in that records its arguments under ``seen[key]``, then returns ``result`` (called
    with them if callable) or, without one, stops the run with a ValueError."""

    def stand_in(*args, **kwargs):
        seen[key] = (args, kwargs)
        if result is None:
            raise ValueError("stand-in stopped the run")
        return result(*args, **kwargs) if callable(result) else result
    return stand_in


def test_eval_metrics_passes_metrics_distance_background_seed_and_tile_to_the_sweep(tmp_path, monkeypatch, capsys):
    seen = {}
    monkeypatch.setattr(metric_sweep, "run_sweep", _recorder(seen, "sweep", {"tests": []}))
    monkeypatch.setattr(metric_sweep, "write_results", _recorder(seen, "write", []))
    assert main(["eval-metrics", "--out", str(tmp_path / "o"), "--metric", "contour", "--metric", "colour",
                 "--metric", "contour", "--distance", "7.5", "--background", "complex", "--seed", "3",
                 "--tile", "32"]) == 0
    assert seen["sweep"][0] == (("contour", "colour"), 7.5, "complex", 3, 32)
    assert seen["write"][0][1] == tmp_path / "o"
    assert main(["eval-metrics", "--out", str(tmp_path / "o")]) == 0  # defaults: Table 6.4's nominal pose
    assert seen["sweep"][0] == (("colour", "contour", "distance_transform"), 5.0, "normal", 0, 64)
    capsys.readouterr()


def test_eval_optimisers_passes_its_settings_on_and_defaults_to_the_thesis_distances(monkeypatch, capsys):
    seen = {}
    monkeypatch.setattr(optimiser_evaluation, "evaluate_optimisers", _recorder(seen, "run", {}))
    monkeypatch.setattr(optimiser_evaluation, "format_tables", lambda result: "tables")
    assert main(["eval-optimisers", "--samples", "3", "--distances", "7", "9", "--particles", "12",
                 "--iterations", "4", "--optimisers", "pso, pfo,pso,", "--pfo-schedule", "3phase",
                 "--pfo-resampling", "systematic", "--seed", "2", "--quiet"]) == 0
    (camera, mesh, config), kwargs = seen["run"]
    assert (config.samples, config.distances, config.particles, config.iterations) == (3, (7.0, 9.0), 12, 4)
    assert config.optimisers == ("pso", "pfo") and config.seed == 2
    assert config.pfo.schedule == "3phase" and config.pfo.resampling == "systematic"
    assert kwargs == {"progress": False}
    assert main(["eval-optimisers"]) == 0
    (_, _, config), kwargs = seen["run"]
    assert config.distances == (5.0, 15.0, 25.0, 35.0, 45.0)  # §6.6: 5, 15, 25, 35 and 45 m
    assert config.pfo.schedule == "noise" and config.pfo.resampling == "reallocation"
    assert kwargs == {"progress": True}
    capsys.readouterr()


def test_build_database_passes_range_distance_and_seed_for_the_rectified_camera(tmp_path, monkeypatch):
    seen = {}
    monkeypatch.setattr(database, "build_database", _recorder(seen, "build"))
    out = str(tmp_path / "db.npz")
    with pytest.raises(SystemExit, match="stand-in stopped the run"):
        main(["build-database", "--out", out, "--count", "5", "--distance", "6.5", "--full-sphere", "--seed", "4",
              "--quiet"])
    (camera, mesh, config), kwargs = seen["build"]
    assert (config.count, config.distance, config.seed) == (5, 6.5, 4)
    assert config.half_range_deg == database.FULL_SPHERE_DEG
    assert not camera.is_distorted and np.all(camera.dist == 0)  # the tracker's frames are rectified
    assert kwargs["progress"] is False
    with pytest.raises(SystemExit):
        main(["build-database", "--out", out, "--half-range-deg", "10", "20", "30"])
    (_, _, config), kwargs = seen["build"]
    assert config.half_range_deg == (10.0, 20.0, 30.0) and config.distance == 4.0 and kwargs["progress"] is True
    with pytest.raises(SystemExit):
        main(["build-database", "--out", out])
    assert seen["build"][0][2].half_range_deg == (90.0, 90.0, 90.0)  # the front hemisphere


def test_build_database_uses_the_named_built_in_mesh(tmp_path, monkeypatch):
    seen = {}
    monkeypatch.setattr(database, "build_database", _recorder(seen, "build"))
    with pytest.raises(SystemExit):
        main(["build-database", "--out", str(tmp_path / "db.npz"), "--model", "low"])
    assert seen["build"][0][1].triangle_count == fixed_wing_mesh("low").triangle_count


def test_eval_boosting_passes_placement_top_and_the_thesis_switches(monkeypatch):
    seen = {}
    monkeypatch.setattr(boosting_evaluation, "evaluate_boosting", _recorder(seen, "run"))
    with pytest.raises(SystemExit, match="stand-in stopped the run"):
        main(["eval-boosting", "--samples", "2", "--distances", "6", "--top", "25", "10", "25",
              "--placement", "view", "--thesis-centre", "--thesis-orientation", "--aspect-weight", "1", "--quiet"])
    (camera, mesh, config), kwargs = seen["run"]
    assert config.top == (10, 25) and config.placement == "view" and config.distances == (6.0,)
    assert config.centre_offset is False and config.turn_orientation is False and config.aspect_weight == 1.0
    assert kwargs == {"database_path": None, "progress": False}
    with pytest.raises(SystemExit):
        main(["eval-boosting", "--database", "/x/db.npz"])
    (_, _, config), kwargs = seen["run"]
    assert config.centre_offset is True and config.turn_orientation is True and config.placement == "axis"
    assert config.aspect_weight == database.ASPECT_WEIGHT == 10.0  # the help's default, the tracker's weight
    assert config.top == (10, 25, 50, 100) and config.distances == (5.0, 15.0, 30.0)  # Tables 6.2-6.3
    assert kwargs == {"database_path": Path("/x/db.npz"), "progress": True}


def test_make_detection_data_passes_every_setting_to_the_generator(tmp_path, monkeypatch, capsys):
    seen = {}
    monkeypatch.setattr(dataset, "generate", _recorder(seen, "generate", {"images": 1, "positives": 1}))
    assert main(["make-detection-data", "--out", str(tmp_path / "d"), "--count", "4", "--seed", "2",
                 "--families", " normal, ,images", "--images", "pics", "--video", "clip.mp4",
                 "--approach-fraction", "0.25", "--label-box", "extent", "--workers", "3"]) == 0
    (cfg, out), kwargs = seen["generate"]
    assert (cfg.count, cfg.seed, cfg.families) == (4, 2, ("normal", "images"))
    assert (cfg.image_dir, cfg.video) == ("pics", "clip.mp4")
    assert cfg.approach_fraction == 0.25 and cfg.label_box == "extent"
    assert out == tmp_path / "d" and kwargs == {"workers": 3}
    capsys.readouterr()


@pytest.mark.parametrize("text, size", [("640x384", (640, 384)), ("320x192", (320, 192)), ("0x0", (0, 0))])
def test_train_detector_sizes_are_width_by_height(text, size):
    args = build_parser().parse_args(["train-detector", "--input", text, "--crop", text])
    assert args.input == size and args.crop == size


@pytest.fixture
def training_stand_ins(monkeypatch):
    seen = {"train": [], "export": []}
    log = {"epochs": [{"val_ap50": 0.5, "val_ap": 0.7}], "train_images": 3, "train_crops": 4}
    monkeypatch.setattr(train, "train", lambda cfg, resume=False: seen["train"].append((cfg, resume)))
    monkeypatch.setattr(verifier_train, "train_verifier", lambda cfg, resume=False: seen["train"].append((cfg, resume)))
    monkeypatch.setattr(train, "load_checkpoint", lambda cfg: {"log": log})
    monkeypatch.setattr(train, "trained_network", lambda cfg, state: "net")
    monkeypatch.setattr(verifier_train, "trained_verifier", lambda cfg, state: "verifier net")

    def export_onnx(net, path, *args, **kwargs):
        seen["export"].append((net, Path(path)))
        return Path(path)

    monkeypatch.setattr(export, "export_onnx", export_onnx)
    monkeypatch.setattr(export, "export_verifier_onnx", export_onnx)
    return seen


def test_train_detector_passes_its_settings_and_exports_where_asked(tmp_path, training_stand_ins, capsys):
    seen = training_stand_ins
    run = tmp_path / "run"
    assert main(["train-detector", "--data", str(tmp_path / "d"), "--out", str(run), "--input", "320x192",
                 "--crop", "0x0", "--max-images", "7", "--init", str(tmp_path / "init.pt"), "--resume"]) == 0
    (cfg, resume), = seen["train"]
    assert resume is True and cfg.input_size == (320, 192) and cfg.crop == (0, 0) and cfg.max_images == 7
    assert cfg.init == str(tmp_path / "init.pt")
    assert seen["export"] == [("net", run / "detector.onnx")]
    assert main(["train-detector", "--data", str(tmp_path / "d"), "--out", str(run), "--export-only",
                 "--export", str(tmp_path / "mine.onnx")]) == 0
    assert len(seen["train"]) == 1  # --export-only: no training
    assert seen["export"][-1] == ("net", tmp_path / "mine.onnx")
    capsys.readouterr()


def test_train_verifier_passes_its_settings_and_exports_where_asked(tmp_path, training_stand_ins, capsys):
    seen = training_stand_ins
    run = tmp_path / "run"
    assert main(["train-verifier", "--data", str(tmp_path / "d"), "--out", str(run), "--mine-threshold", "0.3",
                 "--resume"]) == 0
    (cfg, resume), = seen["train"]
    assert resume is True and cfg.mine_threshold == 0.3
    assert seen["export"] == [("verifier net", run / "verifier.onnx")]
    assert main(["train-verifier", "--data", str(tmp_path / "d"), "--out", str(run),
                 "--export", str(tmp_path / "v.onnx")]) == 0
    assert seen["train"][-1][1] is False and seen["export"][-1] == ("verifier net", tmp_path / "v.onnx")
    capsys.readouterr()


def test_eval_detector_passes_thresholds_threads_verifier_and_truth_box(tmp_path, monkeypatch, capsys):
    seen = {}
    result = {"ap50": 0.9, "precision": 0.8, "recall": 0.7, "threshold": 0.3, "false_positives_per_100_frames": 1.0,
              "best_box_false_positives_per_100_frames": 0.5, "ms_per_frame": 12.0}
    monkeypatch.setattr(detection_evaluation, "evaluate_bag", _recorder(seen, "run", result))
    assert main(["eval-detector", "--bag", str(tmp_path / "bag"), "--json", str(tmp_path / "m.json"),
                 "--threshold", "0.3", "--verifier", "verifier.onnx", "--verifier-threshold", "0.7",
                 "--threads", "1", "--truth-box", "extent"]) == 0
    (bag, cfg, json_path, png), kwargs = seen["run"]
    assert (cfg.score_threshold, cfg.verifier, cfg.verifier_threshold, cfg.threads) == (0.3, "verifier.onnx", 0.7, 1)
    assert png == tmp_path / "m.png"  # next to the JSON by default
    assert kwargs["truth_box"] == "extent"
    assert main(["eval-detector", "--bag", str(tmp_path / "bag"), "--json", str(tmp_path / "m.json"),
                 "--png", str(tmp_path / "curve.PNG")]) == 0
    (bag, cfg, json_path, png), kwargs = seen["run"]
    assert png == tmp_path / "curve.PNG" and cfg.verifier == "" and kwargs["truth_box"] == "oriented"
    assert cfg.score_threshold == 0.5 and cfg.threads == 2
    capsys.readouterr()


def test_simulate_passes_seed_frames_png_dir_and_compression(tmp_path, monkeypatch, capsys):
    seen = {}
    result = types.SimpleNamespace(frames=2, bag_dir=tmp_path / "bag", seconds=0.5)
    monkeypatch.setattr(importlib.import_module("uav_landing_vision.sim.simulate"), "simulate",
                        _recorder(seen, "run", result))
    assert main(["simulate", "--out", str(tmp_path / "bag"), "--seed", "5", "--frames", "2",
                 "--png-dir", str(tmp_path / "png"), "--compress"]) == 0
    (scenario, out), kwargs = seen["run"]
    assert scenario.name == "normal" and out == tmp_path / "bag"
    assert kwargs == {"seed": 5, "frames": 2, "video": None, "png_dir": tmp_path / "png", "compress": True}
    assert main(["simulate", "--out", str(tmp_path / "bag2")]) == 0
    assert seen["run"][1] == {"seed": None, "frames": None, "video": None, "png_dir": None, "compress": False}
    capsys.readouterr()


def test_check_renderer_checks_against_the_given_reference(monkeypatch, capsys):
    seen = []
    monkeypatch.setattr(context, "gl_context", lambda: types.SimpleNamespace(info={"GL_RENDERER": "stand-in"}))
    monkeypatch.setattr(selftest, "check_renderer", lambda path=None: seen.append(path) or
                        types.SimpleNamespace(summary="passed: stand-in"))
    assert main(["check-renderer", "--reference", "/x/mine.npz"]) == 0
    assert main(["check-renderer"]) == 0
    assert seen == ["/x/mine.npz", None]
    assert "renderer self-test passed: stand-in" in capsys.readouterr().out


def _pose_csvs(tmp_path):
    (tmp_path / "truth.csv").write_text("stamp_ns,x,y,z,qx,qy,qz,qw\n10,0,0,5,0,0,0,1\n20,0,0,6,0,0,0,1\n")
    (tmp_path / "est.csv").write_text("stamp_ns,x,y,z,qx,qy,qz,qw\n10,0,0,5.5,0,0,0,1\n"
                                      "20,0,0.1,6,0,0.0871557,0,0.9961947\n")  # 10° about y


def test_score_tables_name_their_units_and_columns(tmp_path, capsys):
    _pose_csvs(tmp_path)
    assert main(["score", "--truth", str(tmp_path / "truth.csv"), "--estimate", str(tmp_path / "est.csv"),
                 "--json", str(tmp_path / "s.json")]) == 0
    out = capsys.readouterr().out
    translation, rotation = out.split("truth.csv: rotation error (deg)\n")
    assert translation.startswith("truth.csv: translation error (m)\n")
    assert "Euclidean" in translation.splitlines()[1] and "Geodesic" in rotation.splitlines()[0]
    median = [line.split()[1:] for line in rotation.splitlines() if line.startswith("Median")][0]
    assert float(median[0]) == pytest.approx(5.0, abs=0.01)  # 0° and 10°: degrees, not radians


def test_score_passes_the_estimate_topic_on(tmp_path, monkeypatch):
    _pose_csvs(tmp_path)
    seen = {}
    monkeypatch.setattr(importlib.import_module("uav_landing_vision.evaluation.score"), "score_files",
                        _recorder(seen, "score"))
    with pytest.raises(SystemExit, match="stand-in stopped the run"):
        main(["score", "--truth", str(tmp_path / "truth.csv"), "--estimate", str(tmp_path / "est.csv"),
              "--topic", "/my/pose", "--json", str(tmp_path / "s.json")])
    assert seen["score"][0] == (tmp_path / "truth.csv", tmp_path / "est.csv", "/my/pose")
