"""The one process-wide headless OpenGL context (EGL: Mesa llvmpipe on CPUs, NVIDIA on GPUs)."""

import os
from pathlib import Path

import moderngl

_CONTEXT: moderngl.Context | None = None
_SHADER_DIR = Path(__file__).resolve().parent / "shaders"


class GLContextError(OSError):
    """No headless OpenGL 4.3 context can be made on this machine (says what to install); an
    OSError, as a missing system library is, so the CLI reports it in one line."""


def gl_context() -> moderngl.Context:
    """Create on first use, then return, the process's EGL OpenGL 4.3+ context; raises
    :class:`GLContextError` when there is none to be had."""
    global _CONTEXT
    if _CONTEXT is None:
        cache = os.environ.get("MESA_SHADER_CACHE_DIR")
        if cache:
            try:
                Path(cache).mkdir(parents=True, exist_ok=True)
            except OSError:
                os.environ["MESA_SHADER_CACHE_DISABLE"] = "true"
        try:
            _CONTEXT = moderngl.create_standalone_context(backend="egl", require=430)
        except Exception as exc:
            raise GLContextError(
                "cannot create a headless OpenGL 4.3 context through EGL "
                f"({exc}); install the system packages libegl1 and libgl1 "
                "(apt-get install libegl1 libgl1), or an NVIDIA driver with EGL"
            ) from exc
    return _CONTEXT


def shader_source(name: str) -> str:
    """The text of ``shaders/<name>``."""
    return (_SHADER_DIR / name).read_text()
