"""Backgrounds seen by the moving deck camera (§6.2.1–6.2.3), drawn in the rectified image.

``normal`` and ``complex`` are looked up per pixel from the camera ray in the ship's mean
frame M, so the horizon tilts and moves with the ship's roll, pitch and heave. The sky is a
panorama over (azimuth, elevation); the sea is a textured plane at the waterline, seen in
perspective, which flows aft at the ship's speed. ``video`` shows any recorded footage.
"""

from pathlib import Path

import cv2
import numpy as np

from ..camera import CameraModel
from .config import BackgroundConfig, ShipConfig

_PANO_RES = np.radians(0.06)  # panorama: radians per pixel, both axes
_PANO_TOP = np.radians(55.0)
_PANO_BOTTOM = np.radians(-2.0)


class BackgroundError(ValueError):
    """A background that cannot be made (e.g. an unreadable video)."""


def fractal_noise(rng: np.random.Generator, shape: tuple[int, int], slope: float,
                  stretch: tuple[float, float] = (1.0, 1.0)) -> np.ndarray:
    """Tileable noise with a power spectrum ∝ 1/f^slope (zero mean, unit SD), float32.

    ``stretch`` scales the (row, column) frequencies: a column stretch < 1 elongates features
    horizontally.
    """
    fy = np.fft.fftfreq(shape[0])[:, None] / stretch[0]
    fx = np.fft.rfftfreq(shape[1])[None, :] / stretch[1]
    f = np.hypot(fy, fx)
    f[0, 0] = 1.0
    spectrum = (rng.standard_normal(f.shape) + 1j * rng.standard_normal(f.shape)) * f ** (-slope / 2)
    spectrum[0, 0] = 0.0
    field = np.fft.irfft2(spectrum, s=shape)
    return ((field - field.mean()) / field.std()).astype(np.float32)


def _smoothstep(a: float, b: float, x: np.ndarray) -> np.ndarray:
    s = np.clip((x - a) / (b - a), 0.0, 1.0)
    return s * s * (3 - 2 * s)


def _ramp(x: np.ndarray, stops: list[tuple[float, tuple[int, int, int]]]) -> np.ndarray:
    """Piecewise-linear colour ramp (x → RGB float)."""
    xs = [s[0] for s in stops]
    return np.stack([np.interp(x, xs, [s[1][c] for s in stops]) for c in range(3)], axis=-1).astype(np.float32)


class _RayBackground:
    """Shared machinery: camera rays in M, sky panorama look-up, sea plane look-up."""

    def __init__(self, camera: CameraModel, cfg: BackgroundConfig, ship: ShipConfig, rng: np.random.Generator):
        self.size = (camera.height, camera.width)
        u, v = np.meshgrid(np.arange(camera.width, dtype=np.float32), np.arange(camera.height, dtype=np.float32))
        rays = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], axis=-1)
        self.rays = (rays / np.linalg.norm(rays, axis=-1, keepdims=True)).astype(np.float32)
        self.cfg, self.ship = cfg, ship
        sun_az, sun_el = np.radians([cfg.sun_azimuth_deg, cfg.sun_elevation_deg])
        self.sun = np.array([np.cos(sun_el) * np.cos(sun_az), np.cos(sun_el) * np.sin(sun_az), np.sin(sun_el)])
        self.pano_w = int(round(2 * np.pi / _PANO_RES))
        self.pano_h = int(round((_PANO_TOP - _PANO_BOTTOM) / _PANO_RES))
        self.swell = fractal_noise(rng, (512, 512), 3.2, (0.3, 1.0))  # 0.6 m/px, crests across the ship
        self.chop = fractal_noise(rng, (512, 512), 2.4, (0.5, 1.0))  # 0.06 m/px
        self.jitter_rng = rng

    def _pano_elevations(self) -> np.ndarray:
        return _PANO_TOP - (np.arange(self.pano_h, dtype=np.float32) + 0.5) * _PANO_RES

    def _pano_azimuths(self) -> np.ndarray:
        """Azimuth of each panorama column, from the ship's bow, positive to port."""
        return (np.arange(self.pano_w, dtype=np.float32) + 0.5) * _PANO_RES - np.pi

    def _sample_pano(self, pano: np.ndarray, az: np.ndarray, el: np.ndarray, shift_rad: float = 0.0) -> np.ndarray:
        mx = ((az + np.pi - shift_rad) / _PANO_RES - 0.5).astype(np.float32)
        my = np.clip((_PANO_TOP - el) / _PANO_RES - 0.5, 0, self.pano_h - 1).astype(np.float32)
        return cv2.remap(pano, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)

    def _sea_texture(self, x: np.ndarray, y: np.ndarray, dist: np.ndarray) -> np.ndarray:
        """Wave height-like pattern (about unit SD near the camera) at water-frame points (m)."""
        swell = cv2.remap(self.swell, x / 0.6, y / 0.6, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        chop = cv2.remap(self.chop, x / 0.06, y / 0.06, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        return swell * np.exp(-dist / 250.0) + chop * np.exp(-dist / 40.0)

    def frame(self, index: int, t: float, cam_rot: np.ndarray, cam_pos: np.ndarray) -> np.ndarray:
        """The background (H, W, 3) uint8 at frame ``index``, time ``t``, camera pose in M."""
        d = self.rays @ cam_rot.T.astype(np.float32)
        az = np.arctan2(d[..., 1], d[..., 0])
        el = np.arcsin(np.clip(d[..., 2], -1.0, 1.0))
        sky = self._sky(az, el, t)
        below = d[..., 2] < -1e-4
        if not np.any(below):
            return np.clip(sky, 0, 255).astype(np.uint8)
        height = self.ship.net_height_m + cam_pos[2]
        dist = np.where(below, height / np.maximum(-d[..., 2], 1e-4), 0.0).astype(np.float32)
        jitter = self.jitter_rng.normal(0.0, self.cfg.sea_jitter_m, 2)
        x = cam_pos[0] + dist * d[..., 0] + self.ship.speed_mps * t + jitter[0]
        y = cam_pos[1] + dist * d[..., 1] + jitter[1]
        sea = self._sea(az, el, dist, self._sea_texture(x.astype(np.float32), y.astype(np.float32), dist), t)
        out = np.where(below[..., None], sea, sky)
        return np.clip(out, 0, 255).astype(np.uint8)

    def _sun_glow(self, az: np.ndarray, el: np.ndarray) -> np.ndarray:
        cos_sun = np.cos(el) * np.cos(az) * self.sun[0] + np.cos(el) * np.sin(az) * self.sun[1] + np.sin(el) * self.sun[2]
        return np.clip(cos_sun, -1.0, 1.0)


class NormalBackground(_RayBackground):
    """§6.2.1: a clear-sky gradient over a moving sea surface."""

    def __init__(self, camera, cfg, ship, rng):
        super().__init__(camera, cfg, ship, rng)
        el = self._pano_elevations()[:, None]
        az = self._pano_azimuths()[None, :]
        e = np.degrees(np.broadcast_to(el, (self.pano_h, self.pano_w)))
        base = _ramp(e, [(-2, (214, 222, 228)), (3, (196, 212, 226)), (15, (150, 182, 216)), (55, (92, 138, 198))])
        glow = np.clip(self._sun_glow(az, el), 0, 1)[..., None] ** 8
        haze = 4.0 * fractal_noise(rng, (self.pano_h, self.pano_w), 3.5, (1.0, 0.3))[..., None]
        self.pano = np.clip(base + 45.0 * glow + haze, 0, 255).astype(np.float32)

    def _sky(self, az, el, t):
        return self._sample_pano(self.pano, az, el)

    def _sea(self, az, el, dist, waves, t):
        grazing = np.sin(-el)
        fresnel = (0.02 + 0.98 * (1.0 - grazing) ** 5)[..., None]
        deep = np.array([28, 62, 88], np.float32)
        reflected = np.array([190, 205, 218], np.float32)
        colour = deep + fresnel * (reflected - deep)
        colour = colour * (1.0 + 0.2 * waves[..., None])
        haze = np.exp(-dist / 900.0)[..., None]
        return haze * colour + (1 - haze) * np.array([205, 214, 222], np.float32)


class ComplexBackground(_RayBackground):
    """§6.2.2: a sunset sky full of clouds with a strong gradient, drifting sideways and wrapping.

    The panorama covers the full circle, so the translation wraps from one border to the other.
    """

    def __init__(self, camera, cfg, ship, rng):
        super().__init__(camera, cfg, ship, rng)
        el = self._pano_elevations()[:, None]
        az = self._pano_azimuths()[None, :]
        e = np.degrees(np.broadcast_to(el, (self.pano_h, self.pano_w)))
        sky = _ramp(e, [(-2, (255, 196, 120)), (2, (250, 160, 90)), (8, (226, 110, 90)),
                        (20, (150, 80, 115)), (55, (48, 44, 96))])
        glow = np.clip(self._sun_glow(az, el), 0, 1)[..., None]
        sky += 70.0 * glow**12 * np.array([1.0, 0.85, 0.5], np.float32)
        big = fractal_noise(rng, (self.pano_h, self.pano_w), 3.6, (1.0, 0.25))
        fine = fractal_noise(rng, (self.pano_h, self.pano_w), 2.8, (1.0, 0.4))
        density = _smoothstep(-0.9, 1.0, big + 0.25 * fine)[..., None]
        thin = 1.0 - density
        dark = np.array([78, 58, 84], np.float32) * (1.0 - 0.35 * e[..., None] / 55.0)
        lit = np.array([255, 150, 95], np.float32) * (0.45 + 0.55 * glow**2) * (1.0 - e[..., None] / 90.0)
        cloud = dark + (lit - dark) * np.clip(thin * 1.3 + 0.15 * fine[..., None], 0, 1)
        self.pano = np.clip(sky + (cloud - sky) * np.clip(1.6 * density, 0, 1), 0, 255).astype(np.float32)

    def _shift(self, t: float) -> float:
        return np.radians(self.cfg.cloud_drift_deg_s) * t

    def _sky(self, az, el, t):
        return self._sample_pano(self.pano, az, el, self._shift(t))

    def _sea(self, az, el, dist, waves, t):
        mirrored = self._sample_pano(self.pano, az, np.minimum(-el, _PANO_TOP), self._shift(t))
        grazing = np.sin(-el)
        fresnel = (0.05 + 0.95 * (1.0 - grazing) ** 6)[..., None]
        dark = np.array([22, 24, 44], np.float32)
        colour = dark + fresnel * (0.75 * mirrored - dark)
        glitter = np.clip(self._sun_glow(az, -el), 0, 1) ** 40
        colour = colour + 160.0 * (glitter * np.clip(waves, 0, None))[..., None] * np.array([1.0, 0.8, 0.5], np.float32)
        return colour * (1.0 + 0.2 * waves[..., None])


class VideoBackground:
    """§6.2.3: frames of a video file or of a rosbag2 image topic, resized to fill the image.

    The footage is taken as the rectified view (the lens model is applied to it with the
    UAV); it loops if the sequence is longer.
    """

    def __init__(self, camera: CameraModel, source: str, topic: str = ""):
        path = Path(source)
        if not source or not path.exists():
            raise BackgroundError(f"video background: file or bag {source!r} not found (give one: the scenario's "
                                  "background.video, or --video of simulate and make-detection-data)")
        self.size = (camera.width, camera.height)
        self.path, self.topic = path, topic
        self.is_bag = path.is_dir() or path.suffix in (".mcap", ".db3")
        self._iter, self._index = None, -1
        if self._next() is None:
            raise BackgroundError(f"video background: no readable frames in {source}")
        self._iter, self._index = None, -1

    def frame(self, index: int, t: float, cam_rot=None, cam_pos=None) -> np.ndarray:
        if index <= self._index:
            self._iter, self._index = None, -1
        img = None
        while self._index < index:
            img = self._next()
            if img is None:  # end of footage: loop
                self._iter = None
                img = self._next()
            self._index += 1
        return self._fit(img)

    def _next(self):
        if self._iter is None:
            self._iter = _bag_frames(self.path, self.topic) if self.is_bag else _video_frames(self.path)
        return next(self._iter, None)

    def _fit(self, img: np.ndarray) -> np.ndarray:
        w, h = self.size
        scale = max(w / img.shape[1], h / img.shape[0])
        resized = cv2.resize(img, (max(w, round(img.shape[1] * scale)), max(h, round(img.shape[0] * scale))),
                             interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
        y0, x0 = (resized.shape[0] - h) // 2, (resized.shape[1] - w) // 2
        return np.ascontiguousarray(resized[y0:y0 + h, x0:x0 + w])


def _video_frames(path: Path):
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise BackgroundError(f"video background: OpenCV cannot open {path}")
    try:
        while True:
            ok, bgr = cap.read()
            if not ok:
                return
            yield cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    finally:
        cap.release()


def _bag_frames(path: Path, topic: str):
    from .bag import iter_images

    yield from iter_images(path, topic)


def make_background(cfg: BackgroundConfig, camera: CameraModel, ship: ShipConfig, rng: np.random.Generator,
                    video: str | None = None):
    """The background of ``cfg.kind``; ``video`` overrides ``cfg.video`` for the ``video`` kind."""
    if cfg.kind == "normal":
        return NormalBackground(camera, cfg, ship, rng)
    if cfg.kind == "complex":
        return ComplexBackground(camera, cfg, ship, rng)
    return VideoBackground(camera, video or cfg.video, cfg.video_topic)
