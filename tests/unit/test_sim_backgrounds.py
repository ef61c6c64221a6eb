"""The simulator's backgrounds (§6.2.1–6.2.3) and the plain sky-over-sea backdrop against
independent geometry and hand-worked values: each pixel's ray is rebuilt here from the intrinsics
and the camera rotation, turned into azimuth/elevation and intersected with the waterline; the
panorama and sea-texture look-ups are checked against direct indexing, the sky drift against a
yawed view, the colours against the documented formulas, and the video footage's fit against the
pixels it keeps."""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision.camera import CameraModel
from uav_landing_vision.render.backdrop import sky_and_sea
from uav_landing_vision.sim import backgrounds as bgm
from uav_landing_vision.sim.backgrounds import ComplexBackground, NormalBackground, VideoBackground, make_background
from uav_landing_vision.sim.config import BackgroundConfig, ShipConfig

# fx != fy and cx != cy, so that a swapped intrinsic changes the rays.
K = np.array([[100.0, 0.0, 70.5], [0.0, 90.0, 50.25], [0.0, 0.0, 1.0]])
CAMERA = CameraModel(160, 120, K)
SHIP = ShipConfig()


def _look(direction, roll_deg=0.0) -> np.ndarray:
    """Rotation optical → M of a camera whose optical axis points along ``direction`` (M), image
    x to the right and y down with M's z up, then rolled about the optical axis."""
    z = np.asarray(direction, float) / np.linalg.norm(direction)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    rot = np.stack([x, y, z], axis=1)
    return rot @ Rotation.from_rotvec([0.0, 0.0, np.radians(roll_deg)]).as_matrix()


def _unit(az, el):
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def _rays_in_m(cam_rot):
    """Unit ray of every pixel centre of CAMERA in M, (H, W, 3)."""
    u, v = np.meshgrid(np.arange(CAMERA.width, dtype=float), np.arange(CAMERA.height, dtype=float))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    return rays @ cam_rot.T


# A camera looking aft and 12° down, rolled 15°: the horizon crosses the image obliquely.
CAM_ROT = _look(_unit(np.radians(170.0), np.radians(-12.0)), roll_deg=15.0)
CAM_POS = np.array([5.0, 0.7, 0.5])


class _Probe(bgm._RayBackground):
    """The backgrounds' shared ray machinery, recording what the colour functions get: sky black, sea white."""

    def _sky(self, az, el, t):
        self.sky_args = (az, el, t)
        return np.zeros(az.shape + (3,), np.float32)

    def _sea(self, az, el, dist, waves, t):
        self.sea_args = (el, dist, t)
        return np.full(az.shape + (3,), 255.0, np.float32)

    def _sea_texture(self, x, y, dist):
        self.water = (x, y)
        return np.zeros_like(dist)


@pytest.fixture(scope="module")
def probe():
    return _Probe(CAMERA, BackgroundConfig(sea_jitter_m=0.0), SHIP, np.random.default_rng(0))


@pytest.fixture(scope="module")
def normal():
    """The normal background without its faint haze (the panorama-sized fractal noise is zero), so
    that its sky is the elevation ramp plus the sun's glow exactly."""
    real = bgm.fractal_noise

    def no_haze(rng, shape, slope, stretch=(1.0, 1.0)):
        return real(rng, shape, slope, stretch) if shape == (512, 512) else np.zeros(shape, np.float32)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(bgm, "fractal_noise", no_haze)
        return NormalBackground(CAMERA, BackgroundConfig(), SHIP, np.random.default_rng(1))


@pytest.fixture(scope="module")
def complex_bg():
    """The complex background's colour functions over a smooth synthetic panorama (its own cloud
    synthesis is slow and not what is checked here)."""
    bg = ComplexBackground.__new__(ComplexBackground)
    bgm._RayBackground.__init__(bg, CAMERA, BackgroundConfig(kind="complex"), SHIP, np.random.default_rng(2))
    i = np.arange(bg.pano_h, dtype=np.float32)[:, None, None]
    j = np.arange(bg.pano_w, dtype=np.float32)[None, :, None]
    phase = np.array([0.0, 1.0, 2.0], np.float32)
    bg.pano = (120 + 60 * np.sin(2 * np.pi * 23 * j / bg.pano_w + phase) * np.cos(i / 40.0 + phase)).astype(np.float32)
    return bg


@pytest.mark.parametrize("stretch", [(1.0, 0.3), (0.5, 1.0)])
def test_fractal_noise_is_standardised_with_the_requested_anisotropic_power_law(stretch):
    """Power ∝ 1/f^slope with f = hypot(f_row / stretch_row, f_col / stretch_col): a regression of
    the averaged periodogram on that frequency gives the slope, and the anisotropy is explained."""
    slope, shape = 3.0, (128, 128)
    rng = np.random.default_rng(4)
    power = np.zeros((shape[0], shape[1] // 2 + 1))
    for _ in range(40):
        field = bgm.fractal_noise(rng, shape, slope, stretch)
        assert field.dtype == np.float32 and field.shape == shape
        assert abs(float(field.mean())) < 1e-5 and float(field.std()) == pytest.approx(1.0, abs=1e-5)
        power += np.abs(np.fft.rfft2(field)) ** 2
    fy = np.broadcast_to(np.fft.fftfreq(shape[0])[:, None], power.shape)
    fx = np.broadcast_to(np.fft.rfftfreq(shape[1])[None, :], power.shape)
    f = np.hypot(fy / stretch[0], fx / stretch[1])
    # Away from DC and from the Nyquist edges (where the clipped spectrum folds).
    use = (f > 0.02) & (f < 0.4) & (np.abs(fy) < 0.45) & (fx < 0.45)
    fit = np.polyfit(np.log(f[use]), np.log(power[use]), 1)
    assert fit[0] == pytest.approx(-slope, abs=0.15)
    residual = np.log(power[use]) - np.polyval(fit, np.log(f[use]))
    assert residual.std() < 0.35  # the anisotropic frequency explains the spectrum (periodogram scatter)
    # A stretch below 1 elongates features along that axis: neighbours along it correlate more.
    field = bgm.fractal_noise(np.random.default_rng(5), (256, 256), 3.0, stretch)
    along_rows = np.mean(field * np.roll(field, 4, axis=1))
    along_columns = np.mean(field * np.roll(field, 4, axis=0))
    long, short = (along_rows, along_columns) if stretch[1] < stretch[0] else (along_columns, along_rows)
    assert 1 - long < 0.6 * (1 - short)


def test_smoothstep_is_the_cubic_hermite_step():
    x = np.array([-1.0, 0.0, 0.25, 0.5, 0.75, 1.0, 2.0])
    np.testing.assert_allclose(bgm._smoothstep(0.0, 1.0, x), [0.0, 0.0, 0.15625, 0.5, 0.84375, 1.0, 1.0])
    np.testing.assert_allclose(bgm._smoothstep(-0.9, 1.0, np.array([0.05])), [0.5])


def test_each_pixel_sees_the_azimuth_and_elevation_of_its_own_ray(probe):
    """Azimuth from the bow, positive to port; elevation above the horizontal; the sky gets the frame's time."""
    probe.frame(0, 1.5, CAM_ROT, CAM_POS)
    d = _rays_in_m(CAM_ROT)
    az, el, t = probe.sky_args
    assert t == 1.5
    np.testing.assert_allclose(el, np.arcsin(d[..., 2]), atol=2e-5)
    wrapped = np.angle(np.exp(1j * (az - np.arctan2(d[..., 1], d[..., 0]))))
    assert np.abs(wrapped).max() < 2e-5


def test_horizon_row_of_a_camera_pitched_up_is_cy_plus_fy_tan_pitch(probe):
    """A forward camera tilted up by θ sees the horizon on the row v = cy + fy·tan θ, in every column."""
    v = np.arange(CAMERA.height)[:, None]
    for theta in (5.0, 12.0, -7.0):
        sea = probe.frame(0, 0.0, _look(_unit(0.0, np.radians(theta))), np.zeros(3))[..., 0] == 255
        row = K[1, 2] + K[1, 1] * np.tan(np.radians(theta))
        clear = np.broadcast_to(np.abs(v - row) > 0.5, sea.shape)
        np.testing.assert_array_equal(sea[clear], np.broadcast_to(v > row, sea.shape)[clear])


def test_sea_below_the_horizon_sky_above_it(probe):
    out = probe.frame(0, 0.0, CAM_ROT, CAM_POS)
    dz = _rays_in_m(CAM_ROT)[..., 2]
    sea = out[..., 0] == 255
    assert 0.2 < sea.mean() < 0.8  # the horizon crosses the image
    clear = np.abs(dz + 1e-4) > 2e-5
    np.testing.assert_array_equal(sea[clear], (dz < -1e-4)[clear])


@pytest.mark.parametrize("cam_rot", [CAM_ROT, _look(_unit(np.radians(-140.0), np.radians(-35.0)), roll_deg=-25.0)])
def test_the_sea_is_looked_up_where_each_ray_meets_the_waterline_and_flows_aft(probe, cam_rot):
    """The water point of a sea pixel lies on z = −net_height (M's origin is the net centre), on
    the pixel's ray from the camera, in a water frame that the ship leaves behind at its speed:
    x_water = x_M + speed·t."""
    d = _rays_in_m(cam_rot)
    sea = d[..., 2] < -2e-4
    assert sea.sum() > 1000
    dist = (-SHIP.net_height_m - CAM_POS[2]) / d[..., 2]
    point = CAM_POS + dist[..., None] * d
    t = 2.5
    probe.frame(3, t, cam_rot, CAM_POS)
    x, y = probe.water
    el, sea_dist, sea_t = probe.sea_args
    assert sea_t == t
    np.testing.assert_allclose(sea_dist[sea], dist[sea], rtol=1e-4)
    np.testing.assert_allclose(el[sea], np.arcsin(d[..., 2])[sea], atol=2e-5)
    np.testing.assert_allclose(x[sea], point[sea][:, 0] + SHIP.speed_mps * t, rtol=1e-4, atol=1e-3)
    np.testing.assert_allclose(y[sea], point[sea][:, 1], rtol=1e-4, atol=1e-3)


def test_sea_texture_is_swell_at_0_6_m_and_chop_at_0_06_m_per_texel_fading_with_distance(normal):
    rng = np.random.default_rng(6)
    i, j = rng.integers(0, 2000, 50), rng.integers(0, 2000, 50)
    x, y = (0.6 * i).astype(np.float32)[None], (0.6 * j).astype(np.float32)[None]
    swell = normal.swell[j % 512, i % 512]
    chop = normal.chop[(10 * j) % 512, (10 * i) % 512]
    for d in (0.0, 30.0, 200.0):
        got = normal._sea_texture(x, y, np.full(x.shape, d, np.float32))[0]
        np.testing.assert_allclose(got, swell * np.exp(-d / 250.0) + chop * np.exp(-d / 40.0), atol=2e-3)


def test_sun_direction_and_glow_are_the_cosine_to_the_sun(probe):
    """The sun at its azimuth about z, then raised by its elevation (scipy), and the glow of any
    direction the cosine of its angle to it."""
    cfg = probe.cfg
    sun = Rotation.from_euler("ZY", [cfg.sun_azimuth_deg, -cfg.sun_elevation_deg], degrees=True).apply([1.0, 0.0, 0.0])
    np.testing.assert_allclose(probe.sun, sun, atol=1e-12)
    dirs = np.random.default_rng(2).standard_normal((500, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    az, el = np.arctan2(dirs[:, 1], dirs[:, 0]), np.arcsin(dirs[:, 2])
    np.testing.assert_allclose(probe._sun_glow(az, el), dirs @ sun, atol=1e-9)
    assert probe._sun_glow(np.radians(cfg.sun_azimuth_deg), np.radians(cfg.sun_elevation_deg)) == pytest.approx(1.0)


def test_panorama_spans_55_to_minus_2_degrees_and_a_full_turn_at_0_06_degrees_per_pixel(normal):
    assert normal.pano.shape == (round(57 / 0.06), round(360 / 0.06), 3)
    np.testing.assert_allclose(np.degrees(normal._pano_elevations()[[0, -1]]), [55 - 0.03, -2 + 0.03], atol=1e-4)
    np.testing.assert_allclose(np.degrees(normal._pano_azimuths()[[0, -1]]), [-180 + 0.03, 180 - 0.03], atol=1e-3)


def test_panorama_is_read_at_the_pixel_centre_of_each_azimuth_and_elevation(probe):
    """A panorama that holds its own column and row index, sampled at the centre azimuth and
    elevation of column c and row r (0.06° pixels from −180° and from 55° down), gives (c, r)."""
    cols, rows = np.meshgrid(np.arange(probe.pano_w, dtype=np.float32), np.arange(probe.pano_h, dtype=np.float32))
    pano = np.stack([cols, rows], -1)
    rng = np.random.default_rng(1)
    c = rng.integers(1, probe.pano_w - 1, 400)
    r = rng.integers(1, probe.pano_h - 1, 400)
    az = np.radians(-180.0 + (c + 0.5) * 0.06).astype(np.float32)[None]
    el = np.radians(55.0 - (r + 0.5) * 0.06).astype(np.float32)[None]
    got = probe._sample_pano(pano, az, el)[0]
    np.testing.assert_allclose(got[:, 0], c, atol=0.02)
    np.testing.assert_allclose(got[:, 1], r, atol=0.02)
    np.testing.assert_allclose(probe._pano_azimuths()[c], az[0], atol=1e-5)
    np.testing.assert_allclose(probe._pano_elevations()[r], el[0], atol=1e-5)


def _centre_level(bg, direction):
    """Mean grey level of the 9×9 centre patch of the frame of a camera looking along ``direction``."""
    img = bg.frame(0, 0.0, _look(direction), np.array([0.0, 0.0, 0.5])).astype(float)
    cy, cx = int(round(K[1, 2])), int(round(K[0, 2]))
    return img[cy - 4:cy + 5, cx - 4:cx + 5].mean()


def test_the_sky_glows_towards_the_sun_as_cos8_of_the_angle_to_it(normal):
    """Looking at the sun (150° to port, 35° up) the sky is about 45 levels brighter than at the
    same elevation opposite it; 25° and 40° away in azimuth by 45·cos⁸ of the angle."""
    cfg = normal.cfg
    az, el = np.radians([cfg.sun_azimuth_deg, cfg.sun_elevation_deg])
    base = _centre_level(normal, _unit(az + np.pi, el))
    for delta_deg in (0.0, 25.0, 40.0, -40.0):
        direction = _unit(az + np.radians(delta_deg), el)
        expected = 45.0 * max(float(direction @ normal.sun), 0.0) ** 8
        assert _centre_level(normal, direction) - base == pytest.approx(expected, abs=1.0), delta_deg
    # the mirror image of the sun's azimuth (to starboard) has next to no glow
    assert _centre_level(normal, _unit(-az, el)) - base < 3.0


def test_clear_sky_is_deep_blue_high_up_and_pale_at_the_horizon(normal):
    az = np.full((1, 2), np.radians(-30.0), np.float32)  # away from the sun
    el = np.radians(np.array([[50.0, 1.0]], np.float32))
    high, low = normal._sky(az, el, 0.0)[0]
    assert high[2] - high[0] > 70 and high[2] > high[1] > high[0]
    assert high[2] - high[0] > low[2] - low[0] + 40 and low.sum() > high.sum() + 60


def test_normal_sea_colour_follows_schlick_fresnel_waves_and_haze(normal):
    deep, reflected, fog = np.array([28, 62, 88.0]), np.array([190, 205, 218.0]), np.array([205, 214, 222.0])
    el = np.radians(np.array([-90.0, -30.0, -5.0, -0.01]))
    az = np.zeros_like(el)
    fresnel = 0.02 + 0.98 * (1 - np.sin(-el)) ** 5
    colour = deep + fresnel[:, None] * (reflected - deep)
    got = normal._sea(az, el, np.zeros_like(el), np.zeros_like(el), 0.0)
    np.testing.assert_allclose(got, colour, rtol=1e-5)
    assert got[0] == pytest.approx(0.98 * deep + 0.02 * reflected, rel=1e-5)  # straight down: the deep water
    waves = np.array([1.0, -1.0, 0.5, 2.0])
    dist = np.array([0.0, 900.0, 450.0, 2700.0])
    haze = np.exp(-dist / 900.0)[:, None]
    expected = haze * colour * (1 + 0.2 * waves[:, None]) + (1 - haze) * fog
    np.testing.assert_allclose(normal._sea(az, el, dist, waves, 0.0), expected, rtol=1e-5)


def test_complex_sea_mirrors_the_sky_at_the_opposite_elevation_and_glitters_towards_the_sun(complex_bg):
    rng = np.random.default_rng(9)
    az = rng.uniform(-np.pi, np.pi, 40).astype(np.float32)[None]
    el = -np.radians(rng.uniform(0.5, 50.0, 40)).astype(np.float32)[None]
    sky_above = complex_bg._sky(az, -el, 0.0)
    fresnel = (0.05 + 0.95 * (1 - np.sin(-el)) ** 6)[..., None]
    dark = np.array([22, 24, 44.0])
    calm = complex_bg._sea(az, el, np.zeros_like(el), np.zeros_like(el), 0.0)
    np.testing.assert_allclose(calm, dark + fresnel * (0.75 * sky_above - dark), rtol=1e-4, atol=1e-3)
    # glitter: the sun's reflection lies at its azimuth and minus its elevation
    sun_az, sun_el = np.radians([complex_bg.cfg.sun_azimuth_deg, complex_bg.cfg.sun_elevation_deg])
    az2 = np.array([[sun_az, sun_az + np.pi / 2]], np.float32)
    el2 = np.array([[-sun_el, -sun_el]], np.float32)
    ones = np.ones_like(az2)
    glitter = complex_bg._sea(az2, el2, ones, ones, 0.0) / 1.2 - complex_bg._sea(az2, el2, ones, 0 * ones, 0.0)
    np.testing.assert_allclose(glitter[0, 0], 160.0 * np.array([1.0, 0.8, 0.5]), rtol=1e-3)
    np.testing.assert_allclose(glitter[0, 1], 0.0, atol=1e-3)


def test_complex_sky_drifts_by_cloud_drift_deg_s_towards_port(complex_bg):
    """A cloud at azimuth a at t = 0 is at a + drift·t later (azimuth positive to port)."""
    az = np.radians(np.linspace(-150.0, 150.0, 31, dtype=np.float32))[None]
    el = np.full_like(az, np.radians(10.0))
    t = 20.0
    later = complex_bg._sky(az + np.radians(complex_bg.cfg.cloud_drift_deg_s * t), el, t)
    np.testing.assert_allclose(later, complex_bg._sky(az, el, 0.0), atol=0.05)
    assert not np.allclose(complex_bg._sky(az, el, t), complex_bg._sky(az, el, 0.0), atol=1.0)


def test_make_background_builds_the_configured_kind(monkeypatch):
    monkeypatch.setattr(bgm, "NormalBackground", lambda *args: "normal")
    monkeypatch.setattr(bgm, "ComplexBackground", lambda *args: "complex")
    rng = np.random.default_rng(0)
    assert make_background(BackgroundConfig(kind="complex"), CAMERA, SHIP, rng) == "complex"
    assert make_background(BackgroundConfig(kind="normal"), CAMERA, SHIP, rng) == "normal"


def test_video_frames_are_rgb_and_the_same_index_gives_the_same_frame(tmp_path):
    frames = [np.zeros((64, 96, 3), np.uint8) for _ in range(3)]
    frames[0][...] = (220, 30, 30)  # red
    frames[1][...] = (30, 30, 220)  # blue
    frames[2][...] = (30, 220, 30)  # green
    writer = cv2.VideoWriter(str(tmp_path / "clip.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 10, (96, 64))
    for rgb in frames:
        writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    writer.release()
    bg = VideoBackground(CameraModel(96, 64, K), str(tmp_path / "clip.avi"))
    first = bg.frame(0, 0.0)
    assert first[..., 0].mean() > 150 and first[..., 2].mean() < 80  # red stays red in RGB
    again = bg.frame(1, 0.0)
    np.testing.assert_array_equal(bg.frame(1, 0.0), again)
    assert again[..., 2].mean() > 150


def test_video_frames_are_scaled_to_cover_the_image_and_cropped_centrally():
    """A 200×100 ramp (value = column) into a 100×100 camera: scale 1 (the height fits), keep
    columns 50–149; into 100×60: scale 0.6 → 120×60, keep the middle 100 columns. The ramp turned
    upright (value = row) into 100×100 keeps rows 50–149."""
    ramp = np.broadcast_to(np.arange(200, dtype=np.uint8)[None, :, None], (100, 200, 3)).copy()
    bg = VideoBackground.__new__(VideoBackground)
    bg.size = (100, 100)
    out = bg._fit(ramp)
    assert out.shape == (100, 100, 3)
    np.testing.assert_array_equal(out[:, :, 0], np.broadcast_to(np.arange(50, 150), (100, 100)))
    np.testing.assert_array_equal(bg._fit(ramp.transpose(1, 0, 2))[:, :, 0],
                                  np.broadcast_to(np.arange(50, 150)[:, None], (100, 100)))
    bg.size = (100, 60)
    out = bg._fit(ramp).astype(float)
    expected = cv2.resize(ramp, (120, 60), interpolation=cv2.INTER_AREA)[:, 10:110].astype(float)
    assert out.shape == (60, 100, 3)
    np.testing.assert_allclose(out, expected, atol=1.0)


def test_sky_and_sea_backdrop_colours_at_top_horizon_and_bottom():
    img = sky_and_sea(50, 200, horizon=0.6)
    assert img.shape == (200, 50, 3) and img.dtype == np.uint8
    assert np.all(img == img[:, :1])  # one colour per row
    col = img[:, 0].astype(float)
    np.testing.assert_array_equal(col[0], [70, 120, 200])  # top of the sky
    top, horizon_sky = np.array([70.0, 120.0, 200.0]), np.array([190.0, 215.0, 235.0])
    for r in (60, 119):  # linear from the top colour to the pale one at the horizon row 120
        np.testing.assert_allclose(col[r], (1 - r / 120) * top + r / 120 * horizon_sky, atol=0.51)
    np.testing.assert_array_equal(col[120], [60, 95, 125])  # the horizon row is sea
    np.testing.assert_allclose(col[199], [60 - 40 * 79 / 80, 95 - 50 * 79 / 80, 125 - 55 * 79 / 80], atol=0.6)
    np.testing.assert_array_equal(sky_and_sea(3, 10, 0.5)[:, 0, 0], [70, 94, 118, 142, 166, 60, 52, 44, 36, 28])
    # a horizon between rows (2.5): rows 0–2 sky at 0, 0.4, 0.8 of its gradient, rows 3–4 sea at 0.2, 0.6
    np.testing.assert_array_equal(sky_and_sea(1, 5, 0.5)[:, 0, 0], [70, 118, 166, 52, 36])
