"""``uav-landing demo``'s simulated landing: kept for later runs, simulated again when its scenario changed."""

import importlib

from uav_landing_vision import demo
from uav_landing_vision.sim.simulate import SimulationResult

simulate_module = importlib.import_module("uav_landing_vision.sim.simulate")  # the package exports simulate()


def test_the_kept_landing_is_reused_only_while_its_scenario_is_unchanged(tmp_path, monkeypatch):
    runs = []

    def fake_simulate(scenario, bag, *, seed=None, frames=None):
        assert not bag.exists()  # simulate() writes a new folder only
        bag.mkdir(parents=True)
        (bag / "metadata.yaml").write_text("")
        runs.append((scenario.approach.start_range_m, seed, frames))
        return SimulationResult(frames=frames, seconds=0.0, bag_dir=bag)

    monkeypatch.setattr(simulate_module, "simulate", fake_simulate)
    scenario = tmp_path / "short.yaml"
    scenario.write_text("seed: 3\napproach:\n  start_range_m: [30.0, 32.0]\n")
    folder = tmp_path / "bags"
    bag = demo.simulated_bag(folder, str(scenario), None, 5)
    assert bag == folder / "short_seed3_5frames" and runs == [((30.0, 32.0), 3, 5)]
    assert demo.simulated_bag(folder, str(scenario), None, 5) == bag and len(runs) == 1  # kept
    scenario.write_text("seed: 3\napproach:\n  start_range_m: [40.0, 42.0]\n")  # edited: same name and seed
    assert demo.simulated_bag(folder, str(scenario), None, 5) == bag
    assert runs == [((30.0, 32.0), 3, 5), ((40.0, 42.0), 3, 5)]
    assert demo.simulated_bag(folder, str(scenario), None, 5) == bag and len(runs) == 2
