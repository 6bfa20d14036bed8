"""The photos a texture is baked from, and their cameras.

COLMAP's undistorter resamples every photo bilinearly, even one whose camera has no distortion: it crops
to the whole pixels of the frame it computes (640x480 becomes 639x479), which moves the principal point
by half a pixel, so each pixel becomes the mean of two or four of the photo's (masked_object's photos
lost 16-20 % of their gradient energy). Dense matching keeps those images: PatchMatch's
photo-consistency gains from that blur, and putting the photos in as taken lowered the zoo's fused and
mesh F (docs/DECISIONS.md). A texture baked from them is blurred as well. classic's held-out texture,
on the same mesh, from its photos through the undistorted cameras: 32.85 dB with COLMAP's images, 32.82
resampled bilinearly here, 33.73 bicubic, 33.97 with Lanczos; 34.13 dB as taken.

So each registered photo is read as taken (``preprocess``'s geometric images, in the sparse model's
cameras), and:
- where its camera projects as a pinhole (no distortion, or its refinement refused by the final bundle
  adjustment), textured from as it is, with the sparse model's camera and preprocess's mask;
- else (lens distortion, a fisheye) resampled into its undistorted view with Lanczos;
- the undistorted workspace's own images are used for 360-degree photos (cube faces) and whenever
  ``undistort.max_image_size`` made the dense images smaller: the texture then keeps the size dense
  work was given, and its memory and time with it.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import pycolmap

from recon.imaging.masks import load_mask
from recon.imaging.pixels import sample_lanczos, seen_pixels
from recon.mvs.views import ViewCamera, pinhole_view

_PINHOLE_TOL = 1e-3  # pixels: how far from a pinhole's projection a camera may map and count as one
_SCALE_TOL = 0.01  # a focal length changed by more than this share: the undistorter scaled the view


class TextureSources(NamedTuple):
    cameras: list[ViewCamera]
    images: list[np.ndarray]  # RGB
    masks: list[np.ndarray | None] | None  # True = the subject; None where a photo has none, or none has
    as_taken: int  # how many photos are textured from as taken
    resampled: int  # how many photos are resampled here into their undistorted view


def texture_sources(views: list[ViewCamera], undistorted: Path, undistorted_masks: Path, model: Path,
                    photos: Path, photo_masks: Path) -> TextureSources:
    """What to texture from, for the undistorted workspace's ``views`` (its images in ``undistorted``,
    masks in ``undistorted_masks``), the sparse ``model`` they were undistorted from, and the photos in
    ``photos`` (masks in ``photo_masks``) the model's cameras describe."""
    rec = pycolmap.Reconstruction(str(model))
    by_name = {img.name: img for img in rec.images.values() if img.has_pose}
    cameras, images, masks, as_taken, resampled = [], [], [], 0, 0
    for view in views:
        image = by_name.get(view.name)
        camera = rec.camera(image.camera_id) if image is not None else None
        if camera is None or abs(view.K[0, 0] / camera.calibration_matrix()[0, 0] - 1.0) >= _SCALE_TOL:
            cameras.append(view)
            images.append(_rgb(undistorted / view.name))
            masks.append(load_mask(undistorted_masks, view.name))
        elif _projects_as_pinhole(camera):
            cameras.append(pinhole_view(image, camera))
            images.append(_rgb(photos / view.name))
            masks.append(load_mask(photo_masks, view.name))
            as_taken += 1
        else:
            cameras.append(view)
            images.append(_resampled(_rgb(photos / view.name), camera, view))
            masks.append(load_mask(undistorted_masks, view.name))
            resampled += 1
    return TextureSources(cameras, images, masks if any(m is not None for m in masks) else None, as_taken,
                          resampled)


def _rgb(path: Path) -> np.ndarray:
    return cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)


def _projects_as_pinhole(camera: pycolmap.Camera) -> bool:
    """Whether ``camera`` maps rays to pixels as the pinhole of its focal lengths and principal point
    does (checked on a grid over its frame, whatever its model)."""
    K = np.asarray(camera.calibration_matrix(), np.float64)
    u, v = np.meshgrid(np.linspace(0, camera.width, 5), np.linspace(0, camera.height, 5))
    pixels = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], axis=1)
    projected = np.asarray(camera.img_from_cam(pixels @ np.linalg.inv(K).T), np.float64)
    return bool(np.all(np.abs(projected - pixels[:, :2]) < _PINHOLE_TOL))


def _resampled(photo: np.ndarray, camera: pycolmap.Camera, view: ViewCamera) -> np.ndarray:
    """``photo`` (uint8 RGB), taken by ``camera``, resampled with Lanczos into the pinhole ``view``."""
    K = view.K
    pinhole = pycolmap.Camera(model="PINHOLE", width=view.width, height=view.height,
                              params=[K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
    x, y = seen_pixels(camera, pinhole).T
    rgb = sample_lanczos(photo, x, y).reshape(view.height, view.width, 3)
    return np.clip(rgb, 0, 255).round().astype(np.uint8)
