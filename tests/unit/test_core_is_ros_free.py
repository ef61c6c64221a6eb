"""The core (everything but ``uav_landing_vision.nodes``) imports no ROS module."""

import os
import subprocess
import sys
from pathlib import Path

import uav_landing_vision

CHECK = r"""
import importlib, pkgutil, sys
import uav_landing_vision
ros_prefixes = ("rclpy", "rcl_", "rosidl", "rmw", "rpyutils", "ament_index_python", "launch",
                "builtin_interfaces", "std_msgs", "sensor_msgs", "geometry_msgs", "diagnostic_msgs",
                "uav_landing_msgs")
imported = []
for info in pkgutil.walk_packages(uav_landing_vision.__path__, "uav_landing_vision."):
    if info.name.startswith("uav_landing_vision.nodes"):
        continue
    importlib.import_module(info.name)
    imported.append(info.name)
ros = sorted(m for m in sys.modules if m.split(".")[0].startswith(ros_prefixes))
print(len(imported))
if ros:
    sys.exit("ROS modules imported by the core: " + ", ".join(ros))
"""


def test_core_imports_no_ros_module():
    source = str(Path(uav_landing_vision.__file__).parents[1])  # the tree under test, not an installed copy
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([source, os.environ.get("PYTHONPATH", "")]))
    result = subprocess.run([sys.executable, "-c", CHECK], capture_output=True, text=True, timeout=120, env=env)
    assert result.returncode == 0, result.stderr
    assert int(result.stdout.strip().splitlines()[-1]) >= 5  # the walk really imported the core
