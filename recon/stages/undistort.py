"""undistort: COLMAP's undistorted workspace (pinhole images, model, stereo configs) for dense work.

It reads preprocess's ``images_geometric``: the photos with only the geometric operations applied
(resize, undistortion), so their pixels match the model's cameras and keep their original colours.
"""

from __future__ import annotations

from dataclasses import dataclass

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
    version = 1
    Config = UndistortConfig
    requires = (PreparedPhotos, SparseModel)
    produces = DenseScene
    summary = "undistorted pinhole images and model in COLMAP's dense workspace layout"

    def run(self, ctx: StageContext, cfg: UndistortConfig) -> dict:
        import pycolmap

        opts = pycolmap.UndistortCameraOptions()
        opts.blank_pixels = cfg.blank_pixels
        if cfg.max_image_size:
            opts.max_image_size = cfg.max_image_size
        dense = ctx.output
        pycolmap.undistort_images(str(dense.folder), str(ctx.input(SparseModel).model()),
                                  str(ctx.input(PreparedPhotos).geometric), undistort_options=opts)
        rec = pycolmap.Reconstruction(str(dense.model))
        cam = next(iter(rec.cameras.values()))
        return {"images": rec.num_reg_images(), "size": f"{cam.width}x{cam.height}"}
