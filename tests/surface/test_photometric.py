"""Photometric calibration before texturing: each photo's gain and the camera's vignetting, recovered
from the colours the photos show of the same faces, and undone."""

from __future__ import annotations

import numpy as np
import pytest
from surface_scene import with_gains

from recon.eval.texture import masked_psnr, render
from recon.surface.options import TextureOptions
from recon.surface.texture import texture_mesh
from recon.surface.texture.photometric import calibrate

GAMMA = 2.2


def test_gains_and_vignetting_are_recovered_despite_a_car():
    rng = np.random.default_rng(0)
    n_faces, n_views = 3000, 12
    face, view = (a.ravel() for a in np.meshgrid(np.arange(n_faces), np.arange(n_views), indexing="ij"))
    albedo = rng.uniform(40, 180, (n_faces, 3))
    gain = 2.0 ** rng.uniform(-0.5, 0.5, (n_views, 1)) * rng.uniform(0.9, 1.1, (n_views, 3))
    r2 = rng.uniform(0, 1, len(face))
    falloff = (1 - 0.4 * r2) ** (1 / GAMMA)  # 40 % of the light lost in the corners, in gamma-encoded values
    colours = np.clip(albedo[face] * gain[view] * falloff[:, None] + rng.normal(0, 2, (len(face), 3)), 0, 255)
    colours[(face < 500) & (view < 3)] = [200.0, 20.0, 20.0]  # a car in 3 photos over a sixth of the faces
    found = calibrate(face, view, colours, r2, np.zeros(n_views, np.int64), n_faces)
    ratio = found.gain / gain  # the gains are known up to a common factor per channel
    assert np.abs(ratio / np.median(ratio, axis=0) - 1).max() < 0.02
    x = np.linspace(0, 1, 11)
    assert np.abs(found.vignetting(0, x) - (1 - 0.4 * x) ** (1 / GAMMA)).max() < 0.02


def test_a_photo_that_shows_something_else_everywhere_keeps_its_own_exposure():
    """A photo black at faces the others see bright (poses off, the black background where the mesh has the
    object) gave a gain of 0.00; undone, its colours came out white or NaN."""
    rng = np.random.default_rng(1)
    n_faces, n_views = 2000, 8
    face, view = (a.ravel() for a in np.meshgrid(np.arange(n_faces), np.arange(n_views), indexing="ij"))
    colours = np.repeat(rng.uniform(40, 180, (n_faces, 3)), n_views, axis=0) + rng.normal(0, 2, (len(face), 3))
    colours[view == 5] = rng.uniform(0, 3, ((view == 5).sum(), 3))
    found = calibrate(face, view, colours, rng.uniform(0, 1, len(face)), np.zeros(n_views, np.int64), n_faces)
    assert np.array_equal(found.gain[5], [1.0, 1.0, 1.0])
    assert np.abs(np.delete(found.gain, 5, axis=0) - 1).max() < 0.02


def test_no_vignetting_is_fitted_from_faces_in_the_middle_of_the_photos_alone():
    """An object in the middle: the fall-off fitted to its faces, extrapolated to the corners, made them
    2.8 times brighter than the centre; a lens darkens its corners, so none is corrected."""
    rng = np.random.default_rng(2)
    n_faces, n_views = 3000, 12
    face, view = (a.ravel() for a in np.meshgrid(np.arange(n_faces), np.arange(n_views), indexing="ij"))
    r2 = rng.uniform(0, 0.3, len(face))
    bump = 1 + 0.6 * r2  # a shading trend over the middle of the photos that a fit extrapolates upwards
    colours = np.repeat(rng.uniform(40, 180, (n_faces, 3)), n_views, axis=0) * bump[:, None]
    found = calibrate(face, view, colours, r2, np.zeros(n_views, np.int64), n_faces)
    assert np.array_equal(found.falloff, [[0.0, 0.0]])
    darkened = calibrate(face, view, colours / bump[:, None] * (1 - 0.2 * r2)[:, None], r2,
                         np.zeros(n_views, np.int64), n_faces)
    assert darkened.vignetting(0, np.array([0.3]))[0] == pytest.approx(0.94, abs=0.02)  # a darkening is fitted


def vignetted(images: list[np.ndarray], loss: float = 0.4) -> list[np.ndarray]:
    """The photos with ``loss`` of the light lost in the corners (quadratic fall-off in linear light)."""
    out = []
    for im in images:
        h, w = im.shape[:2]
        yy, xx = np.mgrid[0:h, 0:w]
        r2 = ((xx + 0.5 - w / 2) ** 2 + (yy + 0.5 - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
        out.append(np.clip(im * ((1 - loss * r2) ** (1 / GAMMA))[..., None] + 0.5, 0, 255).astype(np.uint8))
    return out


def test_calibrated_photos_texture_closer_to_the_truth(small_scene, mesh):
    photos = vignetted(with_gains(small_scene.images))
    gt, cam = small_scene.holdout_images[0], small_scene.holdout_cameras[0]

    def psnr(calibrated: bool) -> float:
        textured = texture_mesh(mesh, photos, small_scene.cameras, TextureOptions(colour_calibration=calibrated))
        image, mask = render(textured, cam, gt.shape[1], gt.shape[0])
        return masked_psnr(image, gt, mask)

    evened, left = psnr(True), psnr(False)
    print(f"hold-out PSNR from photos of different exposure, vignetted: calibrated {evened:.2f} dB, not {left:.2f}")
    assert evened > left + 1
