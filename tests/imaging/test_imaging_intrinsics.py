"""Intrinsics: COLMAP parameter order, OpenCV conversion, scaling and (un)distortion."""

import cv2
import numpy as np
import pytest

from recon.imaging.intrinsics import Intrinsics

OPENCV = Intrinsics("OPENCV", 640, 480, (600.0, 590.0, 321.0, 239.0, -0.2, 0.05, 0.001, -0.002))


def test_parameters_and_validation():
    assert (OPENCV.fx, OPENCV.fy, OPENCV.cx, OPENCV.cy) == (600.0, 590.0, 321.0, 239.0)
    simple = Intrinsics("SIMPLE_RADIAL", 100, 80, (90.0, 50.0, 40.0, 0.1))
    assert simple.fx == simple.fy == 90.0 and list(simple.opencv_distortion()) == [0.1, 0, 0, 0]
    assert not Intrinsics.pinhole(1, 1, 1, 1, 2, 2).has_distortion and OPENCV.has_distortion
    with pytest.raises(ValueError):
        Intrinsics("PINHOLE", 10, 10, (1.0, 2.0, 3.0))
    with pytest.raises(ValueError):
        Intrinsics("FISHEYE_X", 10, 10, ())


def test_opencv_round_trip_moves_the_principal_point_by_half_a_pixel():
    K = OPENCV.opencv_K()
    assert K[0, 2] == 320.5 and K[1, 2] == 238.5
    back = Intrinsics.from_opencv(K, OPENCV.opencv_distortion(), 640, 480)
    assert back == OPENCV
    full = Intrinsics.from_opencv(K, np.array([-0.2, 0.05, 0.0, 0.0, 0.01]), 640, 480)
    assert full.model == "FULL_OPENCV" and full.param("k3") == 0.01
    assert Intrinsics.from_opencv(K, None, 640, 480).model == "PINHOLE"


def test_projection_matches_opencv_and_inverts():
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(-0.5, 0.5, (50, 2)), rng.uniform(1, 3, 50)])
    ours = OPENCV.project(points)
    theirs, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), OPENCV.opencv_K(), OPENCV.opencv_distortion())
    assert np.abs(ours - (theirs.reshape(-1, 2) + 0.5)).max() < 1e-9
    rays = OPENCV.undistort_pixels(ours)
    assert np.abs(rays - points[:, :2] / points[:, 2:]).max() < 1e-10


def test_scaled_follows_colmap_rescale():
    half = OPENCV.scaled(320, 240)
    assert half.params == (300.0, 295.0, 160.5, 119.5, -0.2, 0.05, 0.001, -0.002)
    simple = Intrinsics("SIMPLE_PINHOLE", 101, 100, (100.0, 50.5, 50.0)).scaled(50, 50)
    assert simple.params[0] == pytest.approx(100.0 * 0.5 * (50 / 101 + 0.5))


def test_pycolmap_round_trip():
    camera = OPENCV.to_pycolmap()
    assert camera.model.name == "OPENCV" and camera.width == 640
    assert Intrinsics.from_pycolmap(camera) == OPENCV
