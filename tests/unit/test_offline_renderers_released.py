"""The offline commands free their renderers' GL objects: moderngl frees none when a renderer is
garbage collected, and forty database builds in one process grew it by 470 MB."""

import numpy as np
import pytest

from uav_landing_vision.boosting import DatabaseConfig, build_database
from uav_landing_vision.boosting.evaluation import BoostingEvalConfig, evaluate_boosting
from uav_landing_vision.camera import load_camera_info_yaml
from uav_landing_vision.model import fixed_wing_mesh
from uav_landing_vision.render import Renderer
from uav_landing_vision.resources import config_path
from uav_landing_vision.sim import load_scenario, simulate
from uav_landing_vision.tracking.metric_sweep import run_sweep
from uav_landing_vision.tracking.optimiser_evaluation import OptimiserEvalConfig, evaluate_optimisers


@pytest.fixture
def live(monkeypatch):
    """The renderers made and not yet released."""
    made = set()
    init, release = Renderer.__init__, Renderer.release

    def tracked_init(self, *args, **kwargs):
        init(self, *args, **kwargs)
        made.add(id(self))

    def tracked_release(self):
        release(self)
        made.discard(id(self))

    monkeypatch.setattr(Renderer, "__init__", tracked_init)
    monkeypatch.setattr(Renderer, "release", tracked_release)
    return made


def _camera():
    return load_camera_info_yaml(config_path("camera.yaml"))


@pytest.mark.parametrize("run", [
    lambda tmp: simulate(load_scenario("normal"), tmp / "bag", frames=1, progress=False),
    lambda tmp: build_database(_camera(), fixed_wing_mesh("high"), DatabaseConfig(count=2), progress=False),
    lambda tmp: evaluate_boosting(_camera(), fixed_wing_mesh("high"), BoostingEvalConfig(samples=1, distances=(10.0,), top=(1,)),
                              progress=False),
    lambda tmp: evaluate_optimisers(_camera(), fixed_wing_mesh("high"), OptimiserEvalConfig(
        samples=1, distances=(10.0,), particles=4, iterations=1, optimisers=("pfo",)), progress=False),
    lambda tmp: run_sweep(metrics=("colour",)),
], ids=["simulate", "build_database", "evaluate_boosting", "evaluate_optimisers", "run_sweep"])
def test_every_renderer_is_released(live, run, tmp_path):
    run(tmp_path)
    assert live == set()


def test_a_build_that_fails_still_releases_its_renderer(live):
    with pytest.raises(ValueError, match="leaves the"):
        build_database(_camera(), fixed_wing_mesh("high"), DatabaseConfig(count=2, distance=0.6), progress=False)
    assert live == set()
