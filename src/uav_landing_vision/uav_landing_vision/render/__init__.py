"""The moderngl renderer: batched silhouette tiles for scoring, shaded views for simulation."""

from .context import gl_context
from .renderer import Renderer, SilhouetteBatch

__all__ = ["Renderer", "SilhouetteBatch", "gl_context"]
