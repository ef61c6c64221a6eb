"""After ``make setup`` the plain venv interpreter imports the messages and the core."""

import os
import subprocess
import sys


def test_plain_venv_python_imports_messages_and_core():
    env = {"PATH": os.defpath, "HOME": os.environ.get("HOME", "/")}  # nothing sourced
    code = "import uav_landing_msgs.msg as m, uav_landing_vision; print(type(m.TrackerStatus()).__name__)"
    result = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "TrackerStatus"
