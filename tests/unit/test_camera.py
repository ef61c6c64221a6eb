"""Camera model against OpenCV (projectPoints, undistortPoints, undistort) and camera_info I/O."""

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from uav_landing_vision.camera import (
    CameraInfoError,
    CameraModel,
    camera_from_info_fields,
    camera_from_info_msg,
    camera_info_fields,
    load_camera_info_yaml,
    save_camera_info_yaml,
)
from uav_landing_vision.resources import config_path


@pytest.fixture(scope="module")
def shipped():
    return load_camera_info_yaml(config_path("camera.yaml"))


# Unlike the shipped calibration: fx ≠ fy, an off-centre principal point and k3 ≠ 0.
GENERAL = CameraModel(640, 480, [[800.0, 0.0, 330.0], [0.0, 760.0, 250.0], [0.0, 0.0, 1.0]],
                      [-0.25, 0.1, 0.001, -0.002, -0.03])


# The other lens models of sensor_msgs/CameraInfo: a rational radial factor, and a fisheye lens of
# ~77 deg across (equidistant).
RATIONAL = CameraModel(640, 480, GENERAL.K, [0.12, -0.05, 0.001, -0.002, 0.01, 0.35, -0.02, 0.004],
                       distortion_model="rational_polynomial")
FISHEYE = CameraModel(640, 480, [[400.0, 0.0, 322.0], [0.0, 402.0, 236.0], [0.0, 0.0, 1.0]],
                      [-0.05, 0.01, -0.002, 0.0005], distortion_model="equidistant")


@pytest.fixture(scope="module", params=["shipped", "general", "rational", "fisheye"])
def camera(request, shipped):
    """The shipped calibration, :data:`GENERAL`, :data:`RATIONAL` and :data:`FISHEYE`."""
    return {"shipped": shipped, "general": GENERAL, "rational": RATIONAL, "fisheye": FISHEYE}[request.param]


@pytest.fixture
def points(camera):
    rng = np.random.default_rng(7)
    z = rng.uniform(5.0, 100.0, 400)
    uv = rng.uniform([0, 0], [camera.width, camera.height], size=(400, 2))
    x = (uv[:, 0] - camera.cx) / camera.fx * z
    y = (uv[:, 1] - camera.cy) / camera.fy * z
    return np.stack([x, y, z], axis=-1)


def test_default_calibration(shipped):
    assert (shipped.width, shipped.height) == (1280, 720)
    assert shipped.is_distorted
    assert shipped.dist.shape == (5,)


def test_project_matches_cv2_project_points(camera, points):
    if camera.distortion_model == "equidistant":
        expected, _ = cv2.fisheye.projectPoints(points.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), camera.K, camera.dist)
    else:
        expected, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), camera.K, camera.dist)
    np.testing.assert_allclose(camera.project(points), expected.reshape(-1, 2), atol=1e-9)
    expected0, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), camera.K, np.zeros(5))
    np.testing.assert_allclose(camera.project_pinhole(points), expected0.reshape(-1, 2), atol=1e-9)


def test_undistort_points_inverts_projection(camera, points):
    raw = camera.project(points)
    np.testing.assert_allclose(camera.undistort_points(raw), camera.project_pinhole(points), atol=1e-6)


def test_backproject_inverts_pinhole(camera, points):
    uv = camera.project_pinhole(points)
    np.testing.assert_allclose(camera.backproject(uv, points[:, 2]), points, atol=1e-9)


def test_undistortion_maps_match_cv2_undistort(camera):
    rng = np.random.default_rng(3)
    raw = cv2.GaussianBlur(rng.integers(0, 255, (camera.height, camera.width, 3), dtype=np.uint8), (9, 9), 3)
    map1, map2 = camera.undistortion_maps()
    ours = cv2.remap(raw, map1, map2, cv2.INTER_LINEAR)
    if camera.distortion_model == "equidistant":
        expected = cv2.fisheye.undistortImage(raw, camera.K, camera.dist, Knew=camera.K)
    else:
        expected = cv2.undistort(raw, camera.K, camera.dist)
    inner = (slice(40, -40), slice(60, -60))  # borders differ only by the fill of unmapped pixels
    diff = np.abs(ours[inner].astype(int) - expected[inner].astype(int))
    assert np.percentile(diff, 99) <= 2


def test_distortion_maps_invert_undistortion(camera):
    """Rectified → raw (distortion maps) then raw → rectified recovers a smooth image."""
    yy, xx = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float32)
    rect = (127 + 100 * np.sin(xx / 37.0) * np.cos(yy / 23.0)).astype(np.float32)
    raw = cv2.remap(rect, *camera.distortion_maps(), cv2.INTER_LINEAR)
    back = cv2.remap(raw, *camera.undistortion_maps(), cv2.INTER_LINEAR)
    inner = (slice(60, -60), slice(80, -80))
    assert np.abs(back[inner] - rect[inner]).max() < 3.0
    # A raw pixel sees the rectified pixel that the forward model maps onto it.
    mapx, mapy = camera.distortion_maps()
    pt = camera.backproject(np.array([mapx[100, 200], mapy[100, 200]]), 10.0)
    np.testing.assert_allclose(camera.project(pt), [200, 100], atol=1e-3)


def test_yaml_round_trip(camera, tmp_path):
    path = tmp_path / "cam.yaml"
    save_camera_info_yaml(camera, path)
    again = load_camera_info_yaml(path)
    np.testing.assert_array_equal(again.K, camera.K)
    np.testing.assert_array_equal(again.dist, camera.dist)
    assert again.distortion_model == camera.distortion_model
    assert (again.width, again.height) == (camera.width, camera.height)


def test_camera_info_fields_round_trip(camera):
    fields = camera_info_fields(camera)
    assert len(fields["k"]) == 9 and len(fields["p"]) == 12 and len(fields["r"]) == 9
    again = camera_from_info_fields(**{k: fields[k] for k in ("width", "height", "distortion_model", "d", "k", "r")})
    np.testing.assert_array_equal(again.K, camera.K)
    np.testing.assert_array_equal(again.dist, camera.dist)
    assert again.distortion_model == fields["distortion_model"] == camera.distortion_model


_K = "image_width: 1280\nimage_height: 720\ncamera_matrix: {rows: 3, cols: 3, data: [900,0,640,0,900,360,0,0,1]}\n"


@pytest.mark.parametrize(
    "text, message",
    [
        ("image_width: 1280\n", "camera_matrix"),
        ("- not a mapping\n", "not a camera_info"),
        ("image_width: 1280\nimage_height: 720\nbogus: 1\n", "unknown keys"),
        (
            "image_width: 1280\nimage_height: 720\ndistortion_model: fov\n"
            "camera_matrix: {rows: 3, cols: 3, data: [1,0,0,0,1,0,0,0,1]}\n",
            "not supported",
        ),
        ("image_width: 1280\nimage_height: 720\ncamera_matrix: {rows: 3, cols: 3, data: [1,2]}\n", "needs 9"),
        (
            "image_width: -5\nimage_height: 720\ncamera_matrix: {rows: 3, cols: 3, data: [900,0,1,0,900,1,0,0,1]}\n",
            "1..16384 px a side",
        ),
        ("image_width: [1\n", "cannot read"),
        (
            "image_width: 1280\nimage_height: 720\ncamera_matrix: {rows: 3, cols: 3, data: [a,0,1,0,900,1,0,0,1]}\n",
            "'camera_matrix' must be a list of numbers",
        ),
        (
            "image_width: 1280\nimage_height: 720\ncamera_matrix: {rows: 3, cols: 3, data: [900,0,1,0,900,1,0,0,1]}\n"
            "distortion_coefficients: {rows: 1, cols: 5, data: [0, 0, 0, 0, x]}\n",
            "'distortion_coefficients' must be a list of numbers",
        ),
        (
            "image_width: 1280.5\nimage_height: 720\ncamera_matrix: {rows: 3, cols: 3, data: [900,0,1,0,900,1,0,0,1]}\n",
            "'image_width' must be an integer",
        ),
        (
            "image_width: 1280\nimage_height: 720\ncamera_matrix: {rows: 3, cols: 3, data: [900,0,1,0,900,1,0,0,1]}\n"
            "projection_matrix: {rows: 3, cols: 4, data: [900,0,1,0,900,1,0,0,1]}\n",
            "'projection_matrix' needs 12",
        ),
        ("image_width: 1280\nimage_height: 720\ncamera_matrix: {rows: 1, cols: 9, data: [900,0,1,0,900,1,0,0,1]}\n",
         "must be 3x3"),
        ("image_width: 1280\nimage_width: 640\n", "duplicate key 'image_width'"),
        # Distortion given in another layout, or numbers of another type, was read as no distortion or as 1.0.
        (f"{_K}distortion_coefficients: [-0.3, 0.1, 0.0, 0.0, 0.0]\n", "'distortion_coefficients' must be a mapping"),
        (f"{_K}distortion_coefficients: {{rows: 1, cols: 5, date: [-0.3, 0.1, 0, 0, 0]}}\n",
         "'distortion_coefficients' must be a mapping with rows, cols and data"),
        (f"{_K}distortion_coefficients: {{rows: 1, cols: 5, data: [true, 0, 0, 0, 0]}}\n",
         r"'distortion_coefficients' must be a list of numbers, got \[True"),
        (f"{_K}distortion_coefficients: {{rows: 1, cols: 5, data: ['-0.3', 0, 0, 0, 0]}}\n",
         "'distortion_coefficients' must be a list of numbers"),
        (_K.replace("[900,", "[1" + "0" * 400 + ","), "'camera_matrix' must be a list of numbers"),  # OverflowError before
        # Too many values, a scalar for a list, a missing height and a boolean width.
        (_K.replace("0,0,1]", "0,0,1,0]"), "'camera_matrix' needs 9 values, has 10"),
        (_K.replace("[900,0,640,0,900,360,0,0,1]", "900"), "'camera_matrix' must be a list of numbers, got 900"),
        (_K.replace("image_height: 720\n", ""), "missing image_height"),
        (_K.replace("image_width: 1280", "image_width: true"),
         "'image_width' must be an integer number of pixels, got True"),
        # A size that disagrees with the values: ROS's parser would read another count.
        (f"{_K}distortion_coefficients: {{rows: 1, cols: 5, data: [-0.3, 0.1, 0, 0]}}\n",
         "'distortion_coefficients' must be 1x4 for its 4 values, got 1x5"),
        (f"{_K}distortion_coefficients: {{rows: 5, cols: 1, data: [-0.3, 0.1, 0, 0, 0]}}\n",
         "'distortion_coefficients' must be 1x5 for its 5 values, got 5x1"),
    ],
)
def test_bad_yaml_is_a_clear_error(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(CameraInfoError, match=message):
        load_camera_info_yaml(path)


def test_a_yaml_that_is_not_text_is_a_clear_error(tmp_path):
    path = tmp_path / "camera.yaml"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00")  # e.g. a calibration image given by mistake
    with pytest.raises(CameraInfoError, match=f"cannot read camera calibration {path}: unacceptable character"):
        load_camera_info_yaml(path)  # a UnicodeDecodeError naming no file before


def test_bad_camera_info_fields():
    with pytest.raises(CameraInfoError, match="uncalibrated"):
        camera_from_info_fields(640, 480, "plumb_bob", [0] * 5, [0] * 9)
    with pytest.raises(CameraInfoError, match="not supported"):
        camera_from_info_fields(640, 480, "fov", [0.9], [500, 0, 320, 0, 500, 240, 0, 0, 1])
    with pytest.raises(CameraInfoError, match="1..16384 px a side"):  # no remap table or framebuffer that size
        camera_from_info_fields(2**32 - 1, 1, "plumb_bob", [0] * 5, [500, 0, 320, 0, 500, 240, 0, 0, 1])
    with pytest.raises(CameraInfoError, match=r"coefficients, got \[-0.2, nan, 0.0, 0.0, 0.0\]"):  # was "got 5"
        camera_from_info_fields(640, 480, "plumb_bob", [-0.2, np.nan, 0, 0, 0], [500, 0, 320, 0, 500, 240, 0, 0, 1])


def _info_msg(binning=(0, 0), roi=(0, 0, 0, 0)):
    """A stand-in for ``sensor_msgs/CameraInfo`` of a 640x480 camera (ROI: x, y, width, height)."""
    x, y, w, h = roi
    return SimpleNamespace(width=640, height=480, distortion_model="plumb_bob", d=[0.0] * 5,
                           k=[500.0, 0, 320, 0, 500, 240, 0, 0, 1], r=[1.0, 0, 0, 0, 1, 0, 0, 0, 1],
                           binning_x=binning[0], binning_y=binning[1],
                           roi=SimpleNamespace(x_offset=x, y_offset=y, width=w, height=h))


def test_binning_and_regions_of_interest_are_refused():
    """K and D describe the full sensor: a binned or cropped stream would not match them."""
    for ok in (_info_msg(), _info_msg((1, 1)), _info_msg(roi=(0, 0, 640, 480))):
        assert camera_from_info_msg(ok).width == 640
    for binning in ((2, 2), (2, 1), (1, 2)):
        with pytest.raises(CameraInfoError, match=f"binning {binning[0]}x{binning[1]}"):
            camera_from_info_msg(_info_msg(binning))
    for roi in ((10, 20, 320, 240), (0, 20, 640, 460), (10, 0, 630, 480)):
        with pytest.raises(CameraInfoError, match="region of interest"):
            camera_from_info_msg(_info_msg(roi=roi))


def test_a_stereo_rectification_is_refused_and_p_is_k_with_no_baseline(tmp_path):
    """R rotates a stereo camera's rays and P's fourth column is its baseline (image_geometry reads
    Tx ≠ 0 as the right eye): a monocular camera has R = I and P = [K | 0]."""
    turned = [0.0, 1, 0, -1, 0, 0, 0, 0, 1]
    with pytest.raises(CameraInfoError, match="R must be identity"):
        camera_from_info_fields(640, 480, "plumb_bob", [0] * 5, [500, 0, 320, 0, 500, 240, 0, 0, 1], turned)
    (tmp_path / "stereo.yaml").write_text(f"{_K}rectification_matrix: {{rows: 3, cols: 3, data: {turned}}}\n")
    with pytest.raises(CameraInfoError, match="rectification rotation"):
        load_camera_info_yaml(tmp_path / "stereo.yaml")
    camera = CameraModel(640, 480, [[500, 0, 320], [0, 510, 240], [0, 0, 1]])
    np.testing.assert_array_equal(camera_info_fields(camera)["p"], np.hstack([camera.K, np.zeros((3, 1))]).ravel())


def test_skew_is_refused(points):
    """OpenCV's undistortion ignores K's skew, so a skewed camera's undistort_points and remap
    tables would not invert its projection (by ~1.6 px here): such a calibration is refused."""
    K = np.array([[800.0, 3.0, 330.0], [0.0, 780.0, 250.0], [0.0, 0.0, 1.0]])
    dist = np.array([-0.3, 0.12, 0.001, -0.002, -0.02])
    raw, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K, dist)
    K0 = K * [[1, 0, 1], [1, 1, 1], [1, 1, 1]]
    np.testing.assert_allclose(cv2.undistortPoints(raw, K, dist), cv2.undistortPoints(raw, K0, dist))
    with pytest.raises(ValueError, match="skew"):
        CameraModel(640, 480, K, dist)
    with pytest.raises(CameraInfoError, match="skew"):
        camera_from_info_fields(640, 480, "plumb_bob", dist, K.ravel())


def test_projection_rejects_points_behind_camera(camera):
    with pytest.raises(ValueError, match="behind"):
        camera.project(np.array([0.0, 0.0, -1.0]))
    with pytest.raises(ValueError, match="behind"):
        camera.project_pinhole(np.array([1.0, 0.0, 0.0]))  # in the camera's plane
    with pytest.raises(ValueError, match="shape"):
        camera.project(np.zeros((3, 2)))


def test_camera_is_immutable(camera):
    with pytest.raises(ValueError):
        camera.K[0, 0] = 1.0
    with pytest.raises(ValueError):
        CameraModel(640, 480, np.eye(2))


@pytest.mark.parametrize("k", [[[800, 0, 320], [5, 800, 240], [0, 0, 1]], [[800, 0, 320], [0, 800, 240], [0, 0, 2]],
                               [[800, 0, 320], [0, 800, 240], [1, 0, 1]], [[800, 0, 320], [0, -800, 240], [0, 0, 1]]])
def test_a_matrix_that_is_not_intrinsic_is_refused(k):
    with pytest.raises(ValueError, match="not an intrinsic matrix"):
        CameraModel(640, 480, k)


@pytest.mark.parametrize("k, message", [
    ([[1e-300, 0, 320], [0, 1e-300, 240], [0, 0, 1]], "field of view"),
    ([[1e300, 0, 320], [0, 1e300, 240], [0, 0, 1]], "field of view"),
    ([[800, 0, 320], [0, 8e-4, 240], [0, 0, 1]], "field of view"),
    ([[800, 0, -1e9], [0, 800, 1e9], [0, 0, 1]], r"principal point \(-1e\+09, 1e\+09\) lies outside the 640x480 image"),
    ([[800, 0, 641], [0, 800, 240], [0, 0, 1]], "principal point"),
])
def test_a_matrix_no_lens_has_is_refused(k, message):
    """Such a camera_info was taken: every particle drawn off the image, the tracker 'ready' and never tracking."""
    with pytest.raises(ValueError, match=message):
        CameraModel(640, 480, k)


def test_each_bound_checks_its_own_axis():
    """A principal point or a focal length checked against the other axis's size went unnoticed."""
    K = [[500, 0, 600], [0, 500, 240], [0, 0, 1]]
    assert CameraModel(640, 480, K).cx == 600  # cx beyond the height, inside the width
    with pytest.raises(ValueError, match="principal point"):
        CameraModel(480, 640, K)  # the same cx beyond a portrait camera's width
    CameraModel(1000, 10, [[1e6, 0, 500], [0, 1, 5], [0, 0, 1]])  # 0.06° x 157°; read crosswise, 180° x 0.0006°
    CameraModel(16384, 480, [[5000, 0, 8192], [0, 5000, 240], [0, 0, 1]])  # a side of MAX_IMAGE_SIDE
    assert CameraModel(640, 480, K, frame_id="deck").rectified().frame_id == "deck"


def test_the_extreme_lenses_still_taken():
    CameraModel(640, 480, [[640 / np.pi, 0, 0], [0, 480 / np.pi, 480], [0, 0, 1]], [], distortion_model="equidistant")  # 180°
    CameraModel(640, 480, [[1e6, 0, 320], [0, 1e6, 240], [0, 0, 1]])  # 0.04°: a long telephoto


def test_each_distortion_model_takes_its_own_coefficient_count():
    """plumb_bob 0, 4 or 5; rational_polynomial 0 or 8; equidistant 0 or 4: a D of another length
    was calibrated for another model (ROS's camera_info, cv2.calibrateCamera's rational flag)."""
    assert CameraModel(640, 480, GENERAL.K, [], distortion_model="equidistant").dist.tolist() == [0.0] * 4
    assert not CameraModel(640, 480, GENERAL.K, [], distortion_model="rational_polynomial").is_distorted
    with pytest.raises(ValueError, match="distortion must be 0 or 4 finite equidistant coefficients"):
        CameraModel(640, 480, GENERAL.K, [0.1] * 5, distortion_model="equidistant")
    with pytest.raises(ValueError, match="distortion must be 0 or 8 finite rational_polynomial coefficients"):
        CameraModel(640, 480, GENERAL.K, [0.1] * 5, distortion_model="rational_polynomial")
    with pytest.raises(ValueError, match="distortion model 'fisheye' is not one of"):
        CameraModel(640, 480, GENERAL.K, [0.1] * 4, distortion_model="fisheye")
    with pytest.raises(CameraInfoError, match="distortion must be 0 or 4 finite equidistant coefficients"):
        camera_from_info_fields(640, 480, "equidistant", [0.1] * 5, GENERAL.K.ravel())
    rectified = FISHEYE.rectified()
    assert rectified.distortion_model == "plumb_bob" and not rectified.is_distorted
    np.testing.assert_array_equal(rectified.K, FISHEYE.K)


def test_an_equidistant_lens_without_coefficients_is_still_distorted():
    """θ_d = θ is not the pinhole's tan θ: OpenCV's fisheye rectification moves a corner pixel of
    such a lens by tens of pixels, so it is no rectified camera."""
    camera = CameraModel(1280, 720, [[600, 0, 639.5], [0, 600, 359.5], [0, 0, 1]], [], distortion_model="equidistant")
    assert camera.is_distorted
    assert np.hypot(*(camera.undistort_points(np.array([0.0, 0.0])) - [0.0, 0.0])) > 10.0


def test_four_distortion_coefficients_mean_k3_zero():
    camera = CameraModel(640, 480, GENERAL.K, [-0.2, 0.05, 0.001, -0.002])
    np.testing.assert_array_equal(camera.dist, [-0.2, 0.05, 0.001, -0.002, 0.0])


@pytest.mark.parametrize("model, d", [("", []), ("", [0.0] * 5), ("plumb_bob", [])])
def test_a_camera_info_without_distortion_coefficients_has_none(model, d):
    camera = camera_from_info_fields(640, 480, model, d, GENERAL.K.ravel())
    np.testing.assert_array_equal(camera.dist, np.zeros(5))


def test_coefficients_without_a_distortion_model_are_refused(tmp_path):
    """An empty distortion_model does not say how to read D: four coefficients are also an
    equidistant (fisheye) lens's, whose rectification read as plumb_bob is off by >100 px."""
    fisheye = [-0.05, 0.01, -0.002, 0.0005]
    K = np.array([[600.0, 0.0, 639.5], [0.0, 600.0, 359.5], [0.0, 0.0, 1.0]])
    as_fisheye = cv2.fisheye.initUndistortRectifyMap(K, np.array(fisheye), np.eye(3), K, (1280, 720), cv2.CV_32FC1)
    as_plumb_bob = cv2.initUndistortRectifyMap(K, np.array(fisheye), None, K, (1280, 720), cv2.CV_32FC1)
    assert np.hypot(*(a - b for a, b in zip(as_fisheye, as_plumb_bob)))[100, 100] > 100.0
    with pytest.raises(CameraInfoError, match="4 non-zero distortion coefficients but no distortion_model"):
        camera_from_info_fields(1280, 720, "", fisheye, K.ravel())
    path = tmp_path / "camera.yaml"
    path.write_text("image_width: 640\nimage_height: 480\ndistortion_model: ''\n"
                    "camera_matrix: {rows: 3, cols: 3, data: [500, 0, 320, 0, 500, 240, 0, 0, 1]}\n"
                    "distortion_coefficients: {rows: 1, cols: 4, data: [-0.05, 0.01, -0.002, 0.0005]}\n")
    with pytest.raises(CameraInfoError, match="no distortion_model"):
        load_camera_info_yaml(path)


def test_a_side_of_max_image_side_is_taken_in_height_too_and_a_zero_side_is_refused():
    """Both sides may reach MAX_IMAGE_SIDE, and a side of 0 px is refused for its size, not for a
    field of view."""
    assert CameraModel(480, 16384, [[5000, 0, 240], [0, 5000, 8192], [0, 0, 1]]).height == 16384
    for width, height in ((0, 480), (640, 0)):
        with pytest.raises(ValueError, match="1..16384 px a side"):
            CameraModel(width, height, [[500, 0, 0], [0, 500, 0], [0, 0, 1]])


@pytest.mark.parametrize("k, message", [
    ([[-800, 0, 320], [0, 800, 240], [0, 0, 1]], "not an intrinsic matrix"),
    ([[0, 0, 320], [0, 800, 240], [0, 0, 1]], "not an intrinsic matrix"),
    ([[800, 0, 320], [0, 800, 240], [0, 1, 1]], "not an intrinsic matrix"),
    ([[800, -3, 320], [0, 800, 240], [0, 0, 1]], "skew"),
    ([[np.inf, 0, 320], [0, 800, 240], [0, 0, 1]], "finite 3x3"),
    ([[800, 0, np.nan], [0, 800, 240], [0, 0, 1]], "finite 3x3"),
])
def test_each_entry_of_k_is_checked_for_its_own_reason(k, message):
    """A non-positive fx, a non-zero K[2, 1], a negative skew or a non-finite entry: each named."""
    with pytest.raises(ValueError, match=message):
        CameraModel(640, 480, k)


def test_the_principal_point_may_lie_on_any_image_border_but_cy_not_beyond_the_height():
    """0 ≤ cx ≤ width and 0 ≤ cy ≤ height, each against its own side."""
    assert CameraModel(640, 480, [[500, 0, 640], [0, 500, 0], [0, 0, 1]]).cx == 640
    with pytest.raises(ValueError, match=r"principal point \(320, 500\) lies outside"):
        CameraModel(640, 480, [[500, 0, 320], [0, 500, 500], [0, 0, 1]])  # inside the width, beyond the height


@pytest.mark.parametrize("axis", [0, 1])
def test_the_field_of_view_limits_hold_on_either_axis(axis):
    """2 atan(side / 2f) just inside 0.01°..179° is a lens; just outside it is not."""
    size = (640, 480)

    def camera(fov_deg):
        f = [500.0, 500.0]
        f[axis] = size[axis] / 2 / np.tan(np.radians(fov_deg) / 2)
        return CameraModel(*size, [[f[0], 0, 320], [0, f[1], 240], [0, 0, 1]])

    camera(178.9), camera(0.0105)
    for fov in (179.1, 0.0095):
        with pytest.raises(ValueError, match="field of view"):
            camera(fov)


def test_sizes_are_whole_pixels_and_stored_as_python_ints(tmp_path):
    """A float or bool size is refused (True passed an int test as a 1 px side); numpy integers
    (e.g. from an image's shape) are taken as int, so that the camera can be written as YAML."""
    for width, height in [(640.0, 480), (True, 480), (640, np.True_)]:
        with pytest.raises(ValueError, match="must be integers"):
            CameraModel(width, height, [[500, 0, 0.5], [0, 500, 240], [0, 0, 1]])
    camera = CameraModel(np.int64(640), np.int32(480), GENERAL.K, GENERAL.dist)
    assert type(camera.width) is int and type(camera.height) is int
    save_camera_info_yaml(camera, tmp_path / "cam.yaml")
    again = load_camera_info_yaml(tmp_path / "cam.yaml")
    assert (again.width, again.height) == (640, 480)


def test_the_distortion_coefficients_are_read_only():
    with pytest.raises(ValueError):
        GENERAL.dist[0] = 0.0


@pytest.mark.parametrize("name", ["general", "rational"])
def test_undistort_points_converges_at_the_raw_image_corners(name):
    """The raw image's corners and edge midpoints, where the lens bends most: re-projected by
    cv2.projectPoints, their rectified points land back on them to 1e-6 px."""
    camera = {"general": CameraModel(640, 480, GENERAL.K, [-0.4, 0.2, 0.001, -0.002, -0.05]), "rational": RATIONAL}[name]
    uv = np.array([[0.0, 0.0], [639.0, 0.0], [0.0, 479.0], [639.0, 479.0], [320.0, 0.0], [0.0, 240.0]])
    rect = camera.undistort_points(uv)
    rays = np.hstack([(rect - [camera.cx, camera.cy]) / [camera.fx, camera.fy], np.ones((len(uv), 1))])
    back, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), camera.K, camera.dist)
    np.testing.assert_allclose(back.reshape(-1, 2), uv, atol=1e-6)


def test_a_camera_matrix_given_as_data_alone_is_read(tmp_path):
    """rows and cols may be left out of a block whose data has the right count."""
    path = tmp_path / "camera.yaml"
    path.write_text("image_width: 640\nimage_height: 480\ncamera_matrix: {data: [500, 0, 320, 0, 510, 240, 0, 0, 1]}\n")
    np.testing.assert_array_equal(load_camera_info_yaml(path).K, [[500, 0, 320], [0, 510, 240], [0, 0, 1]])



def test_a_yaml_without_a_distortion_model_reads_its_coefficients_as_plumb_bob(tmp_path):
    """Older calibration files have no distortion_model key: their five coefficients are plumb_bob's
    (an explicit empty model, as a CameraInfo message has it, is refused instead)."""
    path = tmp_path / "camera.yaml"
    path.write_text(f"{_K}distortion_coefficients: {{rows: 1, cols: 5, data: [-0.3, 0.1, 0.001, -0.002, 0.0]}}\n")
    camera = load_camera_info_yaml(path)
    assert camera.distortion_model == "plumb_bob"
    np.testing.assert_array_equal(camera.dist, [-0.3, 0.1, 0.001, -0.002, 0.0])


def test_a_saved_yaml_has_rows_times_cols_of_each_block_and_an_identity_r(camera, tmp_path):
    """ROS's parser reads rows x cols values of each block: D's block says its own length."""
    import yaml

    save_camera_info_yaml(camera, tmp_path / "cam.yaml")
    doc = yaml.safe_load((tmp_path / "cam.yaml").read_text())
    for key in ("camera_matrix", "distortion_coefficients", "rectification_matrix", "projection_matrix"):
        assert doc[key]["rows"] * doc[key]["cols"] == len(doc[key]["data"]), key
    assert doc["distortion_coefficients"]["cols"] == camera.dist.size
    np.testing.assert_array_equal(camera_info_fields(camera)["r"], np.eye(3).ravel())


def test_some_zero_coefficients_without_a_distortion_model_are_still_refused():
    """One non-zero coefficient is enough to need a model that says how to read it."""
    with pytest.raises(CameraInfoError, match="2 non-zero distortion coefficients but no distortion_model"):
        camera_from_info_fields(640, 480, "", [-0.3, 0.1, 0.0, 0.0, 0.0], GENERAL.K.ravel())


def test_an_all_zero_r_is_taken_and_a_k_of_another_size_refused(tmp_path):
    """Drivers without rectification leave R all zeros (read as none, in a message and in a file
    alike); a K that is not 9 values (e.g. P's 12) is no intrinsic matrix."""
    camera = camera_from_info_fields(640, 480, "plumb_bob", [0] * 5, GENERAL.K.ravel(), [0.0] * 9)
    np.testing.assert_array_equal(camera.K, GENERAL.K)
    (tmp_path / "zero_r.yaml").write_text(f"{_K}rectification_matrix: {{rows: 3, cols: 3, data: {[0.0] * 9}}}\n")
    assert load_camera_info_yaml(tmp_path / "zero_r.yaml").K[0, 0] == 900.0
    with pytest.raises(CameraInfoError, match="camera_info K is missing"):
        camera_from_info_fields(640, 480, "plumb_bob", [0] * 5, np.hstack([GENERAL.K, np.zeros((3, 1))]).ravel())


def test_a_region_of_interest_offset_in_y_alone_is_refused():
    with pytest.raises(CameraInfoError, match=r"region of interest 640x480\+0\+20"):
        camera_from_info_msg(_info_msg(roi=(0, 20, 640, 480)))


def _calibration_msg(**changes):
    """:func:`_info_msg` with the fields named changed (``roi_*``: those of its region of interest)."""
    msg = _info_msg()
    for name, value in changes.items():
        setattr(msg.roi if name.startswith("roi_") else msg, name.removeprefix("roi_"), value)
    return msg


@pytest.mark.parametrize("changes", [{"k": [510.0, 0, 320, 0, 505, 240, 0, 0, 1]}, {"d": [-0.2, 0.05, 0, 0, 0]}])
def test_a_calibration_of_other_k_or_d_values_is_taken(changes):
    """Same sizes and model, other K or D values: a new calibration, not a repeat."""
    from uav_landing_vision.nodes.calibration import Calibration

    calibration = Calibration()
    assert calibration.update(_calibration_msg())
    assert calibration.update(_calibration_msg(**changes))
    expected = camera_from_info_msg(_calibration_msg(**changes))
    np.testing.assert_array_equal(calibration.camera.K, expected.K)
    np.testing.assert_array_equal(calibration.camera.dist, expected.dist)


def test_a_calibration_whose_roi_height_alone_changes_is_checked_again():
    """A region of interest of 0 x 480 is a crop, refused, not the repeat of the full image's."""
    from uav_landing_vision.nodes.calibration import Calibration

    calibration = Calibration()
    assert calibration.update(_calibration_msg())
    with pytest.raises(CameraInfoError, match="region of interest 0x480"):
        calibration.update(_calibration_msg(roi_height=480))


def test_a_calibration_is_handed_to_use_before_it_is_taken():
    """use(camera) switches the node; if it refuses, the camera in use stays and the same message is tried again."""
    from uav_landing_vision.nodes.calibration import Calibration

    calibration, used = Calibration(), []
    assert calibration.update(_calibration_msg(), use=used.append)
    assert [c.fx for c in used] == [500.0] and calibration.camera is used[0]

    def refuse(camera):
        raise CameraInfoError("the node cannot switch")

    other = _calibration_msg(k=[520.0, 0, 320, 0, 520, 240, 0, 0, 1])
    with pytest.raises(CameraInfoError, match="cannot switch"):
        calibration.update(other, use=refuse)
    assert calibration.camera.fx == 500.0 and calibration.refused == "the node cannot switch"
    assert calibration.update(other, use=used.append) and calibration.camera.fx == 520.0 == used[-1].fx
