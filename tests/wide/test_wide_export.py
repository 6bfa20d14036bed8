"""transforms.json for fisheye and 360 cameras, in the fields nerfstudio reads."""

from __future__ import annotations

import numpy as np
import pycolmap
import pytest

from recon.sparse.export import intrinsics


def test_fisheye_models_become_opencv_fisheye():
    cam = pycolmap.Camera(model="OPENCV_FISHEYE", width=640, height=480,
                          params=[260.5, 261.0, 321.0, 239.0, -0.01, 0.02, -0.003, 0.0005])
    out = intrinsics(cam)
    assert out == {"camera_model": "OPENCV_FISHEYE", "fl_x": 260.5, "fl_y": 261.0, "cx": 321.0, "cy": 239.0,
                   "w": 640, "h": 480, "k1": -0.01, "k2": 0.02, "k3": -0.003, "k4": 0.0005}
    radial = intrinsics(pycolmap.Camera(model="RADIAL_FISHEYE", width=640, height=480,
                                        params=[250.0, 320.0, 240.0, 0.1, -0.02]))
    assert radial["camera_model"] == "OPENCV_FISHEYE" and radial["fl_x"] == radial["fl_y"] == 250.0
    assert (radial["k1"], radial["k2"], radial["k3"], radial["k4"]) == (0.1, -0.02, 0.0, 0.0)
    assert "p1" not in radial  # nerfstudio's fisheye has no tangential terms
    pinhole = intrinsics(pycolmap.Camera(model="SIMPLE_RADIAL", width=640, height=480, params=[500.0, 320, 240, 0.1]))
    assert pinhole["camera_model"] == "OPENCV" and pinhole["k1"] == 0.1 and pinhole["p2"] == 0.0


def _nerfstudio_equirect_ray(px: np.ndarray, fx, fy, cx, cy) -> np.ndarray:
    """nerfstudio's ray direction (cameras.py, EQUIRECTANGULAR) for pixel positions (N, 2) with
    centres at +0.5, in OpenGL camera axes."""
    u, v = (px[:, 0] - cx) / fx, -(px[:, 1] - cy) / fy
    theta, phi = -np.pi * u, np.pi * (0.5 - v)
    return np.column_stack([-np.sin(theta) * np.sin(phi), np.cos(phi), -np.cos(theta) * np.sin(phi)])


@pytest.mark.parametrize("size", [(1536, 768), (640, 320)])
def test_equirectangular_rays_agree_with_colmap(size):
    cam = pycolmap.Camera(model="EQUIRECTANGULAR", width=size[0], height=size[1], params=list(map(float, size)))
    out = intrinsics(cam)
    assert out["camera_model"] == "EQUIRECTANGULAR" and (out["w"], out["h"]) == size
    px = np.random.default_rng(0).uniform([0, 0], size, (200, 2))
    gl = _nerfstudio_equirect_ray(px, out["fl_x"], out["fl_y"], out["cx"], out["cy"])
    colmap = cam.cam_ray_from_img(px)
    np.testing.assert_allclose(gl * [1, -1, -1], colmap, atol=1e-9)  # OpenGL -> COLMAP camera axes
