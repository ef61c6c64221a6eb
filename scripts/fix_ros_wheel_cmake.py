"""Rewrite the wheel builder's include paths left in ROS 2 Jazzy wheels' CMake exports.

About twenty ``*.cmake`` files under ``<venv>/share`` name ``/opt/python/cp3XX-cp3XX/...``
include directories of the machine that built the wheels; rosidl's Python generator then
fails with "includes non-existent path". This points them at this interpreter's Python
headers and numpy's include directory. Idempotent: run it after every ros-jazzy-* install.
"""

import re
import sys
import sysconfig
from pathlib import Path

import numpy

_BUILDER_NUMPY = re.compile(r"/opt/python/cp3\d+-cp3\d+/lib/python3\.\d+/site-packages/numpy/_core/include")
_BUILDER_PYTHON = re.compile(r"/opt/python/cp3\d+-cp3\d+/include/python3\.\d+")


def main() -> int:
    share = Path(sys.prefix) / "share"
    python_include = sysconfig.get_paths()["include"]
    numpy_include = numpy.get_include()
    changed = 0
    for path in share.rglob("*.cmake"):
        text = path.read_text()
        if "/opt/python/cp3" not in text:
            continue
        fixed = _BUILDER_NUMPY.sub(numpy_include, text)
        fixed = _BUILDER_PYTHON.sub(python_include, fixed)
        if fixed != text:
            path.write_text(fixed)
            changed += 1
    print(f"ros wheel cmake fix: {changed} file(s) rewritten under {share}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
