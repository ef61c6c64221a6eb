"""Built-in test of this machine's OpenGL: silhouettes of fixed poses against a shipped reference.

Every particle's likelihood is computed from its silhouette, so a GL implementation that
rasterises differently would bias the tracker without any error. Examples are another
pixel-centre or winding convention, or a faulty driver build. The reference
(``models/render_reference.npz``) holds 128 poses at 5–80 m, the camera, and the tiles that
Mesa's llvmpipe drew for them. :func:`check_renderer` draws them again here and compares tile by
tile. On an NVIDIA H100, 3–8 of 300 such tiles differed from llvmpipe's, each by one edge pixel
(of this reference's 128 tiles, one). Drawing the silhouettes a tenth of a tile pixel off changes
2–27 pixels a tile (median 13); a quarter of a pixel, 3–55. The limit per tile
(``TILE_LIMIT_PX`` pixels, or ``TILE_LIMIT_FRACTION`` of the tile's silhouette when that is
more) passes the first and fails the tenth of a pixel in 85 of the 128 tiles, the quarter in
127 or all 128.

The shipped reference was made with Mesa llvmpipe (Debian 12) by::

    python -m uav_landing_vision.render.selftest src/uav_landing_vision/models/render_reference.npz
"""

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..camera import CameraModel, load_camera_info_yaml
from ..model import fixed_wing_mesh
from ..resources import config_path, model_path
from .benchmark import random_poses
from .renderer import Renderer

REFERENCE = "render_reference.npz"
POSES, TILE, MESH, SEED = 128, 64, "low", 0
TILE_LIMIT_PX = 3
TILE_LIMIT_FRACTION = 0.02
_KEYS = ("quats", "trans", "K", "size", "tile", "mesh", "masks")


class RendererSelfTestError(OSError):
    """The renderer's silhouettes differ from the reference, or the reference cannot be read;
    an OSError, as a broken system library is, so the CLI reports it in one line."""


@dataclass(frozen=True)
class SelfTestResult:
    tiles: int
    differing_tiles: int  # tiles with any pixel unlike the reference's
    failing_tiles: int  # tiles over the limit
    differing_px: int
    worst_tile_px: int
    silhouette_px: int  # the reference's silhouette pixels, all tiles

    @property
    def ok(self) -> bool:
        return self.failing_tiles == 0

    @property
    def summary(self) -> str:
        verdict = "passed" if self.ok else f"FAILED in {self.failing_tiles} tiles"
        return (f"{verdict}: {self.differing_tiles} of {self.tiles} tiles differ from the reference, "
                f"{self.differing_px} of {self.silhouette_px} silhouette pixels, at most {self.worst_tile_px} in one tile")


def compare(reference: np.ndarray, masks: np.ndarray) -> SelfTestResult:
    """Tile-by-tile comparison of ``masks (M,T,T)`` with the ``reference`` tiles of the same shape."""
    if masks.shape != reference.shape:
        raise ValueError(f"masks {masks.shape} do not match the reference's {reference.shape}")
    diff = (masks.astype(bool) != reference.astype(bool)).reshape(len(masks), -1).sum(axis=1)
    area = reference.astype(bool).reshape(len(reference), -1).sum(axis=1)
    limit = np.maximum(TILE_LIMIT_PX, TILE_LIMIT_FRACTION * area)
    return SelfTestResult(
        tiles=len(masks),
        differing_tiles=int((diff > 0).sum()),
        failing_tiles=int((diff > limit).sum()),
        differing_px=int(diff.sum()),
        worst_tile_px=int(diff.max(initial=0)),
        silhouette_px=int(area.sum()),
    )


def render_tiles(camera, quats: np.ndarray, trans: np.ndarray, tile: int = TILE, mesh: str = MESH) -> np.ndarray:
    """Silhouette tiles of the poses, drawn in one batch by a renderer made for the purpose."""
    renderer = Renderer(camera, fixed_wing_mesh(mesh), tile=tile, max_batch=len(quats))
    try:
        return renderer.silhouettes(quats, trans).masks
    finally:
        renderer.release()


def load_reference(path=None) -> dict:
    """The reference's arrays, checked; ``path`` defaults to the shipped one."""
    try:
        path = Path(path) if path is not None else model_path(REFERENCE)
        with np.load(path, allow_pickle=False) as data:
            missing = [key for key in _KEYS if key not in data.files]
            if missing:
                raise ValueError(f"missing {', '.join(missing)}")
            ref = {key: data[key] for key in _KEYS}
        m, tile = len(ref["quats"]), int(ref["tile"])
        ref["masks"] = np.unpackbits(ref["masks"], axis=-1, count=tile)
        ref["mesh"] = str(ref["mesh"])
        shapes = {"quats": (m, 4), "trans": (m, 3), "K": (3, 3), "size": (2,), "masks": (m, tile, tile)}
        wrong = [f"{key} {ref[key].shape}" for key, shape in shapes.items() if ref[key].shape != shape]
        if m == 0 or wrong:
            raise ValueError(f"inconsistent shapes: {', '.join(wrong) or 'no poses'}")
        ref["camera"] = CameraModel(int(ref["size"][0]), int(ref["size"][1]), ref["K"])
    except Exception as exc:  # zip, zlib, .npy header and value errors of a damaged file
        raise RendererSelfTestError(f"render reference {path}: {exc}") from exc
    return ref


def check_renderer(path=None) -> SelfTestResult:
    """Draw the reference's poses and compare; :class:`RendererSelfTestError` when a tile is off."""
    ref = load_reference(path)
    result = compare(ref["masks"], render_tiles(ref["camera"], ref["quats"], ref["trans"], int(ref["tile"]), ref["mesh"]))
    if not result.ok:
        raise RendererSelfTestError(
            f"this machine's OpenGL draws the UAV unlike the reference: {result.summary} "
            f"(limit {TILE_LIMIT_PX} px or {TILE_LIMIT_FRACTION:.0%} of a tile's silhouette)"
        )
    return result


def write_reference(path) -> None:
    """Render the reference poses with this machine's OpenGL and save them to ``path``."""
    camera = load_camera_info_yaml(config_path("camera.yaml")).rectified()
    quats, trans = random_poses(camera, POSES, np.random.default_rng(SEED))
    masks = render_tiles(camera, quats, trans)
    np.savez_compressed(path, quats=quats, trans=trans, K=camera.K, size=np.array([camera.width, camera.height]),
                        tile=np.array(TILE), mesh=np.array(MESH), masks=np.packbits(masks, axis=-1))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="write the renderer's self-test reference")
    parser.add_argument("out", type=Path, help="the .npz file to write")
    write_reference(parser.parse_args(argv).out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
