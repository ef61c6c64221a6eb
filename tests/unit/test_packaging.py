"""The ROS packaging: what ``rosdep install`` and a plain ``colcon build`` on a ship PC rely on.

Every third-party module that ``uav_landing_vision`` (or its launch file) imports is declared:
a ROS package or a rosdep key as an ``exec_depend`` of package.xml, a pip-only one in
requirements.txt and package.xml's note, the training-only ones in requirements-dev.txt. Every
console script names a function that exists, and the message package depends on every package
its messages use.
"""

import ast
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).parents[2]
VISION = ROOT / "src" / "uav_landing_vision"
MSGS = ROOT / "src" / "uav_landing_msgs"

# Import name -> rosdep key, for the non-ROS modules that have one.
ROSDEP_KEYS = {
    "numpy": "python3-numpy",
    "scipy": "python3-scipy",
    "cv2": "python3-opencv",
    "yaml": "python3-yaml",
    "matplotlib": "python3-matplotlib",
    "tqdm": "python3-tqdm",
    "PIL": "python3-pil",
}
# Installed with pip from requirements.txt on a ship PC (no rosdep key, or a pip key only).
PIP_ONLY = {"moderngl", "onnxruntime", "pymavlink", "rosbags", "trimesh"}
# Detector training and ONNX export (requirements-dev.txt), only in these modules.
TRAINING_ONLY = {"torch", "onnx"}
TRAINING_MODULES = {"network.py", "train.py", "export.py", "verifier_train.py"}


def _package_xml(path: Path) -> ET.Element:
    return ET.parse(path / "package.xml").getroot()


def _depends(root: ET.Element, *tags: str) -> set[str]:
    return {e.text.strip() for tag in tags for e in root.findall(tag)}


def _requirement_names(path: Path) -> set[str]:
    names = set()
    for line in path.read_text().splitlines():
        line = line.split("#")[0].strip()
        if line:
            names.add(re.split(r"[\[=<>!~ ;]", line, maxsplit=1)[0].lower())
    return names


def _third_party_imports() -> dict[str, set[Path]]:
    """Top-level module name -> the files importing it (absolute imports only)."""
    files = sorted((VISION / "uav_landing_vision").rglob("*.py")) + sorted((VISION / "launch").glob("*.py"))
    found: dict[str, set[Path]] = {}
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                if top not in sys.stdlib_module_names and top != "uav_landing_vision":
                    found.setdefault(top, set()).add(path)
    return found


def test_every_import_of_the_package_is_a_declared_dependency():
    root = _package_xml(VISION)
    exec_depends = _depends(root, "exec_depend", "depend")
    note = " ".join(re.findall(r"<!--(.*?)-->", (VISION / "package.xml").read_text(), re.S))
    requirements = _requirement_names(ROOT / "requirements.txt")
    dev_requirements = _requirement_names(ROOT / "requirements-dev.txt")
    imports = _third_party_imports()
    assert {"numpy", "rclpy", "launch_ros"} <= set(imports)  # the walk really saw the package

    problems = []
    for name, files in sorted(imports.items()):
        where = ", ".join(sorted(str(p.relative_to(VISION)) for p in files))
        if name in ROSDEP_KEYS:
            if ROSDEP_KEYS[name] not in exec_depends:
                problems.append(f"{name} ({where}): no <exec_depend>{ROSDEP_KEYS[name]}</exec_depend>")
        elif name in PIP_ONLY:
            if name not in requirements or name not in note:
                problems.append(f"{name} ({where}): pip-only, must be in requirements.txt and package.xml's note")
        elif name in TRAINING_ONLY:
            outside = sorted(str(p.relative_to(VISION)) for p in files if p.name not in TRAINING_MODULES)
            if name not in dev_requirements or outside:
                problems.append(f"{name}: training-only, must be in requirements-dev.txt and only in {sorted(TRAINING_MODULES)}; also in {outside}")
        elif name not in exec_depends:  # a ROS package: its name is its key
            problems.append(f"{name} ({where}): no <exec_depend>{name}</exec_depend> (a ROS package), "
                            "nor in this test's ROSDEP_KEYS / PIP_ONLY")
    assert not problems, "undeclared dependencies:\n" + "\n".join(problems)


def test_vision_package_is_ament_python_on_the_message_package():
    root = _package_xml(VISION)
    assert root.get("format") == "3"
    assert root.findtext("export/build_type") == "ament_python"
    assert root.findtext("name") == VISION.name
    assert (VISION / "resource" / VISION.name).is_file()  # the ament index marker setup.py installs
    assert {"uav_landing_msgs", "rclpy", "launch", "launch_ros", "ament_index_python"} <= _depends(root, "exec_depend", "depend")


def test_every_console_script_names_an_existing_function():
    tree = ast.parse((VISION / "setup.py").read_text())
    scripts = next(
        ast.literal_eval(value)
        for node in ast.walk(tree) if isinstance(node, ast.Dict)
        for key, value in zip(node.keys, node.values)
        if isinstance(key, ast.Constant) and key.value == "console_scripts"
    )
    assert scripts
    for entry in scripts:
        name, target = (s.strip() for s in entry.split("="))
        module, func = target.split(":")
        path = VISION / Path(*module.split(".")).with_suffix(".py")
        assert path.is_file(), f"{name}: no module {module}"
        defined = {n.name for n in ast.parse(path.read_text()).body if isinstance(n, ast.FunctionDef)}
        assert func in defined, f"{name}: {module} defines no {func}()"


def test_message_package_depends_on_every_package_its_messages_use():
    used = set()
    for msg in (MSGS / "msg").glob("*.msg"):
        for line in msg.read_text().splitlines():
            field = line.split("#")[0].split()
            if field and "/" in field[0]:
                used.add(field[0].split("/")[0])
    assert used, "no message uses another package's type"
    root = _package_xml(MSGS)
    assert root.findtext("export/build_type") == "ament_cmake"
    assert _depends(root, "buildtool_depend") >= {"ament_cmake", "rosidl_default_generators"}
    assert "rosidl_default_runtime" in _depends(root, "exec_depend")
    assert [g.text for g in root.findall("member_of_group")] == ["rosidl_interface_packages"]
    assert used <= _depends(root, "depend") | (_depends(root, "build_depend") & _depends(root, "exec_depend"))
    cmake = (MSGS / "CMakeLists.txt").read_text()
    dependencies = re.search(r"DEPENDENCIES([^)]*)\)", cmake).group(1).split()
    for package in used:
        assert f"find_package({package} REQUIRED)" in cmake and package in dependencies, package
