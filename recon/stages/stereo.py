"""stereo: depth of one photo from a stereo pair: rectification, semi-global matching with a
left-right check, depth = f B / d in the left photo's own frame, and a coloured point cloud.

Two ways to give the pair's geometry:

- ``stereo.calibration``: a stereo calibration file (K1, D1, K2, D2, R, T, image_size; format in
  :mod:`recon.stereo.calibration` and pipelines/stereo.yaml) for the ingested photos ``stereo.left``
  and ``stereo.right``; the cloud is in the left camera's frame.
- no calibration, ``sfm`` in the run: both cameras come from the sparse model (from undistort's
  pinhole model and images when undistort is in the run too, so the depth map lines up with the dense
  stage's maps of that photo); unnamed photos are chosen for baseline and overlap; the cloud is in
  the model's world.

Outputs (``<workspace>/stereo/``): ``depth.npy`` / ``depth.bin`` (COLMAP's depth-map format) /
``depth_preview.png`` of the left photo at the working size, ``cloud.ply``, ``calibration.json`` (the
pair as used, reusable as ``stereo.calibration``), ``summary.json``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from recon.files import write_json
from recon.options import opt
from recon.products import DenseScene, Photos, PreparedPhotos, SparseModel, StereoDepth
from recon.stage import Stage, StageContext, StageError, register
from recon.stereo.calibration import StereoCalibration
from recon.stereo.options import StereoOptions

MIN_COVERAGE = 0.01


@dataclass(frozen=True)
class StereoConfig(StereoOptions):
    left: str = opt("", "the photo whose depth is computed (its name among the photos, e.g. 'IMG_01.jpg'); "
                        "empty = chosen from the sfm model")
    right: str = opt("", "the photo it is matched with; empty = chosen from the sfm model")
    calibration: str | None = opt(None, "stereo calibration file (YAML or JSON with image_size, K1, D1, K2, D2, "
                                        "R, T: see pipelines/stereo.yaml), relative to the config file; "
                                        "unset = the cameras of the sfm model")


@dataclass(frozen=True, eq=False)
class _Pair:
    """The photos (uint8 RGB) and cameras of the pair; ``pose``: the left camera's world-to-camera
    pose (None: the cloud stays in the left camera's frame); ``depth_range``: from sparse points."""

    left_name: str
    right_name: str
    left: np.ndarray
    right: np.ndarray
    calib: StereoCalibration
    pose: tuple[np.ndarray, np.ndarray] | None = None
    depth_range: tuple[float, float] | None = None


def _calibration_file(ctx: StageContext, cfg: StereoConfig) -> Path | None:
    return ctx.user_path("calibration", cfg.calibration,
                         "give the stereo calibration file (format: see pipelines/stereo.yaml)")


def _read_photo(path: Path) -> np.ndarray:
    from recon.sparse.photos import read_upright

    return np.asarray(read_upright(path).convert("RGB"))


@register
class Stereo(Stage):
    name = "stereo"
    version = 1
    Config = StereoConfig
    requires = (Photos,)
    optional = (PreparedPhotos, SparseModel, DenseScene)
    produces = StereoDepth
    summary = "two-view stereo (SGBM + left-right check): depth map and point cloud of one photo pair"

    def fingerprint(self, ctx: StageContext, cfg: StereoConfig):
        path = _calibration_file(ctx, cfg)
        return None if path is None else [path.name, ctx.digest(path)]

    def run(self, ctx: StageContext, cfg: StereoConfig) -> dict:
        from recon.stereo.calibration import write_calibration
        from recon.stereo.depth import stereo_depth
        from recon.stereo.outputs import point_cloud, write_depth, write_ply

        path = _calibration_file(ctx, cfg)
        if path is not None:
            pair = _calibrated_pair(ctx, cfg, path)
        elif "sfm" in ctx.upstream:
            pair = _model_pair(ctx, cfg)
        else:
            raise StageError("stereo.calibration: not set, and this run has no sfm stage to take the pair's "
                             "cameras from; set stereo.calibration, or add sfm to `stages`")
        names = f"{pair.left_name} / {pair.right_name}"
        ctx.log.info("stereo: %s (left / right), baseline %.4g", names, pair.calib.baseline)
        try:
            result = stereo_depth(pair.left, pair.right, pair.calib, cfg, pair.depth_range)
        except ValueError as exc:
            raise StageError(f"stereo: {names}: {exc}") from None
        if result.coverage < MIN_COVERAGE:
            raise StageError(f"stereo: {names} gave depth at {100 * result.coverage:.2f}% of "
                             "the pixels; check that the photos overlap, the cameras (stereo.calibration) and "
                             "the depth range (stereo.depth_min/depth_max or stereo.num_disparities)")
        out = ctx.output.folder
        write_depth(out, result.depth)
        points, colours = point_cloud(result, pair.pose)
        write_ply(out / "cloud.ply", points, colours)
        write_calibration(out / "calibration.json", pair.calib)
        write_json(out / "summary.json", {
            "left": pair.left_name, "right": pair.right_name,
            "cameras": "calibration file" if path is not None else "sfm model",
            "cloud_frame": "left camera" if pair.pose is None else "model world",
            "depth": "camera z of the left photo at the working size (intrinsics K, COLMAP's pixel convention), "
                     "0 = none",
            "K": result.camera.K.tolist(),
            "cam_from_world": None if pair.pose is None else {"R": pair.pose[0].tolist(), "t": pair.pose[1].tolist()},
            "points": len(points), **result.figures})
        return {"left": pair.left_name, "right": pair.right_name, "size": result.figures["size"],
                "coverage": result.figures["coverage"], "points": len(points)}


def _calibrated_pair(ctx: StageContext, cfg: StereoConfig, path: Path) -> _Pair:
    """Mode (a): the named ingested photos with the calibration file's cameras."""
    from recon.stereo.calibration import read_calibration

    photos = ctx.input(Photos)
    listed = [i["name"] for i in photos.listing()["images"]]
    for key, name in (("left", cfg.left), ("right", cfg.right)):
        if not name:
            raise StageError(f"stereo.{key}: with stereo.calibration, name both photos of the pair "
                             f"(stereo.left and stereo.right) among the photos: {_shown(listed)}")
        if name not in listed:
            raise StageError(f"stereo.{key}: no photo '{name}' among the photos: {_shown(listed)}")
    try:
        calib = read_calibration(path)
    except ValueError as exc:
        raise StageError(f"stereo.calibration: {exc}") from None
    images = photos.images
    left, right = _read_photo(images / cfg.left), _read_photo(images / cfg.right)
    try:
        calib = calib.fitted(left.shape[1::-1], right.shape[1::-1])
    except ValueError as exc:
        raise StageError(f"stereo.calibration: {exc}") from None
    return _Pair(cfg.left, cfg.right, left, right, calib)


def _model_pair(ctx: StageContext, cfg: StereoConfig) -> _Pair:
    """Mode (b): two registered photos of the sfm model (undistort's pinhole model when in the run)."""
    import pycolmap

    from recon.stereo import pairs

    if ctx.has(DenseScene):
        dense = ctx.input(DenseScene)
        model, images = dense.model, dense.images
    else:
        model, images = ctx.input(SparseModel).model(), ctx.input(PreparedPhotos).geometric
    rec = pycolmap.Reconstruction(str(model))
    try:
        views = pairs.model_views(rec)
    except ValueError as exc:
        raise StageError(f"stereo: {exc}; set stereo.calibration, or use a pinhole/radial/OpenCV camera "
                         "model (ingest.camera_model)") from None
    for key, name in (("left", cfg.left), ("right", cfg.right)):
        if name and name not in views:
            raise StageError(f"stereo.{key}: '{name}' is not a registered photo of the sfm model; registered: "
                             f"{_shown(sorted(views))}")
    if cfg.left and cfg.right:
        pair = pairs.score_pair(rec, views[cfg.left], views[cfg.right])
        if pair.shared < pairs.MIN_SHARED:
            raise StageError(f"stereo.right: '{cfg.left}' and '{cfg.right}' share {pair.shared} sparse points "
                             f"(fewer than {pairs.MIN_SHARED}): name two photos that overlap, or leave "
                             "stereo.right empty to pick one")
        left_name, right_name = cfg.left, cfg.right
    else:
        named = cfg.left or cfg.right or None
        pair = pairs.best_pair(rec, views, among=named)
        if pair is None:
            key, which = ("right", f"with '{named}' ") if cfg.right else ("left", f"with '{named}' " if named else "")
            raise StageError(f"stereo.{key}: no pair of registered photos {which}shares enough sparse points "
                             "seen side by side; name the pair (stereo.left and stereo.right)")
        left_name, right_name = pair.left, pair.right
        if (cfg.left and cfg.left != left_name) or (cfg.right and cfg.right != right_name):
            left_name, right_name = right_name, left_name  # keep the photo the user named on its side
        ctx.log.info("stereo: picked %s / %s (%d shared points, median triangulation angle %.1f deg)",
                     left_name, right_name, pair.shared, pair.angle_deg)
    left_view, right_view = views[left_name], views[right_name]
    return _Pair(left_name, right_name, _read_photo(images / left_name), _read_photo(images / right_name),
                 pairs.pair_calibration(left_view, right_view), (left_view.R, left_view.t),
                 pairs.depth_range(rec, left_view, cfg.depth_margin))


def _shown(names: list[str], most: int = 8) -> str:
    return ", ".join(names[:most]) + (f" ... ({len(names)} in all)" if len(names) > most else "")
