"""The texture reads a photo as taken, with the sparse model's camera, where that camera has no
distortion, and resamples it into its undistorted view with Lanczos otherwise (recon.surface.texture.
sources); the undistorted workspace has pinhole cameras only (recon.stages.undistort.undistort_photos)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pycolmap
import pytest

from recon.imaging.masks import save_mask
from recon.mvs.views import model_views
from recon.stages.undistort import UndistortConfig, undistort_photos
from recon.surface.texture.sources import texture_sources

WIDTH, HEIGHT = 160, 120


def _workspace(tmp_path: Path, max_image_size: int = 0, smooth: bool = False) -> dict:
    """A sparse model of two photos, ``plain.png`` (SIMPLE_RADIAL with k1 = 0) and ``bent.png``
    (k1 = -0.1), their photos (noise, or a smooth pattern) and masks, and COLMAP's undistorted
    workspace of them."""
    rng = np.random.default_rng(0)
    rec = pycolmap.Reconstruction()
    photos, masks = tmp_path / "photos", tmp_path / "masks"
    photos.mkdir(parents=True)
    for image_id, (name, k1) in enumerate([("plain.png", 0.0), ("bent.png", -0.1)], start=1):
        rec.add_camera_with_trivial_rig(pycolmap.Camera(model="SIMPLE_RADIAL", width=WIDTH, height=HEIGHT,
                                                        params=[150.0, 80.0, 60.0, k1], camera_id=image_id))
        image = pycolmap.Image(name=name, camera_id=image_id, image_id=image_id)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(), [0.1 * image_id, 0, 0]))
        photo = rng.integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8)
        if smooth:
            y, x = np.mgrid[:HEIGHT, :WIDTH]
            photo[:] = (127.5 + 100 * np.sin(x / 6.0) * np.cos(y / 5.0)).astype(np.uint8)[..., None]
        cv2.imwrite(str(photos / name), photo)
        save_mask(masks, name, np.arange(WIDTH)[None, :].repeat(HEIGHT, 0) < 40 * image_id)
    model = tmp_path / "sparse"
    model.mkdir(parents=True)
    rec.write(str(model))
    dense = tmp_path / "dense"
    undistort_photos(model, photos, dense, UndistortConfig(max_image_size=max_image_size))
    dense_masks = dense / "masks"
    for name in ("plain.png", "bent.png"):
        save_mask(dense_masks, name, np.ones(cv2.imread(str(dense / "images" / name)).shape[:2], bool))
    return {"views": model_views(dense / "sparse"), "undistorted": dense / "images", "undistorted_masks": dense_masks,
            "model": model, "photos": photos, "photo_masks": masks}


def test_a_camera_without_distortion_comes_out_pinhole_without_a_size_limit(tmp_path):
    """Given no size limit, COLMAP copies such a photo and keeps its SIMPLE_RADIAL camera, which dense
    stereo cannot take: ``undistort.max_image_size: 0`` made the mvs stage fail."""
    _workspace(tmp_path)
    dense = pycolmap.Reconstruction(str(tmp_path / "dense" / "sparse"))
    assert {c.model_name for c in dense.cameras.values()} == {"PINHOLE"}
    assert {c.params[0] for c in dense.cameras.values()} == {150.0}  # both kept the focal length: no scaling


def _rgb(path: Path) -> np.ndarray:
    return cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)


def test_a_photo_without_distortion_is_read_as_taken_with_the_models_camera(tmp_path):
    ws = _workspace(tmp_path)
    assert [v.width for v in ws["views"]] != [WIDTH, WIDTH]  # the undistorter cropped and resampled both
    sources = texture_sources(**ws)
    names = [c.name for c in sources.cameras]
    plain, bent = names.index("plain.png"), names.index("bent.png")
    assert sources.as_taken == 1
    camera = sources.cameras[plain]
    assert (camera.width, camera.height) == (WIDTH, HEIGHT)
    np.testing.assert_allclose(camera.K, [[150, 0, 80], [0, 150, 60], [0, 0, 1]])
    np.testing.assert_allclose(camera.t, [0.1, 0, 0])
    assert np.array_equal(sources.images[plain], _rgb(ws["photos"] / "plain.png"))
    assert sources.masks[plain].sum() == 40 * HEIGHT  # preprocess's mask, in the photo's own pixels

    undistorted = next(v for v in ws["views"] if v.name == "bent.png")
    assert sources.cameras[bent] is undistorted
    assert sources.images[bent].shape == (undistorted.height, undistorted.width, 3)
    assert sources.masks[bent].all()  # the undistorted workspace's mask


def _gradient_energy(image: np.ndarray) -> float:
    grey = image.astype(float).mean(axis=2)[4:-4, 4:-4]
    return float(np.abs(np.diff(grey, axis=0)).mean() + np.abs(np.diff(grey, axis=1)).mean())


def test_a_photo_with_distortion_is_resampled_into_its_undistorted_view_sharper_than_colmap_does(tmp_path):
    """On a smooth pattern the resampled photo matches COLMAP's undistorted image (half a pixel off
    would differ by about 10 grey levels); on noise it keeps more of the photo's detail than COLMAP's
    bilinear lookups."""
    for smooth in (True, False):
        ws = _workspace(tmp_path / str(smooth), smooth=smooth)
        sources = texture_sources(**ws)
        assert sources.resampled == 1
        bent = [c.name for c in sources.cameras].index("bent.png")
        ours, colmap = sources.images[bent], _rgb(ws["undistorted"] / "bent.png")
        if smooth:
            assert np.abs(ours.astype(float) - colmap)[4:-4, 4:-4].mean() < 2.0
        else:
            assert _gradient_energy(ours) > 1.1 * _gradient_energy(colmap)


def test_photos_made_smaller_for_dense_work_are_textured_at_that_size(tmp_path):
    """``undistort.max_image_size`` bounds the texture's memory and time too."""
    ws = _workspace(tmp_path, max_image_size=80)
    sources = texture_sources(**ws)
    assert sources.as_taken == sources.resampled == 0
    assert all(image.shape[1] <= 80 for image in sources.images)


@pytest.mark.parametrize("model", ["OPENCV_FISHEYE", "PINHOLE"])
def test_only_a_camera_that_projects_as_a_pinhole_counts_as_without_distortion(model):
    """A fisheye with zero distortion coefficients still maps angles, not tangents, to pixels."""
    from recon.surface.texture.sources import _projects_as_pinhole

    camera = pycolmap.Camera(model=model, width=WIDTH, height=HEIGHT,
                             params=[150.0, 150.0, 80.0, 60.0] + [0.0] * (4 if model == "OPENCV_FISHEYE" else 0))
    assert _projects_as_pinhole(camera) == (model == "PINHOLE")
