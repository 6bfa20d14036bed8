"""Photos whose camera has no distortion reach dense work as they were taken (recon.stages.undistort):
COLMAP's undistorter would crop them by a pixel and resample every pixel half a pixel over."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pycolmap

import recon
from recon.stages.undistort import _photos_as_taken

FULL = Path(__file__).resolve().parents[2] / "pipelines" / "full.yaml"


def test_photos_without_distortion_are_used_as_taken(sparse_workspace, small_scene, tmp_path):
    ws = tmp_path / "ws"
    shutil.copytree(sparse_workspace, ws, symlinks=True)
    recon.run(FULL, images=str(small_scene / "images"), workspace=str(ws), until="undistort",
              overrides=["sfm.deterministic=true"])
    sparse = pycolmap.Reconstruction(str(ws / "sparse" / "0"))
    dense = pycolmap.Reconstruction(str(ws / "dense" / "sparse"))
    (camera_id, camera), = sparse.cameras.items()
    assert not np.any(camera.params[list(camera.extra_params_idxs())])  # the small scene's: refused
    undistorted = dense.cameras[camera_id]
    assert undistorted.model.name == "PINHOLE" and (undistorted.width, undistorted.height) == (320, 240)
    f, cx, cy = camera.params[:3]
    assert list(undistorted.params) == [f, f, cx, cy]
    for image in dense.images.values():
        assert (ws / "dense" / "images" / image.name).read_bytes() == (small_scene / "images" / image.name).read_bytes()


def test_photos_with_distortion_are_left_to_the_undistorter(tmp_path):
    def model(k1: float) -> pycolmap.Reconstruction:
        rec = pycolmap.Reconstruction()
        rec.add_camera_with_trivial_rig(pycolmap.Camera(model="SIMPLE_RADIAL", width=64, height=48,
                                                        params=[50.0, 32.0, 24.0, k1], camera_id=1))
        rec.add_image_with_trivial_frame(pycolmap.Image(name="a.jpg", camera_id=1, image_id=1), pycolmap.Rigid3d())
        return rec

    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "a.jpg").write_bytes(b"photo")
    (tmp_path / "images").mkdir()
    (tmp_path / "images" / "a.jpg").write_bytes(b"undistorted")
    dense = pycolmap.Reconstruction()
    dense.add_camera_with_trivial_rig(pycolmap.Camera(model="PINHOLE", width=63, height=47,
                                                      params=[49.0, 49.0, 31.5, 23.5], camera_id=1))
    dense.add_image_with_trivial_frame(pycolmap.Image(name="a.jpg", camera_id=1, image_id=1), pycolmap.Rigid3d())
    assert _photos_as_taken(model(-0.05), dense, tmp_path / "photos", tmp_path / "images", 0) == 0
    assert (tmp_path / "images" / "a.jpg").read_bytes() == b"undistorted" and dense.cameras[1].width == 63
    assert _photos_as_taken(model(0.0), dense, tmp_path / "photos", tmp_path / "images", 40) == 0  # to be shrunk
    assert _photos_as_taken(model(0.0), dense, tmp_path / "photos", tmp_path / "images", 0) == 1
    assert (tmp_path / "images" / "a.jpg").read_bytes() == b"photo" and dense.cameras[1].width == 64
