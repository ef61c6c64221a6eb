"""Where the shipped configuration (``config/``) and artefacts (``models/``) are.

In a source checkout (also a ``colcon build --symlink-install``) they are read from the
repository; in an installed package from ``share/uav_landing_vision`` of the first prefix on
``AMENT_PREFIX_PATH`` that has it.
"""

import os
from pathlib import Path

PACKAGE = "uav_landing_vision"
_PACKAGE_DIR = Path(__file__).resolve().parent


def _share_dir() -> Path | None:
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        share = Path(prefix) / "share" / PACKAGE
        if prefix and share.is_dir():
            return share
    return None


def _locate(kind: str, name: str, source_dir: Path) -> Path:
    candidates = [source_dir / name]
    share = _share_dir()
    if share is not None:
        candidates.append(share / kind / name)
    for path in candidates:
        if path.exists():
            return path
    raise FileNotFoundError(f"{kind} file '{name}' not found (looked in {', '.join(map(str, candidates))})")


def config_path(name: str) -> Path:
    """A file of the project's ``config/`` folder, e.g. ``config_path("camera.yaml")``."""
    return _locate("config", name, _PACKAGE_DIR.parents[2] / "config")


def model_path(name: str) -> Path:
    """A shipped artefact of ``models/`` (detector, pose database, tables)."""
    return _locate("models", name, _PACKAGE_DIR.parent / "models")


def config_file(name_or_path) -> Path:
    """``name_or_path`` where that file exists, else the ``config/`` file of that name."""
    path = Path(name_or_path)
    return path if path.exists() else config_path(str(name_or_path))


def model_file(name_or_path) -> Path:
    """``name_or_path`` as is when it is absolute or exists (its reader reports a missing file),
    else the ``models/`` artefact of that name."""
    path = Path(name_or_path)
    return path if path.is_absolute() or path.exists() else model_path(str(name_or_path))
