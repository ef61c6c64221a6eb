"""Frame synthesis: the motion-blurred UAV layer is composited premultiplied, sensor noise has
the configured spread, and the simulator hands each frame the smear and sun it should."""

import dataclasses

import cv2
import numpy as np
import pytest

from uav_landing_vision.camera import CameraModel
from uav_landing_vision.geometry import matrix_to_quat
from uav_landing_vision.model import fixed_wing_mesh
from uav_landing_vision.sim import generators, load_scenario, make_trajectory, simulate
from uav_landing_vision.sim import synthesis
from uav_landing_vision.sim.config import ImagingConfig
from uav_landing_vision.sim.synthesis import FrameSynthesizer, motion_blur_kernel

MESH = fixed_wing_mesh("low")
FACING = matrix_to_quat(np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]]))
GREY = 90


@pytest.fixture(scope="module")
def synth():
    # No lens distortion: the raw image is the render camera's image cropped by the padding.
    K = np.array([[150.0, 0.0, 80.0], [0.0, 150.0, 60.0], [0.0, 0.0, 1.0]])
    cam = CameraModel(160, 120, K, np.zeros(5), "cam")
    with FrameSynthesizer(cam, ImagingConfig(noise_sigma=0.0), MESH) as s:
        yield s


def _frames(synth, shift):
    rc = synth.render_camera
    bg = np.full((rc.height, rc.width, 3), GREY, np.uint8)
    light = np.array([0.3, -1.0, -0.4])
    sharp = synth.frame(bg, FACING, [0.0, 0.0, 3.0], light, np.zeros(2), None)
    blurred = synth.frame(bg, FACING, [0.0, 0.0, 3.0], light, np.asarray(shift, float), None)
    return sharp, blurred


@pytest.mark.parametrize("shift", [(6.0, 0.0), (3.0, -4.0)])
def test_motion_blur_smears_the_uav_layer_and_its_coverage_premultiplied(synth, shift):
    """Over a uniform background b: blurred coverage = K * α, blurred frame = K * (I − (1−α) b)
    + (1 − K * α) b (a premultiplied layer), so the background stays b where the smear does not
    reach and the UAV's total brightness change is kept."""
    (raw0, a0), (raw1, a1) = _frames(synth, shift)
    k = motion_blur_kernel(np.asarray(shift))
    assert a0.sum() > 100 and not np.allclose(a0, a1)
    np.testing.assert_allclose(a1, cv2.filter2D(a0, -1, k, borderType=cv2.BORDER_CONSTANT), atol=2e-3)
    layer = raw0.astype(np.float32) - (1.0 - a0[..., None]) * GREY
    expected = cv2.filter2D(layer, -1, k, borderType=cv2.BORDER_CONSTANT) + (1.0 - a1[..., None]) * GREY
    np.testing.assert_allclose(raw1.astype(np.float32), expected, atol=1.6)
    far = cv2.dilate((a0 > 0).astype(np.uint8), np.ones((15, 15), np.uint8)) == 0
    assert np.all(raw1[far] == GREY)
    change0 = raw0.astype(float).sum() - GREY * raw0.size
    change1 = raw1.astype(float).sum() - GREY * raw1.size
    assert change1 == pytest.approx(change0, abs=0.02 * abs(change0) + raw0.size * 0.01)


def test_sensor_noise_has_the_configured_sigma_and_no_bias():
    K = np.array([[100.0, 0.0, 40.0], [0.0, 100.0, 30.0], [0.0, 0.0, 1.0]])
    cam = CameraModel(80, 60, K, np.zeros(5), "cam")
    with FrameSynthesizer(cam, ImagingConfig(noise_sigma=4.0), MESH) as s:
        rc = s.render_camera
        scene = np.full((rc.height, rc.width, 3), 120, np.uint8)
        raw = s.sensor(scene, np.random.default_rng(3)).astype(float)
    assert raw.shape == (60, 80, 3)
    assert np.std(raw) == pytest.approx(4.0, rel=0.08)
    assert np.mean(raw) == pytest.approx(120.0, abs=0.1)


def test_simulate_passes_each_frame_the_clipped_exposure_smear_and_the_sun_in_the_camera_frame(tmp_path, monkeypatch):
    """Smear of frame i: exposure_fraction × (pinhole centre of frame i − of frame i−1) in the
    render camera, shortened to max_blur_px (none for the first frame); the sun at azimuth az
    (from the bow, to port) and elevation el is (cos el cos az, cos el sin az, sin el) in M,
    expressed in the camera optical frame."""
    s = load_scenario("normal")
    s = dataclasses.replace(
        s,
        approach=dataclasses.replace(s.approach, start_range_m=(12.0, 14.0)),
        imaging=dataclasses.replace(s.imaging, exposure_fraction=0.4, max_blur_px=0.66),
        background=dataclasses.replace(s.background, sun_azimuth_deg=60.0, sun_elevation_deg=30.0),
    )
    calls = []

    def fake_frame(self, background, quat, trans, light_dir, blur_shift_px, rng):
        calls.append((np.array(trans), np.array(light_dir), np.array(blur_shift_px), self.render_camera.K.copy()))
        return np.zeros((self.camera.height, self.camera.width, 3), np.uint8), None

    monkeypatch.setattr(synthesis.FrameSynthesizer, "frame", fake_frame)
    simulate(s, tmp_path / "bag", seed=4, frames=6, progress=False, mesh=MESH)
    tr = make_trajectory(s, generators(4)).head(6)
    assert len(calls) == 6
    K = calls[0][3]
    centres = np.stack([K[0, 0] * tr.trans[:, 0] / tr.trans[:, 2] + K[0, 2],
                        K[1, 1] * tr.trans[:, 1] / tr.trans[:, 2] + K[1, 2]], axis=1)
    smear = np.zeros_like(centres)
    smear[1:] = 0.4 * np.diff(centres, axis=0)
    length = np.linalg.norm(smear, axis=1, keepdims=True)
    smear = np.where(length > 0.66, smear * 0.66 / np.maximum(length, 1e-12), smear)
    got = np.stack([c[2] for c in calls])
    lengths = np.linalg.norm(0.4 * np.diff(centres, axis=0), axis=1)
    assert np.any(lengths > 0.67) and np.any(lengths < 0.65)  # frames shortened and frames not
    np.testing.assert_allclose(got, smear, atol=1e-6)
    el, az = np.radians(30.0), np.radians(60.0)
    sun = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    for i, call in enumerate(calls):
        np.testing.assert_allclose(call[0], tr.trans[i])
        np.testing.assert_allclose(tr.cam_rot[i] @ call[1], sun, atol=1e-9)


@pytest.mark.parametrize("dist, spills", [([-0.3, 0.08, 0.002, -0.003, 0.0], True),
                                          ([0.15, 0.0, 0.0, 0.0, 0.0], False)])
def test_every_raw_pixels_ray_falls_inside_the_padded_render_camera(dist, spills):
    """The maps send each raw pixel to the render-camera pixel of its ray (projected back through
    the lens with cv2.projectPoints), which lies inside that camera: a few pixels from its edges
    where barrel distortion spills the rays past the raw image, unpadded where pincushion
    distortion keeps them inside."""
    K = np.array([[300.0, 0.0, 165.0], [0.0, 290.0, 118.0], [0.0, 0.0, 1.0]])
    cam = CameraModel(320, 240, K, np.array(dist), "cam")
    render, mx, my = synthesis.render_camera_for(cam)
    assert mx.shape == my.shape == (240, 320)
    np.testing.assert_allclose(render.K[:2, :2], K[:2, :2])
    x = (mx.astype(float) - render.K[0, 2]) / render.K[0, 0]
    y = (my.astype(float) - render.K[1, 2]) / render.K[1, 1]
    rays = np.stack([x.ravel(), y.ravel(), np.ones(x.size)], axis=-1)
    raw, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, np.array(dist))
    u, v = np.meshgrid(np.arange(320.0), np.arange(240.0))
    np.testing.assert_allclose(raw.reshape(240, 320, 2), np.stack([u, v], axis=-1), atol=2e-3)
    margins = [mx.min(), my.min(), render.width - 1 - mx.max(), render.height - 1 - my.max()]
    assert all(0.0 <= m for m in margins), margins
    if spills:
        assert all(m <= 3.0 for m in margins), margins
    else:
        assert (render.width, render.height) == (320, 240) and np.array_equal(render.K, K)


def test_a_smear_of_one_pixel_already_blurs():
    for shift in ([1.0, 0.0], [0.0, -1.0]):
        kernel = motion_blur_kernel(np.array(shift))
        assert kernel is not None and kernel.shape == (3, 3) and kernel.sum() == pytest.approx(1.0)
        assert np.count_nonzero(kernel) >= 2


def test_the_uav_is_lit_from_light_dir_the_direction_towards_the_sun(synth):
    """Facing the camera, the UAV is brighter with the sun behind the camera (towards −z) than
    with the sun behind the UAV (towards +z)."""
    rc = synth.render_camera
    bg = np.full((rc.height, rc.width, 3), GREY, np.uint8)
    front, alpha = synth.frame(bg, FACING, [0.0, 0.0, 3.0], np.array([0.0, -0.3, -1.0]), np.zeros(2), None)
    back, _ = synth.frame(bg, FACING, [0.0, 0.0, 3.0], np.array([0.0, -0.3, 1.0]), np.zeros(2), None)
    uav = alpha > 0.99
    assert uav.sum() > 50
    assert front[uav].mean() > back[uav].mean() + 40


@pytest.mark.parametrize("length", [1.0, 2.0, 3.0, 4.5, 5.0, 7.0, 8.0])
def test_a_blur_kernel_has_an_odd_side_that_holds_the_smear(length):
    for direction in ([1.0, 0.0], [0.0, -1.0], [0.6, 0.8]):
        side = motion_blur_kernel(length * np.array(direction)).shape
        assert side[0] == side[1] and side[0] % 2 == 1 and length + 1 <= side[0] < length + 3


def test_the_blurred_frame_is_rounded_to_the_nearest_grey_level(synth):
    """Over a uniform background the blurred frame is the premultiplied formula rounded, not
    truncated: no bias where the smear reaches."""
    (raw0, a0), (raw1, a1) = _frames(synth, (5.0, 2.0))
    layer = raw0.astype(np.float32) - (1.0 - a0[..., None]) * GREY
    k = motion_blur_kernel(np.array([5.0, 2.0]))
    expected = cv2.filter2D(layer, -1, k, borderType=cv2.BORDER_CONSTANT) + (1.0 - a1[..., None]) * GREY
    reached = a1 > 0.01
    assert reached.sum() > 100
    assert abs(np.mean(raw1[reached].astype(np.float32) - expected[reached])) < 0.2
