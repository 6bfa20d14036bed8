"""undistort: COLMAP's undistorted workspace (pinhole images, model, stereo configs) for dense work.

360-degree (equirectangular) photos become six cube-map faces each, with exactly known relative
poses (:mod:`recon.mvs.cubemap`); masks are not carried over to them.

It reads preprocess's ``images_geometric``: the photos with only the geometric operations applied
(resize, undistortion), so their pixels match the model's cameras and keep their original colours.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from recon.mvs import cubemap
from recon.options import opt
from recon.products import DenseScene, PreparedPhotos, SparseModel
from recon.stage import Stage, StageContext, register


@dataclass(frozen=True)
class UndistortConfig:
    max_image_size: int = opt(0, "longest side of the undistorted images (0 = keep the photos' size)", ge=0)
    blank_pixels: float = opt(0.0, "fraction of blank pixels allowed at the borders (0 = crop to valid pixels)",
                              ge=0, le=1)


@register
class Undistort(Stage):
    name = "undistort"
    version = 4  # 3 was photos without distortion put in as taken, not kept
    Config = UndistortConfig
    requires = (PreparedPhotos, SparseModel)
    produces = DenseScene
    summary = "undistorted pinhole images and model in COLMAP's dense workspace layout"

    def run(self, ctx: StageContext, cfg: UndistortConfig) -> dict:
        import pycolmap

        dense = ctx.output
        model = ctx.input(SparseModel).model()
        registration = ctx.input(SparseModel).report()
        for warning in (registration.get("warning"), registration.get("weak_joins", {}).get("warning")):
            if warning:  # repeated before the long dense work
                ctx.log.warning("undistort: dense work on the largest model: %s", warning)
        if cubemap.is_spherical(model):  # 360-degree photos: six pinhole faces each (recon.mvs.cubemap)
            return cubemap.write_cubemap_workspace(model, ctx.input(PreparedPhotos).geometric, dense.folder,
                                                   cfg.max_image_size)
        undistort_photos(model, ctx.input(PreparedPhotos).geometric, dense.folder, cfg)
        rec = pycolmap.Reconstruction(str(dense.model))
        masked = _undistort_masks(ctx.input(PreparedPhotos).masks, pycolmap.Reconstruction(str(model)), rec,
                                  dense.masks)
        cam = next(iter(rec.cameras.values()))
        return {"images": rec.num_reg_images(), "size": f"{cam.width}x{cam.height}", "masked": masked}


def undistort_photos(model: Path, photos: Path, folder: Path, cfg: UndistortConfig) -> None:
    """COLMAP's undistorted workspace in ``folder`` of the sparse ``model``'s ``photos``.

    COLMAP copies a photo as taken, and keeps its camera model (SIMPLE_RADIAL with k1 = 0, say), when the
    camera has no distortion and no image size limit is given; dense stereo needs pinhole cameras, so a
    limit is always given and every camera comes out PINHOLE. With ``max_image_size`` 0 it is one no
    undistorted frame reaches (COLMAP's frames are at most ``max_scale`` times the photo). A photo
    without distortion is then resampled half a pixel over (the frame is cropped to whole pixels):
    PatchMatch was measured to gain from that; the texture reads the photo as taken
    (:mod:`recon.surface.texture.sources`)."""
    import pycolmap

    opts = pycolmap.UndistortCameraOptions()
    opts.blank_pixels = cfg.blank_pixels
    cameras = pycolmap.Reconstruction(str(model)).cameras.values()
    opts.max_image_size = cfg.max_image_size or math.ceil(opts.max_scale * max(max(c.width, c.height) for c in cameras))
    pycolmap.undistort_images(str(folder), str(model), str(photos), undistort_options=opts)


def _undistort_masks(masks: Path, sparse, dense, out: Path) -> int:
    """Each photo's mask (preprocess's, in the model's camera) resampled into its undistorted view,
    so that no later stage takes a masked pixel for the subject; returns how many were written."""
    from recon.imaging.masks import load_mask, resample_mask, save_mask

    if not masks.is_dir():
        return 0
    written = 0
    for image in dense.images.values():
        mask = load_mask(masks, image.name)
        if mask is None:
            continue
        source = sparse.find_image_with_name(image.name)
        save_mask(out, image.name, resample_mask(mask, sparse.cameras[source.camera_id],
                                                 dense.cameras[image.camera_id]))
        written += 1
    return written
