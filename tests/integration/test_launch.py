"""The ship-PC launch file (not executable here: no launch/launch_ros wheels) and what it relies on:
console scripts, parameter files installed to share/, and the same node list as ``uav-landing graph``."""

import ast
import py_compile
import subprocess
import sys
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
    assert "from uav_landing_vision.graph import PIPELINE_TOPICS" in LAUNCH.read_text()  # the graph's links
    scripts = _console_scripts()
    for name in GRAPH_NODES:
        assert scripts[name] == f"uav_landing_vision.nodes.{name}:main"
        assert (PACKAGE_DIR / "uav_landing_vision" / "nodes" / f"{name}.py").is_file()


def test_setup_installs_the_launch_file_parameter_files_models_and_shaders(tmp_path):
    """What a plain (non-symlink) ``colcon build`` installs: setup.py's build_py and install_data,
    run from the package folder as colcon does."""
    subprocess.run([sys.executable, "setup.py", "-q", "build_py", "-d", str(tmp_path / "lib"),
                    "install_data", "-d", str(tmp_path / "data")],
                   cwd=PACKAGE_DIR, check=True, capture_output=True)
    share = tmp_path / "data" / "share" / "uav_landing_vision"
    assert (share / "launch" / "landing_vision.launch.py").is_file()
    installed = {p.name for p in (share / "config").glob("*.yaml")}
    assert {f"{name}.yaml" for name in GRAPH_NODES} | {"camera.yaml"} <= installed
    assert {p.name for p in (PACKAGE_DIR / "models").iterdir()} <= {p.name for p in (share / "models").iterdir()}
    shaders = {p.name for p in (PACKAGE_DIR / "uav_landing_vision" / "render" / "shaders").iterdir()}
    assert shaders and shaders == {p.name for p in (tmp_path / "lib" / "uav_landing_vision" / "render" / "shaders").iterdir()}
