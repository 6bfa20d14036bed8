"""sfm: camera poses and sparse points from verified matches (COLMAP's incremental or global mapper).

Cameras come from the database (preprocess's intrinsics); when they are a calibration used as
``fixed`` (calibrate.use), bundle adjustment refines no intrinsics.

Last step: with enough GPS-tagged photos the models are georeferenced (:mod:`recon.sparse.georeference`):
written in local East-North-Up metres, so every later stage's output is too; ``georeference.json``
records the frame, the similarity applied and the GPS residuals.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

from recon.files import write_json
from recon.options import opt
from recon.products import MatchDatabase, PreparedPhotos, SparseModel
from recon.sparse import georeference, lens, mapping
from recon.sparse.frame import level_model
from recon.stage import Stage, StageContext, StageError, register


@dataclass(frozen=True)
class SfmConfig:
    mapper: Literal["incremental", "global"] = opt("incremental", "incremental (COLMAP) or global (GLOMAP) mapper")
    min_num_matches: int = opt(15, "fewest verified matches for a pair to be used", ge=5)
    min_model_size: int = opt(3, "smallest model (registered photos) that is kept", ge=2)
    multiple_models: bool = opt(True, "keep reconstructing the photos left out of the first model")
    init_min_tri_angle: float = opt(16.0, "initial pair: smallest triangulation angle, degrees", gt=0)
    abs_pose_min_num_inliers: int = opt(30, "fewest 2D-3D inliers to register a photo", ge=6)
    refine_focal_length: bool = opt(True, "bundle adjustment refines focal lengths")
    refine_principal_point: bool = opt(False, "bundle adjustment refines principal points")
    refine_extra_params: bool = opt(True, "bundle adjustment refines distortion")
    ba_global_ratio: float = opt(1.2, "run global BA when the model grew by this factor (COLMAP: 1.1)", gt=1)
    ba_local_images: int = opt(6, "photos in each local bundle adjustment", ge=2)
    ba_max_iterations: int = opt(50, "iterations of each global bundle adjustment (COLMAP: 100)", ge=1)
    final_ba_iterations: int = opt(100, "iterations of a last global BA over the finished model (0 = off)", ge=0)
    final_refine_principal_point: bool = opt(
        True, "a last global BA also refines principal points, kept where that explains the observations "
              "better (fountain_p11: AUC@5 93.3 -> 98.5); never while the model grows (unstable)")
    deterministic: bool = opt(False, "single-threaded mapping and bundle adjustment: bit-identical re-runs "
                                     "(multi-threaded runs agree to ~1e-3 of the camera spread), slower")
    georeference: Literal["auto", "off"] = opt(
        "auto", "auto: models in local East-North-Up metres when at least 3 registered photos, and more than "
                "half, have EXIF GPS (robust fit to the GPS positions); off: the mapper's arbitrary frame")
    gps_sigma: float = opt(0.0, "GPS accuracy in metres for every photo (0: each photo's GPSHPositioningError, "
                                "else GPSDOP, else 5 m); a photo farther than 3.4 sigma is an outlier", ge=0)


@register
class Sfm(Stage):
    name = "sfm"
    version = 4
    Config = SfmConfig
    requires = (PreparedPhotos, MatchDatabase)
    produces = SparseModel
    uses_seed = True
    summary = "incremental (or global) SfM with bundle adjustment; every model kept, largest as sparse/0"

    def run(self, ctx: StageContext, cfg: SfmConfig) -> dict:
        database = ctx.input(MatchDatabase).database
        photos = ctx.input(PreparedPhotos)
        images = photos.geometric  # original colours for the points
        listing = photos.listing()
        cameras = listing["cameras"]
        if cameras and all(c["fixed"] for c in cameras):
            ctx.log.info("sfm: calibrated cameras kept fixed")
            cfg = replace(cfg, refine_focal_length=False, refine_principal_point=False, refine_extra_params=False)
        models = mapping.reconstruct(database, images, cfg, ctx.seed)
        report = mapping.registration_report(database, models, cfg.min_num_matches, cfg.init_min_tri_angle)
        if not models:
            raise StageError(f"sfm: no model could be built. {report['reason']}")
        georef = _georeference(ctx, cfg, models, listing["images"])
        if not georef["georeferenced"]:  # georeferenced models are in ENU, already up along +Z
            report["frame"] = {"up": "+Z, the photos' average up",
                               "rotations_from_mapper": [level_model(rec).tolist() for rec in models]}
        else:
            report["frame"] = {"up": "+Z, local East-North-Up (georeference.json)"}
        for k, rec in enumerate(models):
            path = ctx.output.model(k)
            path.mkdir(parents=True, exist_ok=True)
            rec.write(str(path))
        ctx.output.write_report(report)
        write_json(ctx.output.georeference, georef)
        best = models[0]
        total = report["total_images"]
        if len(models) > 1:
            ctx.log.warning("sfm: %d separate models (sizes %s); the largest is sparse/0",
                            len(models), ", ".join(str(m.num_reg_images()) for m in models))
        for name, why in report["unregistered"].items():
            ctx.log.warning("not registered: %s: %s", name, why)
        for camera in best.cameras.values():
            if (why := lens.pinhole_fit_warning(camera)) is not None:
                ctx.log.warning("sfm: %s", why)
        return {"models": len(models), "registered": best.num_reg_images(), "images": total,
                "points": best.num_points3D(), "mean_reproj_error": round(best.compute_mean_reprojection_error(), 3),
                "georeferenced": georef["georeferenced"]}


def _georeference(ctx: StageContext, cfg: SfmConfig, models: list, images: list[dict]) -> dict:
    """Georeference the models in place (sfm.georeference) and log what was done; georeference.json."""
    if cfg.georeference == "off":
        return {"georeferenced": False, "reason": "sfm.georeference is off"}
    gps = georeference.gps_positions(images)
    if not gps:
        return {"georeferenced": False, "reason": "no photo has a GPS position with altitude in its EXIF"}
    result = georeference.georeference(models, gps, sigma=cfg.gps_sigma, seed=ctx.seed)
    if not result["georeferenced"]:
        ctx.log.warning("sfm: not georeferenced: %s", result["reason"])
        return result
    origin, residuals, scale_std = result["origin"], result["residuals_m"], result["scale_relative_std"]
    ctx.log.info("sfm: georeferenced in local ENU metres around lat %.6f, lon %.6f: GPS residuals median %.2f m, "
                 "90th percentile %.2f m; scale uncertainty %s", origin["lat"], origin["lon"], residuals["median"],
                 residuals["p90"], "unknown (3 photos)" if scale_std is None else f"{100 * scale_std:.2f} %")
    if result["outliers"]:
        ctx.log.warning("sfm: GPS of %d photo(s) disagrees with the model (left out of the fit): %s",
                        len(result["outliers"]), ", ".join(result["outliers"]))
    return result
