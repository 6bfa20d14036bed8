"""calibrate: intrinsics and distortion from photos of a chessboard or ChArUco board.

Runs only when ``calibrate.images`` names a folder of board photos (all from the camera that took
the scene's photos, at one size); otherwise it writes nothing but its manifest. Its
``intrinsics.json`` is read by preprocess, which gives every photo this camera (scaled when the
photos are a resized version of the calibration photos), and ``use`` tells SfM whether to keep it
fixed or only start from it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from recon.imaging.calibration import CharucoTarget, Chessboard, calibrate
from recon.options import opt
from recon.products import Calibration
from recon.sparse.photos import PhotoError, inspect_photo, list_photos, read_upright
from recon.stage import Stage, StageContext, StageError, register


@dataclass(frozen=True)
class CalibrateConfig:
    images: str | None = opt(None, "folder of photos of the calibration board, taken with the scene's camera; "
                                   "relative to the config file; unset = no calibration")
    target: Literal["chessboard", "charuco"] = opt("chessboard", "the board in the photos")
    chessboard: Chessboard = opt(Chessboard(), "target chessboard: inner corners and square size")
    charuco: CharucoTarget = opt(CharucoTarget(), "target charuco: squares, marker size and ArUco dictionary")
    model: Literal["SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV"] = opt(
        "OPENCV", "COLMAP camera model to estimate (its parameters only)")
    use: Literal["fixed", "prior"] = opt("fixed", "fixed: SfM keeps these intrinsics; prior: SfM starts from "
                                                  "them and refines them")
    max_rms: float = opt(1.0, "fail when the calibration's RMS reprojection error exceeds this, pixels", gt=0)


def _folder(ctx: StageContext, cfg: CalibrateConfig) -> Path | None:
    return ctx.user_path("images", cfg.images, "give the folder of board photos", folder=True)


@register
class Calibrate(Stage):
    name = "calibrate"
    version = 1
    Config = CalibrateConfig
    produces = Calibration
    summary = "camera intrinsics and distortion from chessboard/ChArUco photos (when calibrate.images is set)"

    def fingerprint(self, ctx: StageContext, cfg: CalibrateConfig):
        folder = _folder(ctx, cfg)
        if folder is None:
            return None
        return [[p.relative_to(folder).as_posix(), ctx.digest(p)] for p in list_photos(folder).photos]

    def run(self, ctx: StageContext, cfg: CalibrateConfig) -> dict:
        folder = _folder(ctx, cfg)
        if folder is None:
            return {"calibrated": False}
        photos = list_photos(folder).photos
        images = []
        for path in photos:
            try:
                inspect_photo(path, path.name)
            except PhotoError as exc:
                raise StageError(f"calibrate.images: {exc}") from None
            images.append(np.asarray(read_upright(path).convert("L")))
        target = cfg.chessboard if cfg.target == "chessboard" else cfg.charuco
        try:
            result = calibrate(images, target, cfg.model)
        except ValueError as exc:
            raise StageError(f"calibrate: {exc}; check the board size (calibrate.{cfg.target}) and that the "
                             "photos show the whole board") from None
        if result.rms > cfg.max_rms:
            raise StageError(f"calibrate: RMS reprojection error {result.rms:.2f} px exceeds calibrate.max_rms "
                             f"({cfg.max_rms}); the board size may be wrong, or some photos are blurred")
        cam = result.camera
        unused = [photos[i].name for i in range(len(photos)) if i not in set(result.used)]
        if unused:
            ctx.log.warning("calibrate: board not found in %d photo(s): %s", len(unused), ", ".join(unused[:5]))
        ctx.output.write({
            "model": cam.model, "width": cam.width, "height": cam.height, "params": list(cam.params),
            "use": cfg.use, "rms": result.rms, "views": len(result.used), "photos": len(photos), "unused": unused})
        return {"calibrated": True, "model": cam.model, "rms": round(result.rms, 4), "views": len(result.used),
                "fx": round(cam.fx, 2)}
