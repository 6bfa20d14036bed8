"""The parts of the two-view stereo: calibration files, the left-right check, disparity sampling,
the search range, rectification's frames, outputs, and pairs from a sparse model."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from stereo_pairs import BASELINE, depth_scores, pinhole

from recon.imaging.intrinsics import Intrinsics
from recon.stereo import StereoOptions, from_poses, read_calibration, stereo_depth, write_calibration
from recon.stereo.depth import sample_disparity, textured
from recon.stereo.disparity import left_right_check, search_range
from recon.stereo.outputs import point_cloud, write_depth, write_ply
from recon.stereo.rectify import rectify

K_CV = [[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]]
R_SMALL = cv2.Rodrigues(np.radians([0.5, 1.0, 0.2]))[0]


def test_yaml_json_and_opencv_files_read_alike(tmp_path):
    yaml_file = tmp_path / "rig.yaml"
    yaml_file.write_text(f"image_size: [640, 480]\nK1: {K_CV}\nD1: [-0.1, 0.01, 0, 0]\nK2: {K_CV}\n"
                         f"R: {R_SMALL.tolist()}\nT: [-0.12, 0.001, 0.002]\n")
    calib = read_calibration(yaml_file)
    assert calib.left.model == "OPENCV" and calib.right.model == "PINHOLE"  # D2 absent: no distortion
    assert calib.left.cx == pytest.approx(320.0)  # OpenCV's 319.5 in COLMAP's convention
    assert calib.baseline == pytest.approx(np.linalg.norm([-0.12, 0.001, 0.002]))
    json_file = write_calibration(tmp_path / "rig.json", calib)
    storage = cv2.FileStorage(str(tmp_path / "rig.yml"), cv2.FILE_STORAGE_WRITE)
    for key, value in (("image_size", [640.0, 480.0]), ("K1", calib.left.opencv_K()), ("D1", calib.left.opencv_distortion()),
                       ("K2", calib.right.opencv_K()), ("R", R_SMALL), ("T", np.array([[-0.12], [0.001], [0.002]]))):
        storage.write(key, np.asarray(value, dtype=np.float64))
    storage.release()
    for other in (read_calibration(json_file), read_calibration(tmp_path / "rig.yml")):
        assert other.left == calib.left and other.right.model == "PINHOLE"
        np.testing.assert_allclose(other.R, calib.R)
        np.testing.assert_allclose(other.T, calib.T)


@pytest.mark.parametrize("text,words", [
    ("image_size: [640, 480]\n", "missing K1, K2, R, T"),
    (f"image_size: [640, 480]\nK1: {K_CV}\nK2: {K_CV}\nR: [[1, 0, 0], [0, 2, 0], [0, 0, 1]]\nT: [1, 0, 0]\n",
     "R is not a rotation"),
    (f"image_size: [640, 480]\nK1: {K_CV}\nK2: {K_CV}\nR: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\nT: [0, 0, 0]\n",
     "T is zero"),
    (f"image_size: [640, 480]\nK1: {K_CV}\nK2: {K_CV}\nD2: [1, 2, 3]\nR: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n"
     "T: [1, 0, 0]\n", "4, 5 or 8"),
    ("- just\n- a list\n", "expected a mapping"),
    ("image_size: [640, 480\n", "cannot parse"),
])
def test_bad_calibration_files(tmp_path, text, words):
    path = tmp_path / "rig.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match=words):
        read_calibration(path)


def test_calibration_fitted_to_other_photo_sizes(tmp_path):
    path = tmp_path / "rig.yaml"
    path.write_text(f"image_size: [640, 480]\nK1: {K_CV}\nK2: {K_CV}\nR: {np.eye(3).tolist()}\nT: [-1, 0, 0]\n")
    calib = read_calibration(path).fitted((1280, 960), (640, 480))
    assert calib.left.fx == pytest.approx(1000.0) and calib.left.cx == pytest.approx(640.0)
    assert calib.right.fx == pytest.approx(500.0)
    with pytest.raises(ValueError, match="another aspect ratio"):
        read_calibration(path).fitted((640, 360), (640, 480))


def test_left_right_check():
    left = np.array([[2.0, 2.0, 2.0, np.nan, 3.0, 3.0]], np.float32)
    right = np.array([[2.0, 9.0, 2.0, 2.5, np.nan, 3.0]], np.float32)
    # pixel 2 -> match 0 (2.0, kept); 3 has none; 4 -> 1 (9.0 vs 3.0); 5 -> 2 (2.0 vs 3.0); 0, 1 fall outside
    np.testing.assert_array_equal(left_right_check(left, right, 1.0)[0], [False, False, True, False, False, True])
    np.testing.assert_array_equal(left_right_check(left, right, 0.5)[0], [False, False, True, False, False, False])


def test_sample_disparity_interpolates_within_surfaces_only():
    disparity = np.array([[10.0, 11.0, 30.0], [10.0, 11.0, 30.0], [np.nan, 11.0, 30.0]], np.float32)
    x = np.array([0.5, 1.25, 1.75, 0.4, 2.0, 5.0])
    y = np.array([0.5, 0.0, 0.0, 1.4, 2.0, 0.0])
    got = sample_disparity(disparity, x, y)
    np.testing.assert_allclose(got[:2], [10.5, 11.0])  # bilinear inside a surface
    assert got[2] == 30.0  # across a depth edge: the nearest pixel, not 20.5
    assert got[3] == 10.0  # a NaN neighbour: the nearest pixel when it has a disparity
    assert got[4] == 30.0 and np.isnan(got[5])


def test_search_range():
    opts = StereoOptions()
    assert search_range((19.2, 56.2), -19.2, 640, opts) == (-1, 48)  # 0..37 after the offset: 39 -> 48
    assert search_range(None, 0.0, 640, opts) == (-1, 176)
    assert search_range(None, -5.0, 640, StereoOptions(min_disparity=5, num_disparities=30)) == (-1, 32)
    assert search_range((0.0, 900.0), 0.0, 640, opts) == (-1, 640)  # at most the width


def test_textured():
    image = np.zeros((20, 20), np.uint8)
    image[:, 10:] = np.random.default_rng(0).integers(0, 255, (20, 10))
    mask = textured(image, 5, 0.01)
    assert not mask[:, :7].any() and mask[:, 12:].all()


def test_forward_motion_is_refused():
    cam = Intrinsics.pinhole(500, 500, 320, 240, 640, 480)
    calib = from_poses(cam, (np.eye(3), np.zeros(3)), cam, (np.eye(3), np.array([0.05, 0.0, -1.0])))
    with pytest.raises(ValueError, match="along the viewing direction"):
        rectify(calib)


def test_outputs(render_pair, tmp_path):
    import trimesh

    from recon.mvs.colmap_io import read_depth_map

    pair = render_pair()
    calib = from_poses(pinhole(pair.left), (pair.left.R, pair.left.t), pinhole(pair.right),
                       (pair.right.R, pair.right.t))
    result = stereo_depth(pair.left_image, pair.right_image, calib, StereoOptions(max_image_size=320))
    paths = write_depth(tmp_path, result.depth)
    np.testing.assert_array_equal(np.load(paths["npy"]), result.depth)
    np.testing.assert_array_equal(read_depth_map(paths["bin"]), result.depth)
    # in the world frame: the points project back to their pixels with their depth
    points, colours = point_cloud(result, (pair.left.R, pair.left.t))
    cloud = trimesh.load(write_ply(tmp_path / "cloud.ply", points, colours))
    np.testing.assert_allclose(cloud.vertices, points, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(cloud.colors[:, :3], colours)
    rows, cols = np.nonzero(result.depth)
    K = result.camera.K
    x_cam = points @ pair.left.R.T + pair.left.t
    np.testing.assert_allclose(x_cam[:, 2], result.depth[rows, cols], rtol=1e-5)
    np.testing.assert_allclose((x_cam @ K.T)[:, 0] / x_cam[:, 2], cols + 0.5, atol=1e-6)
    np.testing.assert_array_equal(colours, result.image[rows, cols])


def test_pairs_from_a_sparse_model(render_pair):
    """The model's cameras, the best pair (ordered left to right), the depth range of its points."""
    from recon.mvs.gt_workspace import points_from_depths
    from recon.mvs.views import ViewCamera
    from recon.stereo.pairs import best_pair, depth_range, model_views, pair_calibration

    pair = render_pair(offset=(-BASELINE, 0.0, 0.0), rotation_deg=(0.0, 1.0, 0.5))  # right camera on the left
    cams = [ViewCamera(name, c.K, c.R, c.t, c.width, c.height) for name, c in (("a.png", pair.left),
                                                                                ("b.png", pair.right))]
    rec = points_from_depths(cams, [pair.left_depth, pair.right_depth], points_per_image=300)
    views = model_views(rec)
    assert sorted(views) == ["a.png", "b.png"]
    best = best_pair(rec, views)
    assert (best.left, best.right) == ("b.png", "a.png") and best.shared >= 300
    assert best.angle_deg == pytest.approx(3.0, abs=1.5)
    low, high = depth_range(rec, views["a.png"], 0.25)
    truth = pair.left_depth[pair.left_depth > 0]
    assert low <= truth.min() and truth.max() <= high < 1.3 * 1.25 * truth.max()
    assert best_pair(rec, views, among="a.png") is not None
    calib = pair_calibration(views["a.png"], views["b.png"])
    result = stereo_depth(pair.left_image, pair.right_image, calib, StereoOptions(), (low, high))
    assert depth_scores(result.depth, pair.left_depth, pair.left_image)["within"] >= 0.9
    assert json.dumps(result.figures)  # plain JSON for summary.json
