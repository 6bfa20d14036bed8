"""View quality, the data term of view selection: area times sharpness relative to the other views."""

import cv2
import numpy as np

import recon.surface.texture.views as views
from recon.surface.raycast import render_ids, scene_of
from recon.surface.texture.views import relative_sharpness, view_quality


def _quality(mesh, images, cameras):
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    scene = scene_of(vertices, faces)
    depths = [render_ids(scene, cam, im.shape[1], im.shape[0])["depth"] for cam, im in zip(cameras, images, strict=True)]
    return view_quality(vertices, faces, images, cameras, depths)


def test_relative_sharpness_is_capped_at_the_median_and_zero_where_unseen():
    sharpness = np.array([[0.1, 0.2, 0.4, np.nan], [np.nan, np.nan, np.nan, np.nan], [0.3, np.nan, np.nan, np.nan]],
                         np.float32)
    expected = [[0.5, 1, 1, 0], [0, 0, 0, 0], [1, 0, 0, 0]]
    np.testing.assert_allclose(relative_sharpness(sharpness), expected)
    np.testing.assert_allclose(relative_sharpness(sharpness, block=1), expected)  # taken a face at a time


def test_a_blurred_photo_scores_lower(small_scene, mesh):
    before = _quality(mesh, small_scene.images, small_scene.cameras)
    images = list(small_scene.images)
    images[3] = cv2.GaussianBlur(images[3], (0, 0), 3.0)
    after = _quality(mesh, images, small_scene.cameras)
    seen = before[:, 3] > 0
    assert np.array_equal(seen, after[:, 3] > 0)
    ratio = after[seen, 3] / before[seen, 3]
    assert np.median(ratio) < 0.8
    assert after[seen, 3].sum() < 0.7 * before[seen, 3].sum()


def test_a_photo_with_more_texture_than_the_others_scores_its_area_and_no_more(small_scene, mesh, monkeypatch):
    """A view whose photo shows busier texture at a face than the other views do (where the mesh is off the
    surface, it shows something else there) gains nothing over a view as sharp as the others."""
    images = list(small_scene.images)
    height, width = images[3].shape[:2]
    blocks = np.random.default_rng(0).integers(0, 2, (height // 2 + 1, width // 2 + 1), dtype=np.uint8) * 255
    images[3] = np.repeat(np.repeat(blocks, 2, 0), 2, 1)[:height, :width, None].repeat(3, 2)  # black and white 2 x 2
    busy = _quality(mesh, images, small_scene.cameras)
    monkeypatch.setattr(views, "gradient_magnitude", lambda image: np.ones(image.shape[:2], np.float32))
    area = _quality(mesh, images, small_scene.cameras)  # every view equally sharp: the area (a tenth by silhouettes)
    seen = area[:, 3] > 0
    assert seen.sum() > 100
    assert np.all(busy[seen, 3] <= area[seen, 3] * (1 + 1e-5))
    assert np.mean(np.isclose(busy[seen, 3], area[seen, 3], rtol=1e-5)) > 0.95
