"""The ship-PC launch file (not executable here: no launch/launch_ros wheels) and what it relies on:
console scripts, parameter files installed to share/, and the same node list as ``uav-landing graph``."""

import ast
import py_compile
from glob import glob
from pathlib import Path

from uav_landing_vision.graph import GRAPH_NODES, PLAYER

PACKAGE_DIR = Path(__file__).parents[2] / "src" / "uav_landing_vision"
LAUNCH = PACKAGE_DIR / "launch" / "landing_vision.launch.py"


def _assignments(path: Path) -> dict:
    tree = ast.parse(path.read_text())
    return {
        node.targets[0].id: ast.literal_eval(node.value)
        for node in tree.body
        if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Name) and isinstance(node.value, (ast.Tuple, ast.Constant))
    }


def _console_scripts() -> dict:
    tree = ast.parse((PACKAGE_DIR / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Dict) and any(isinstance(k, ast.Constant) and k.value == "console_scripts" for k in node.keys):
            entries = ast.literal_eval(node.values[0])
            return dict(e.replace(" ", "").split("=") for e in entries)
    raise AssertionError("no console_scripts in setup.py")


def test_launch_file_compiles(tmp_path):
    py_compile.compile(str(LAUNCH), cfile=str(tmp_path / "launch.pyc"), doraise=True)


def test_launch_and_graph_start_the_same_nodes_each_with_script_module_and_parameters():
    launch = _assignments(LAUNCH)
    assert set(launch["NODES"]) | {launch["PLAYER"]} == set(GRAPH_NODES) and launch["PLAYER"] == PLAYER
    scripts = _console_scripts()
    for name in GRAPH_NODES:
        assert scripts[name] == f"uav_landing_vision.nodes.{name}:main"
        assert (PACKAGE_DIR / "uav_landing_vision" / "nodes" / f"{name}.py").is_file()


def test_setup_installs_the_launch_file_and_every_parameter_file(monkeypatch):
    monkeypatch.chdir(PACKAGE_DIR)  # colcon runs setup.py from the package folder
    source = (PACKAGE_DIR / "setup.py").read_text()
    assert '("share/" + package_name + "/launch", glob("launch/*.py"))' in source
    assert '("share/" + package_name + "/config", glob("../../config/*.yaml"))' in source
    assert "launch/landing_vision.launch.py" in glob("launch/*.py")
    installed = {Path(p).name for p in glob("../../config/*.yaml")}
    assert {f"{name}.yaml" for name in GRAPH_NODES} <= installed
