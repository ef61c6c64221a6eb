"""Make the built workspace importable from the plain ``.venv`` interpreter.

Writes ``uav_landing_workspace.pth`` into the venv's site-packages, naming the colcon install
space of ``uav_landing_msgs`` and the source tree of ``uav_landing_vision``, so that
``.venv/bin/python -c "import uav_landing_msgs.msg, uav_landing_vision"`` works without
sourcing anything. Publishing custom messages over DDS still needs the ROS environment
(``source scripts/env.sh``), as any ROS 2 workspace does. Idempotent.
"""

import sys
import sysconfig
from pathlib import Path


def main() -> int:
    root = Path(__file__).resolve().parents[1]
    version = f"python{sys.version_info.major}.{sys.version_info.minor}"
    paths = [
        root / "install" / "uav_landing_msgs" / "lib" / version / "site-packages",
        root / "src" / "uav_landing_vision",
    ]
    missing = [p for p in paths if not p.is_dir()]
    if missing:
        print(f"link_workspace: missing {', '.join(map(str, missing))}; build first", file=sys.stderr)
        return 1
    pth = Path(sysconfig.get_paths()["purelib"]) / "uav_landing_workspace.pth"
    pth.write_text("".join(f"{p}\n" for p in paths))
    print(f"link_workspace: {pth}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
