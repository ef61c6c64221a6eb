"""The workspace: after ``make setup`` the plain venv interpreter imports the messages and the
core; ``.ci/run`` sets up a bare machine."""

import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path


def test_plain_venv_python_imports_messages_and_core():
    env = {"PATH": os.defpath, "HOME": os.environ.get("HOME", "/")}  # nothing sourced
    code = "import uav_landing_msgs.msg as m, uav_landing_vision; print(type(m.TrackerStatus()).__name__)"
    result = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "TrackerStatus"


def test_ci_installs_make_on_a_bare_machine_then_runs_the_readmes_commands(tmp_path):
    """A bare Debian has no ``make``: ``.ci/run`` installs it with apt-get before ``make apt``."""
    ci = Path(__file__).parents[2] / ".ci" / "run"
    calls = tmp_path / "calls"
    stub = f'#!/bin/bash\necho "$(basename "$0") $*" >> {calls}\n'
    bin_dir = tmp_path / "bin"  # the whole PATH: the tools .ci/run needs, and no make
    bin_dir.mkdir()
    for tool in ("bash", "dirname", "basename", "chmod"):
        (bin_dir / tool).symlink_to(shutil.which(tool))
    apt = bin_dir / "apt-get"
    apt.write_text(stub + f'if [ "$1" = install ]; then printf %s {shlex.quote(stub)} > {bin_dir}/make; chmod +x {bin_dir}/make; fi\n')
    apt.chmod(0o755)
    result = subprocess.run(["bash", str(ci)], env={"PATH": str(bin_dir)}, capture_output=True, text=True, timeout=30)
    assert result.returncode == 0, result.stderr
    assert calls.read_text().splitlines() == [
        "apt-get update -qq",
        "apt-get install -y -qq --no-install-recommends make",
        "make apt",
        "make test",
    ]
