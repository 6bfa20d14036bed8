"""Photo-consistency in texturing: a face's view that shows something else there than most of its views
(an object present in a minority of the photos) is dropped; exposure and white-balance changes and
faces without a clear majority are left alone."""

from __future__ import annotations

import cv2
import numpy as np
from surface_scene import with_gains

from recon.eval.texture import masked_psnr, render
from recon.geometry.transforms import backproject, project
from recon.surface.options import TextureOptions
from recon.surface.raycast import render_ids, scene_of
from recon.surface.texture import texture_mesh
from recon.surface.texture.consistency import inconsistent


def _entries(n_faces: int, n_views: int, seed: int = 0):
    """Every face seen in every view: base colours, per-view exposure (+-0.7 stops) and white balance
    (+-12 %), and a little noise."""
    rng = np.random.default_rng(seed)
    face, view = (a.ravel() for a in np.meshgrid(np.arange(n_faces), np.arange(n_views), indexing="ij"))
    base = rng.uniform(30, 140, (n_faces, 3))  # no view saturates
    gain = 2.0 ** rng.uniform(-0.7, 0.7, (n_views, 1)) * rng.uniform(0.88, 1.12, (n_views, 3))
    colours = np.clip(base[face] * gain[view] + rng.normal(0, 2, (len(face), 3)), 0, 255)
    return face, view, colours


def test_a_minority_showing_something_else_is_dropped_and_exposure_is_not():
    face, view, colours = _entries(200, 9)
    car = (face < 60) & (view < 3)  # 3 of 9 photos show a car over 60 faces
    colours[car] = [200.0, 20.0, 20.0]
    out = inconsistent(face, view, colours, 200, 9)
    assert out[car].all() and out[~car].mean() < 0.005  # noise on dark faces may cost a view now and then


def test_no_majority_or_too_few_views_drops_nothing():
    face, view, colours = _entries(40, 4)
    colours[(view < 2) & (face < 20)] = [20.0, 200.0, 20.0]  # two views against two
    assert not inconsistent(face, view, colours, 40, 4).any()
    face, view, colours = _entries(40, 2)
    colours[view == 0] = [20.0, 200.0, 20.0]
    assert not inconsistent(face, view, colours, 40, 2).any()


def _sees(point: np.ndarray, cam, depth: np.ndarray) -> bool:
    uv, z = project(cam.K, cam.R, cam.t, point[None])
    x, y = int(uv[0, 0]), int(uv[0, 1])
    return 0 <= x < depth.shape[1] and 0 <= y < depth.shape[0] and abs(depth[y, x] - z[0]) < 0.01 * z[0]


def _transient(scene, count: int = 4, radius: int = 14):
    """The photos with a red disc painted, in the ``count`` nearest views that see it, on a surface point of the
    first hold-out view that most photos see: something in a minority of the photos. Returns the photos
    and the point's pixel in that hold-out view."""
    cam = scene.holdout_cameras[0]
    h, w = scene.holdout_images[0].shape[:2]
    depth = render_ids(scene_of(scene.gt_mesh.vertices, scene.gt_mesh.faces), cam, w, h)["depth"]
    v, u = (a.ravel() for a in np.mgrid[h // 4:3 * h // 4:10, w // 4:3 * w // 4:10])
    pixels = np.column_stack([u + 0.5, v + 0.5])[np.isfinite(depth[v, u])]
    points = backproject(cam.K, cam.R, cam.t, pixels, depth[pixels[:, 1].astype(int), pixels[:, 0].astype(int)])
    seen = np.array([[_sees(p, c, d) for c, d in zip(scene.cameras, scene.depths, strict=True)] for p in points])
    best = int(np.argmax(seen.sum(axis=1)))
    assert seen[best].sum() >= 2 * count + 1  # the painted views are a minority
    photos = [im.copy() for im in scene.images]
    near = [j for j in np.argsort([np.linalg.norm(c.center - points[best]) for c in scene.cameras]) if seen[best, j]]
    for j in near[:count]:  # the closest views: those texturing would pick
        uv, _ = project(scene.cameras[j].K, scene.cameras[j].R, scene.cameras[j].t, points[best][None])
        cv2.circle(photos[j], (int(uv[0, 0]), int(uv[0, 1])), radius, (220, 30, 30), -1)
    return photos, pixels[best]


def _psnr_near(textured, scene, pixel, half: int = 15) -> float:
    """PSNR in the hold-out view over a window the size of the painted disc (radius 14 px in the photos)."""
    gt = scene.holdout_images[0]
    image, mask = render(textured, scene.holdout_cameras[0], gt.shape[1], gt.shape[0])
    window = np.zeros_like(mask)
    x, y = int(pixel[0]), int(pixel[1])
    window[y - half:y + half, x - half:x + half] = True
    return masked_psnr(image, gt, mask & window)


def test_an_object_in_a_minority_of_photos_stays_out_of_the_texture(small_scene, mesh):
    photos, pixel = _transient(small_scene)
    clean = _psnr_near(texture_mesh(mesh, small_scene.images, small_scene.cameras), small_scene, pixel)
    checked = _psnr_near(texture_mesh(mesh, photos, small_scene.cameras), small_scene, pixel)
    unchecked = _psnr_near(texture_mesh(mesh, photos, small_scene.cameras, TextureOptions(photo_consistency=False)),
                           small_scene, pixel)
    print(f"hold-out PSNR near the painted point: clean {clean:.2f} dB, checked {checked:.2f}, unchecked {unchecked:.2f}")
    assert checked > unchecked + 3 and checked > clean - 1


def test_exposure_changes_keep_the_texture(small_scene, mesh):
    photos = with_gains(small_scene.images)
    checked = texture_mesh(mesh, photos, small_scene.cameras)
    unchecked = texture_mesh(mesh, photos, small_scene.cameras, TextureOptions(photo_consistency=False))
    assert np.mean(checked.face_view == unchecked.face_view) > 0.95
