"""Batched silhouettes (one instanced draw into a tile atlas) and shaded, anti-aliased views.

The renderer draws the rectified (undistorted) pinhole image of the camera: only its
``width``, ``height`` and ``K`` are used. Poses are the UAV body in the camera optical frame,
``p_cam = R(q) p_body + t``, quaternions ``[x, y, z, w]``. Box and pixel conventions are
those of :mod:`.boxes` (OpenCV: integer coordinates at pixel centres).
"""

from dataclasses import dataclass

import moderngl
import numpy as np
from scipy.spatial import ConvexHull, QhullError

from ..model import Mesh
from .boxes import NEAR, pose_matrices, tile_boxes
from .context import gl_context, shader_source

_GL_CLIP_DISTANCE0 = 0x3000
_INSTANCE_FLOATS = 20  # three rows of [R|t], box, destination rectangle
_AMBIENT = 0.35
_DEFAULT_LIGHT = (0.3, -1.0, -0.5)  # above (−y), slightly right, behind the camera


@dataclass
class SilhouetteBatch:
    """Per-pose tiles: ``masks (M,T,T)`` uint8 {0,1} (row 0 = box top), ``boxes (M,4)``
    ``[x0,y0,x1,y1]`` (box edges; NaN when the model is not in front of the camera),
    ``visible (M,)`` (in front of the camera and the box overlapping the image; masks of
    invisible poses are all zero)."""

    masks: np.ndarray
    boxes: np.ndarray
    visible: np.ndarray


# Every GL object a renderer makes, framebuffers (with their attachments) last; see Renderer.release.
_GL_OBJECTS = ("_sil_vao", "_full_vao", "_shade_vao", "_bg_vao", "_vbo", "_ibo", "_inst_buf", "_one_buf", "_bg_tex",
               "_sil_prog", "_shade_prog", "_bg_prog", "_atlas", "_full", "_rgba")


MIN_TILE, MAX_TILE = 8, 1024  # silhouette tile side (px)


class Renderer:
    """Renders one mesh through one camera; all renderers share the process's GL context."""

    def __init__(self, camera, mesh: Mesh, *, tile: int = 64, max_batch: int = 512, margin: float = 0.1):
        if not MIN_TILE <= tile <= MAX_TILE or max_batch < 1 or mesh.triangle_count == 0 or not 0 <= margin < np.inf:
            raise ValueError(f"invalid renderer settings: tile={tile}, max_batch={max_batch}, margin={margin}")
        self.width, self.height = int(camera.width), int(camera.height)
        self.K = np.array(camera.K, dtype=float)
        self.mesh, self.tile, self.max_batch, self.margin = mesh, int(tile), int(max_batch), float(margin)
        self.cull = mesh.is_closed
        self._hull = _hull_points(mesh.vertices)

        self._cols, (aw, ah) = atlas_layout(self.tile, self.max_batch)
        size = (self.width, self.height)
        ctx = self.ctx = gl_context()
        # Checked before any GL object exists: a refused renderer leaves nothing to release.
        check_atlas(ctx, self.tile, self.max_batch,
                    f"lower max_batch ({self.max_batch}: the particles per draw) or tile ({self.tile})")
        _check_target_size(ctx, "image", size, "use a smaller camera resolution", texture=True)
        self._msaa: dict[int, moderngl.Framebuffer] = {}
        try:
            self._make_gl_objects(ctx, (aw, ah), size)
        except Exception:  # e.g. moderngl.Error, out of GPU memory: free what was made before it
            self.release()
            raise

    def _make_gl_objects(self, ctx, atlas_size: tuple[int, int], size: tuple[int, int]) -> None:
        mesh, (aw, ah) = self.mesh, atlas_size
        vert = shader_source("project.vert")
        self._sil_prog = ctx.program(vertex_shader=vert, fragment_shader=shader_source("silhouette.frag"))
        self._shade_prog = ctx.program(vertex_shader=vert, fragment_shader=shader_source("shaded.frag"))
        self._bg_prog = ctx.program(
            vertex_shader=shader_source("background.vert"), fragment_shader=shader_source("background.frag")
        )
        for prog in (self._sil_prog, self._shade_prog):
            prog["intrinsics"].value = (self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2])
            prog["skew"].value = self.K[0, 1]
            prog["near"].value = NEAR

        self._vbo = ctx.buffer(mesh.vertices.tobytes())
        self._ibo = ctx.buffer(mesh.faces.tobytes())
        self._instances = np.zeros((self.max_batch, _INSTANCE_FLOATS), dtype=np.float32)
        self._inst_buf = ctx.buffer(reserve=self._instances.nbytes)
        self._one_buf = ctx.buffer(reserve=_INSTANCE_FLOATS * 4)
        layout = ("4f 4f 4f 4f 4f/i", "in_row0", "in_row1", "in_row2", "in_box", "in_dst")
        self._sil_vao = ctx.vertex_array(
            self._sil_prog, [(self._vbo, "3f", "in_pos"), (self._inst_buf, *layout)], self._ibo, index_element_size=4
        )
        self._full_vao = ctx.vertex_array(
            self._sil_prog, [(self._vbo, "3f", "in_pos"), (self._one_buf, *layout)], self._ibo, index_element_size=4
        )
        self._shade_vao = ctx.vertex_array(
            self._shade_prog, [(self._vbo, "3f", "in_pos"), (self._one_buf, *layout)], self._ibo, index_element_size=4
        )
        self._bg_vao = ctx.vertex_array(self._bg_prog, [])

        self._atlas = ctx.framebuffer(color_attachments=[ctx.renderbuffer((aw, ah), components=1, dtype="f1")])
        self._atlas_buf = np.zeros((ah, aw), dtype=np.uint8)
        slot = np.arange(self.max_batch)
        col, row = slot % self._cols, slot // self._cols
        self._dst = np.stack(
            [-1 + 2 * col * self.tile / aw, -1 + 2 * row * self.tile / ah,
             -1 + 2 * (col + 1) * self.tile / aw, -1 + 2 * (row + 1) * self.tile / ah],
            axis=1,
        )  # fmt: skip

        self._full_box = np.array([-0.5, -0.5, self.width - 0.5, self.height - 0.5])
        self._full = ctx.framebuffer(color_attachments=[ctx.renderbuffer(size, components=1, dtype="f1")])
        self._full_buf = np.zeros((self.height, self.width), dtype=np.uint8)
        self._bg_tex = ctx.texture(size, 3, dtype="f1", alignment=1)
        self._rgba = ctx.framebuffer(color_attachments=[ctx.renderbuffer(size, components=4, dtype="f1")])
        self._rgba_buf = np.zeros((self.height, self.width, 4), dtype=np.uint8)

    def __enter__(self) -> "Renderer":
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def release(self) -> None:
        """Free this renderer's GL objects (moderngl frees none when they are garbage collected),
        also those of one whose construction failed partway; the renderer is unusable afterwards,
        and a second call does nothing. The shared context stays."""
        made = [getattr(self, name, None) for name in _GL_OBJECTS]
        framebuffers = [fbo for fbo in made[-3:] if fbo is not None] + list(self._msaa.values())
        for obj in made[:-3]:
            if obj is not None:
                obj.release()
        for fbo in framebuffers:
            attachments = [*fbo.color_attachments, fbo.depth_attachment]
            fbo.release()
            for attachment in attachments:
                if attachment is not None:
                    attachment.release()
        self._msaa.clear()
        for name in _GL_OBJECTS:
            setattr(self, name, None)

    @property
    def gl_renderer(self) -> str:
        """The GL renderer string (e.g. llvmpipe or the GPU's name), to log at start-up."""
        return self.ctx.info["GL_RENDERER"]

    def silhouettes(self, quats: np.ndarray, trans: np.ndarray) -> SilhouetteBatch:
        """Silhouette tiles of M poses, rendered in one instanced draw call."""
        rot, trans = pose_matrices(quats, trans)
        m, t = len(rot), self.tile
        if m > self.max_batch:
            raise ValueError(f"{m} poses exceed max_batch={self.max_batch}")
        boxes, visible = tile_boxes(self.K, self.width, self.height, rot, trans, self._hull, self.margin)
        if m == 0:
            return SilhouetteBatch(np.zeros((0, t, t), np.uint8), boxes, visible)
        self._fill_instances(self._instances[:m], rot, trans, boxes, self._dst[:m])
        self._instances[:m][~visible, 11] = -1.0  # behind the camera: clipped away entirely
        self._instances[:m][~visible, 12:16] = (0.0, 0.0, 1.0, 1.0)
        self._inst_buf.write(self._instances[:m])

        rows = -(-m // self._cols)
        view = (0, 0, self._cols * t, rows * t)
        self._begin(self._atlas, (0, 0, *self._atlas.size))  # the tiles' NDC span the whole atlas
        self._atlas.clear(0.0, 0.0, 0.0, 0.0, viewport=view)
        self._sil_vao.render(moderngl.TRIANGLES, instances=m)
        buf = self._atlas_buf[: rows * t]
        self._atlas.read_into(buf, viewport=view, components=1, dtype="f1")
        # Always a new array: with one tile column the reshape alone would be a view of the buffer.
        masks = np.empty((rows, self._cols, t, t), np.uint8)
        masks[...] = buf.reshape(rows, t, self._cols, t).transpose(0, 2, 1, 3)
        masks = masks.reshape(-1, t, t)[:m]
        masks[~visible] = 0
        return SilhouetteBatch(masks, boxes, visible)

    def silhouette_full(self, quat, trans) -> np.ndarray:
        """``(H, W)`` bool silhouette at image resolution (pixel centres sampled)."""
        self._write_one(quat, trans)
        view = (0, 0, self.width, self.height)
        self._begin(self._full, view)
        self._full.clear(0.0, 0.0, 0.0, 0.0)
        self._full_vao.render(moderngl.TRIANGLES)
        self._full.read_into(self._full_buf, components=1, dtype="f1")
        return self._full_buf.astype(bool)

    def shaded(
        self, quat, trans, background: np.ndarray, *, albedo=(0.85, 0.85, 0.82), light_dir=None, samples: int = 4
    ) -> tuple[np.ndarray, np.ndarray]:
        """The UAV shaded over ``background`` (H,W,3) uint8 RGB → (rgb uint8, alpha float32 coverage).

        Anti-aliased by ``samples``× MSAA (1: aliased); Lambert + ambient with a uniform albedo;
        ``light_dir`` points towards the light in the camera optical frame.
        """
        background = np.ascontiguousarray(background)
        if background.shape != (self.height, self.width, 3) or background.dtype != np.uint8:
            raise ValueError(
                f"background must be ({self.height}, {self.width}, 3) uint8, got {background.shape} {background.dtype}"
            )
        light = np.asarray(_DEFAULT_LIGHT if light_dir is None else light_dir, dtype=float)
        if light.shape != (3,) or not np.linalg.norm(light) > 0:
            raise ValueError(f"light_dir must be a non-zero 3-vector, got {light_dir!r}")
        self._write_one(quat, trans)
        self._shade_prog["albedo"].value = tuple(float(a) for a in albedo)
        self._shade_prog["light_dir"].value = tuple(light / np.linalg.norm(light))
        self._shade_prog["ambient"].value = _AMBIENT
        self._bg_tex.write(background)

        target = self._msaa_target(samples)
        view = (0, 0, self.width, self.height)
        self._begin(target, view)
        target.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        self.ctx.enable_only(moderngl.NOTHING)
        self._set_clip_distances(False)  # the background pass writes none
        self._bg_tex.use(0)
        self._bg_prog["background"].value = 0
        self._bg_vao.render(moderngl.TRIANGLES, vertices=3)
        self._set_clip_distances(True)
        self.ctx.enable_only(moderngl.DEPTH_TEST | (moderngl.CULL_FACE if self.cull else moderngl.NOTHING))
        self._shade_vao.render(moderngl.TRIANGLES)
        self.ctx.copy_framebuffer(self._rgba, target)  # MSAA resolve
        self._rgba.read_into(self._rgba_buf, components=4, dtype="f1")
        rgb = self._rgba_buf[..., :3].copy()
        alpha = self._rgba_buf[..., 3].astype(np.float32) / np.float32(255.0)
        return rgb, alpha

    def _begin(self, fbo: moderngl.Framebuffer, viewport) -> None:
        ctx = self.ctx
        fbo.use()
        fbo.viewport = viewport
        ctx.enable_only(moderngl.CULL_FACE if self.cull else moderngl.NOTHING)
        ctx.front_face = "cw"  # image rows are written to framebuffer rows: a mirror
        self._set_clip_distances(True)

    def _set_clip_distances(self, on: bool) -> None:
        for i in range(4):
            (self.ctx.enable_direct if on else self.ctx.disable_direct)(_GL_CLIP_DISTANCE0 + i)

    def _write_one(self, quat, trans) -> None:
        rot, t = pose_matrices(np.reshape(quat, (1, 4)), np.reshape(trans, (1, 3)))
        one = np.zeros((1, _INSTANCE_FLOATS), dtype=np.float32)
        self._fill_instances(one, rot, t, self._full_box[None], np.array([[-1.0, -1.0, 1.0, 1.0]]))
        self._one_buf.write(one)

    @staticmethod
    def _fill_instances(out, rot, trans, boxes, dst) -> None:
        out[:, 0:12] = np.concatenate([rot, trans[:, :, None]], axis=2).reshape(-1, 12)
        out[:, 12:16] = boxes
        out[:, 16:20] = dst

    def _msaa_target(self, samples: int) -> moderngl.Framebuffer:
        """The (cached) colour + depth target with ``samples`` per pixel, resolved into ``_rgba``."""
        if not 1 <= samples <= self.ctx.max_samples:
            raise ValueError(f"samples must be 1..{self.ctx.max_samples}, got {samples}")
        if samples not in self._msaa:
            size, s = (self.width, self.height), (0 if samples == 1 else samples)
            self._msaa[samples] = self.ctx.framebuffer(
                color_attachments=[self.ctx.renderbuffer(size, components=4, dtype="f1", samples=s)],
                depth_attachment=self.ctx.depth_renderbuffer(size, samples=s),
            )
        return self._msaa[samples]


def atlas_layout(tile: int, max_batch: int) -> tuple[int, tuple[int, int]]:
    """The silhouette atlas of ``max_batch`` tiles: a power-of-two number of columns (exact NDC
    offsets), rows as needed; returns ``(columns, (width, height))`` in pixels."""
    cols = 1 << int(np.ceil(np.log2(np.sqrt(max_batch))))
    return cols, (cols * tile, -(-max_batch // cols) * tile)


def check_atlas(ctx: moderngl.Context, tile: int, max_batch: int, fix: str) -> None:
    """Refuse (ValueError, advising ``fix``) an atlas of ``max_batch`` tiles that ``ctx`` cannot draw."""
    _check_target_size(ctx, "silhouette atlas", atlas_layout(tile, max_batch)[1], fix)


def _check_target_size(ctx: moderngl.Context, what: str, size: tuple[int, int], fix: str, *, texture: bool = False):
    """Refuse a render target that this context cannot draw: wider or taller than a renderbuffer
    may be (the framebuffer would be incomplete), than the viewport (GL clamps it silently, and
    every tile would land in the wrong place) or, with ``texture``, than a texture."""
    rb = ctx.info["GL_MAX_RENDERBUFFER_SIZE"]
    limits = {"GL_MAX_RENDERBUFFER_SIZE": (rb, rb), "GL_MAX_VIEWPORT_DIMS": tuple(ctx.info["GL_MAX_VIEWPORT_DIMS"])}
    if texture:
        limits["GL_MAX_TEXTURE_SIZE"] = (ctx.info["GL_MAX_TEXTURE_SIZE"],) * 2
    for name, (max_w, max_h) in limits.items():
        if size[0] > max_w or size[1] > max_h:
            raise ValueError(f"{what} {size[0]}x{size[1]} exceeds this GL context's {name} "
                             f"({max_w}x{max_h}, {ctx.info['GL_RENDERER']}); {fix}")


def _hull_points(vertices: np.ndarray) -> np.ndarray:
    """The convex-hull vertices (their projection bounds the model's); all vertices if flat."""
    try:
        return vertices[ConvexHull(vertices).vertices].astype(float)
    except QhullError:
        return vertices.astype(float)
