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
