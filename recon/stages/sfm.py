"""sfm: camera poses and sparse points from verified matches (COLMAP's incremental or global mapper).

Where the incremental mapper leaves photos out or splits them into several models, the global mapper
runs too and the result registering more photos is kept (``mapper_fallback``,
:func:`recon.sparse.mapping.reconstruct`); ``models.json`` and the summary say which mapper made the
model and why. A largest model that leaves out more than a quarter of the photos ends the stage with a
warning naming the count and what to try.

Cameras come from the database (preprocess's intrinsics); when they are a calibration used as
``fixed`` (calibrate.use), bundle adjustment refines no intrinsics.

Last step: with enough GPS-tagged photos the models are georeferenced (:mod:`recon.sparse.georeference`):
written in local East-North-Up metres, so every later stage's output is too; ``georeference.json``
records the frame, the similarity applied and the GPS residuals. Ground control points, scale bars
and printed targets the photos show (ArUco markers, a chessboard: :mod:`recon.sparse.markers`) place
or scale the first model (:func:`recon.sparse.georeference.place`).

Photos added to a finished workspace: the newest earlier model made with the same options, whose
photos are all still there with the same features, is continued instead of mapping every photo
again (``continue_from_previous``, :mod:`recon.sparse.continuation`): its photos' poses stay fixed
while the new photos are registered and adjusted, and the result stays in that model's frame, so
the outputs made from it stay where they were.

Photos smaller than ``refine_image_size`` have each model refined after mapping: finer SIFT matched only
where the model shows two photos overlapping, the points triangulated again and the last bundle
adjustment re-run (:mod:`recon.sparse.refine`).
"""

from __future__ import annotations

import tempfile
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Literal

from recon.config import to_dict
from recon.files import write_json
from recon.geometry.gcp import GcpFileError, read_gcp_list
from recon.options import opt, output_options
from recon.products import FeatureDatabase, MatchDatabase, PreparedPhotos, SparseModel
from recon.sparse import continuation, georeference, lens, mapping, markers, refine
from recon.sparse.control import ControlError, ScaleBar
from recon.sparse.features import FeaturesConfig, extract_photo, load_features
from recon.sparse.frame import level_model
from recon.sparse.georeference import DEFAULT_GCP_SIGMA
from recon.sparse.markers import ArucoMarkers, Chessboard
from recon.sparse.weak_joins import weak_joins
from recon.stage import Stage, StageContext, StageError, producer, register


@dataclass(frozen=True)
class SfmConfig:
    mapper: Literal["incremental", "global"] = opt("incremental", "incremental (COLMAP) or global (GLOMAP) mapper")
    mapper_fallback: bool = opt(
        True, "incremental mapper: where its largest model holds under 95 % of the photos (or they split into "
              "several models), also run the global mapper and keep its model if it registers more photos at a "
              "mean reprojection error up to 2 px")
    min_num_matches: int = opt(15, "fewest verified matches for a pair to be used", ge=5)
    min_model_size: int = opt(3, "smallest model (registered photos) that is kept", ge=2)
    multiple_models: bool = opt(True, "keep reconstructing the photos left out of the first model")
    init_min_tri_angle: float = opt(16.0, "initial pair: smallest triangulation angle, degrees", gt=0)
    abs_pose_min_num_inliers: int = opt(30, "fewest 2D-3D inliers to register a photo", ge=6)
    refine_focal_length: bool = opt(True, "bundle adjustment refines focal lengths")
    refine_principal_point: bool = opt(False, "bundle adjustment refines principal points")
    refine_extra_params: bool = opt(
        True, "bundle adjustment refines distortion; the last global BA keeps it only where that lowers the mean "
              "reprojection error enough (0.2 %, more in small models; else it holds the starting value: zero, or a "
              "calibration's)")
    ba_global_ratio: float = opt(1.2, "run global BA when the model grew by this factor (COLMAP: 1.1)", gt=1)
    ba_local_images: int = opt(6, "photos in each local bundle adjustment", ge=2)
    ba_max_iterations: int = opt(50, "iterations of each global bundle adjustment (COLMAP: 100)", ge=1)
    final_ba_iterations: int = opt(100, "iterations of a last global BA over the finished model (0 = off)", ge=0)
    final_refine_principal_point: bool = opt(
        True, "a last global BA also refines principal points, kept where that explains the observations "
              "better (fountain_p11: AUC@5 93.3 -> 98.5) and takes no EXIF focal length's camera farther "
              "from it; never while the model grows (unstable)")
    deterministic: bool = opt(False, "single-threaded mapping and bundle adjustment: bit-identical re-runs "
                                     "(multi-threaded runs agree to ~1e-3 of the camera spread), slower")
    georeference: Literal["auto", "off"] = opt(
        "auto", "auto: models in local East-North-Up metres when at least 3 registered photos, and more than "
                "half, have EXIF GPS (robust fit to the GPS positions); off, or too little GPS: the photos' average "
                "up along +Z, scale and position as the mapper left them")
    crs: Literal["enu", "utm"] = opt(
        "enu", "frame of a model placed on the Earth (GPS, or GCPs in a CRS): enu = local East-North-Up metres around "
               "the origin; utm = its UTM zone (WGS 84), easting / northing / height minus whole kilometres "
               "(georeference.json: zone, offset), as GIS tools take it")
    gps_sigma: float = opt(0.0, "GPS accuracy in metres for every photo (0: each photo's GPSHPositioningError, "
                                "else GPSDOP, else 5 m); a photo farther than 3.4 sigma is an outlier", ge=0)
    gcp_file: str | None = opt(None, "ground control points: OpenDroneMap's gcp_list.txt (first line a CRS: EPSG:<code>, "
                                     "WGS84, 'WGS84 UTM 32N', a PROJ string or ENU; then 'x y z px py photo [name]'), "
                                     "relative to the config file; the model is moved onto them (with GPS, jointly)")
    gcp_sigma: float = opt(DEFAULT_GCP_SIGMA,
                           "how far a GCP found in the model may be from its surveyed position, metres: weighs GCPs "
                           "against GPS; a GCP beyond 3.4 sigma after the fit is left out and named", gt=0)
    scale_bars: list[ScaleBar] = opt([], "known distances between two points each marked in two photos or more "
                                         "({length: metres, a: [{photo, x, y}, ...], b: [...]}): they set the "
                                         "model's scale (without GCPs), or check it")
    aruco: ArucoMarkers = opt(ArucoMarkers(), "printed ArUco markers of one size in view: found in the photos by "
                                              "themselves, their sides set the model's scale as scale bars do "
                                              "(without GCPs or scale bars), or check it")
    chessboard: Chessboard = opt(Chessboard(), "a printed chessboard in view: found in the photos by itself, its "
                                               "rows and columns set the model's scale as scale bars do (without "
                                               "GCPs, scale bars or ArUco markers), or check it")
    gps_prior: Literal["auto", "on", "off"] = opt(
        "auto", "a last bundle adjustment with the GPS positions as priors (georeferenced models): auto = when the "
                "photos' GPS accuracy is 0.5 m or better (RTK / PPK; sfm.gps_sigma, else their tags), where it "
                "straightens the bowl a nadir block bends into; coarser GPS bends it further, so auto uses that only "
                "where the model's photos fall into groups tied by few points, which GPS places against each "
                "other (measured: recon.sparse.gps_prior)")
    refine_image_size: int = opt(
        0, "after mapping, photos smaller than this (longest side, px) have their SIFT extracted again upsized to "
           "it, matched only between photos the model shows overlapping, kept on its epipolar geometry; the "
           "points are triangulated again and the last bundle adjustment re-run (recon.sparse.refine). Cameras "
           "closer to the truth (640x480 photos at 1280: temple_ring AUC@1 73.9 -> 77.9) for about a minute more "
           "per 24 photos; off by default, as the zoo's dense clouds followed on one scene of three. 0: off",
        ge=0)
    continue_from_previous: bool = opt(
        True, "incremental mapper: when photos were added, continue the workspace's previous model (same sfm "
              "options, all its photos still there with the same features; their poses kept fixed) and keep its "
              "frame, instead of mapping every photo again")


@register
class Sfm(Stage):
    name = "sfm"
    version = 12
    Config = SfmConfig
    requires = (PreparedPhotos, FeatureDatabase, MatchDatabase)
    produces = SparseModel
    uses_seed = True
    summary = "incremental (or global) SfM with bundle adjustment; every model kept, largest as sparse/0"

    def run(self, ctx: StageContext, cfg: SfmConfig) -> dict:
        database = ctx.input(MatchDatabase).database
        photos = ctx.input(PreparedPhotos)
        images = photos.geometric  # original colours for the points
        listing = photos.listing()
        previous, previous_key = self.previous_model(ctx, cfg)
        cameras = listing["cameras"]
        if cameras and all(c["fixed"] for c in cameras):
            ctx.log.info("sfm: calibrated cameras kept fixed")
            cfg = replace(cfg, refine_focal_length=False, refine_principal_point=False, refine_extra_params=False)
        start = None if previous is None else continuation.start_model(previous, *continuation.database_ids(database))
        if start is not None:
            ctx.log.info("sfm: continuing the previous model (%s, %d photos) with the new photos",
                         previous_key[:16], start.num_reg_images())
        made = (mapping.reconstruct(database, images, cfg, ctx.seed) if start is None
                else continuation.continue_model(database, images, cfg, ctx.seed, start))
        models = made.models if start is not None else [_refined(ctx, cfg, rec, images, database)
                                                          for rec in made.models]
        report = mapping.registration_report(database, models, cfg.min_num_matches, cfg.init_min_tri_angle,
                                              cfg.min_model_size, made.taken_out)
        if not models:
            tried = f": {made.why}" if len(made.attempts) > 1 else ""  # the global mapper's model refused, or none
            raise StageError(f"sfm: no model could be built{tried}. {report['reason']}")
        kept = _keep_frame(ctx, models, previous) if start is not None else None
        joins = weak_joins(models[0], cfg.abs_pose_min_num_inliers)
        georef = _georeference(ctx, cfg, models, listing["images"], images, continued=start is not None,
                               groups=len(joins.groups))
        report["frame"] = _level(models, georef, kept)
        report["mapping"] = ({"continued_from": previous_key[:16], "previous_photos": start.num_reg_images()}
                             if start is not None else "from scratch")
        report["mapper"] = {"used": made.mapper, "why": made.why, "attempts": [asdict(a) for a in made.attempts]}
        if made.false_pairs:
            report["mapper"]["false_pairs"] = made.false_pairs
        left_out = mapping.left_out_warning(models[0].num_reg_images(), report["total_images"], made)
        if left_out:
            report["warning"] = left_out
        loose = joins.warning()
        report["weak_joins"] = joins.to_json() | ({"warning": loose} if loose else {})
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
        if left_out:
            ctx.log.warning("sfm: %s", left_out)
        if loose:
            ctx.log.warning("sfm: %s", loose)
        return {"models": len(models), "registered": best.num_reg_images(), "images": total,
                "points": best.num_points3D(), "mean_reproj_error": round(best.compute_mean_reprojection_error(), 3),
                "georeferenced": georef["georeferenced"], "mapper": made.mapper, "mapper_why": made.why,
                "mapping": "continued" if start is not None else "from scratch",
                **({"continued_from": previous_key[:16]} if start is not None else {})}

    def fingerprint(self, ctx: StageContext, cfg: SfmConfig):
        """The GCP file's content (sfm.gcp_file)."""
        path = _gcp_file(ctx, cfg)
        return None if path is None else [path.name, ctx.digest(path)]

    def reusable(self, ctx: StageContext, cfg: SfmConfig) -> str:
        previous, key = self.previous_model(ctx, cfg)
        if previous is None:
            return "maps every photo (no previous model to continue)"
        return f"continues the previous model {key[:16]} ({previous.num_reg_images()} photos)"

    def previous_model(self, ctx: StageContext, cfg: SfmConfig):
        """The model to continue (a pycolmap Reconstruction) and the key of its output, or (None, None):
        the newest earlier output of this stage with the same options and seed, undamaged, all of whose
        photos are among this run's with the same features (their item keys, :mod:`recon.items`), from
        a run that lacked some of this run's photos. Without added photos nothing is continued: what
        made sfm run again (matches, lens settings) must reach every photo's pose."""
        if not (cfg.continue_from_previous and cfg.mapper == "incremental" and ctx.reuse):
            return None, None
        import pycolmap

        ws, features = ctx.workspace, producer(FeatureDatabase)
        current = ctx.input(FeatureDatabase).item_keys()
        config = to_dict(output_options(cfg))
        for manifest in reversed(ws.manifests(self.name)):
            key = manifest.get("key", "")
            if (manifest.get("version"), manifest.get("seed"), manifest.get("config")) != (self.version, ctx.seed, config) \
                    or ws.verify(self.name, key) is not None:
                continue
            before = FeatureDatabase(ws.output_dir(features, manifest["upstream"].get(features, ""))).item_keys()
            if not current.keys() - before.keys():
                continue
            model = pycolmap.Reconstruction(str(SparseModel(ws.output_dir(self.name, key)).model()))
            if all(image.name in current and before.get(image.name) == current[image.name]
                   for image in model.images.values()):
                return model, key
        return None, None


def _refined(ctx: StageContext, cfg: SfmConfig, rec, images: Path, database: Path):
    """``rec`` refined with finer features (:mod:`recon.sparse.refine`) where ``cfg.refine_image_size`` asks
    for it and the model allows it; else ``rec``."""
    if not cfg.refine_image_size:
        return rec
    why = refine.refinable(rec, cfg.refine_image_size)
    if why is not None:
        ctx.log.info("sfm: a model of %d photos not refined: %s", rec.num_reg_images(), why)
        return rec
    settings = replace(FeaturesConfig().settings(), max_image_size=cfg.refine_image_size,
                       min_image_size=cfg.refine_image_size)
    ids = sorted(rec.reg_image_ids())
    with tempfile.TemporaryDirectory(prefix="recon-refine-") as scratch:
        tasks = [(images / rec.image(i).name, Path(scratch) / f"{i}.npz", settings, None) for i in ids]
        ctx.map(extract_photo, tasks, desc="sfm: refinement features")
        features = {i: load_features(task[1]) for i, task in zip(ids, tasks)}
    return refine.refine(rec, features, images, cfg, *mapping.camera_start(database))


def _keep_frame(ctx: StageContext, models: list, previous) -> dict | None:
    """Put the model that continued ``previous`` back in its frame (:mod:`recon.sparse.continuation`);
    which model, and how well its photos' centres fit their previous places."""
    shared = [len({i.name for i in rec.images.values()} & {i.name for i in previous.images.values()})
              for rec in models]
    k = max(range(len(models)), key=shared.__getitem__)
    fit = continuation.align_to_previous(models[k], previous, ctx.seed)
    if fit is None:
        return None
    ctx.log.info("sfm: model %d kept in the previous model's frame (%d photos, centres' RMS %.3g)", k,
                 fit["photos"], fit["rms"])
    return {"model": k, **fit}


def _level(models: list, georef: dict, kept: dict | None = None) -> list[dict]:
    """Put each model that GPS did not place with its up along +Z (:mod:`recon.sparse.frame`; a
    georeferenced model is in local East-North-Up, up along +Z already; the model ``kept`` in a
    previous model's frame stays in it); how, per model."""
    placed = [georef["georeferenced"]] + [other["georeferenced"] for other in georef.get("other_models", [])]
    frames = []
    for k, rec in enumerate(models):
        if k < len(placed) and placed[k]:
            frames.append({"model": k, "frame": "local East-North-Up metres (georeference.json)"})
        elif kept is not None and kept["model"] == k:
            frames.append({"model": k, "frame": "the previous model's (up along +Z), fitted on its photos' centres",
                           "fit": kept})
        else:
            frames.append({"model": k, "frame": "up along +Z: the photos' average up",
                           "rotation_from_mapper": level_model(rec).tolist()})
    return frames


def _gcp_file(ctx: StageContext, cfg: SfmConfig) -> Path | None:
    return ctx.user_path("gcp_file", cfg.gcp_file,
                         "give an OpenDroneMap gcp_list.txt (format: README, 'Metric scale and ground control')")


def _georeference(ctx: StageContext, cfg: SfmConfig, models: list, images: list[dict], pictures: Path,
                  continued: bool, groups: int) -> dict:
    """Put the models in metres in place (GPS: sfm.georeference, sfm.gps_prior unless the model was
    ``continued``, weighing the first model's ``groups`` of photos tied by few points; sfm.gcp_file;
    sfm.scale_bars; sfm.aruco and sfm.chessboard, searched for in the registered photos of the first
    model, under ``pictures``) and log what was done; georeference.json."""
    gps = georeference.gps_positions(images) if cfg.georeference == "auto" else None
    path = _gcp_file(ctx, cfg)
    found = [_search(ctx, models[0], pictures, target) for target in (cfg.aruco, cfg.chessboard) if target.enabled]
    try:
        gcps = None if path is None else read_gcp_list(path)
        result = georeference.place(models, gps, sigma=cfg.gps_sigma, seed=ctx.seed, gcps=gcps,
                                    gcp_sigma=cfg.gcp_sigma, scale_bars=cfg.scale_bars, markers=found,
                                    prior=None if continued else cfg.gps_prior,
                                    ba_options=mapping.ba_options(cfg, principal_point=False), crs=cfg.crs,
                                    groups=groups)
    except GcpFileError as exc:
        raise StageError(f"sfm.gcp_file: {exc}") from None
    except ControlError as exc:  # it names the option at fault
        raise StageError(f"sfm.{exc}") from None
    _log_control(ctx, result)
    utm = result.get("utm")
    if utm is not None and utm["used"]:
        ctx.log.info("sfm: model in UTM zone %s (EPSG:%d) minus offset %s m (similarity error at most %.3f m)",
                     utm["zone"], utm["epsg"], utm["offset"], utm["max_error_m"])
    elif utm is not None:
        ctx.log.warning("sfm: sfm.crs is utm but %s; the model stays in its own frame", utm["why"])
    if not result["georeferenced"]:
        if gps:
            ctx.log.warning("sfm: not georeferenced: %s", result["reason"])
        return result
    if result["scale_source"] == "GCP":
        return result
    origin, residuals, scale_std = result["origin"], result["residuals_m"], result["scale_relative_std"]
    ctx.log.info("sfm: georeferenced in metres, origin lat %.6f, lon %.6f: GPS residuals median %.2f m, "
                 "90th percentile %.2f m; scale uncertainty %s", origin["lat"], origin["lon"], residuals["median"],
                 residuals["p90"], "unknown (3 photos)" if scale_std is None else f"{100 * scale_std:.2f} %")
    prior = result["gps_prior"]
    if prior["used"]:
        error = prior["reprojection_error_px"]
        ctx.log.info("sfm: bundle adjustment with the GPS of %d photos as priors (%s): mean reprojection error "
                     "%.3f -> %.3f px", prior["photos"], prior["why"], error["before"], error["after"])
    else:
        ctx.log.info("sfm: no GPS prior bundle adjustment: %s", prior["why"])
    if result["outliers"]:
        ctx.log.warning("sfm: GPS of %d photo(s) disagrees with the model (left out of the fit): %s",
                        len(result["outliers"]), ", ".join(result["outliers"]))
    return result


def _search(ctx: StageContext, model, pictures: Path, target: ArucoMarkers | Chessboard) -> markers.Found:
    """The registered photos of ``model`` searched for ``target``, one task per photo."""
    desc = f"sfm: looking for {target.describe()}"
    return markers.search(model, pictures, target, lambda fn, items: ctx.map(fn, items, desc=desc))


def _log_control(ctx: StageContext, result: dict) -> None:
    """Log what the GCPs, scale bars and printed targets did (georeference.json has the figures)."""
    gcp = result.get("gcp")
    if gcp is not None:
        check = "" if gcp["check_rms_m"] is None else f", leave-one-out check RMS {gcp['check_rms_m']:.3f} m"
        ctx.log.info("sfm: placed on %d GCPs%s: residual RMS %.3f m%s", len(gcp["points"]) - len(gcp["outliers"]),
                     " and the GPS photos" if gcp["with_gps"] else "", gcp["rms_m"], check)
        if gcp["outliers"]:
            ctx.log.warning("sfm: GCP(s) that disagree with the model, left out of the fit: %s",
                            ", ".join(gcp["outliers"]))
        for name, why in gcp["not_used"].items():
            ctx.log.warning("sfm: GCP %s not used: %s", name, why)
    for k, bar in enumerate(result.get("scale_bars", []), start=1):
        ctx.log.info("sfm: scale bar %d: %.4g m, %.4g m in the model (%s)", k, bar["length_m"], bar["model_length_m"],
                     "it set the scale" if result["scale_source"] == "scale bar" else "a check")
    for record in result.get("markers", []):
        if not record["used"]:
            ctx.log.warning("sfm: %s", record["reason"])
            continue
        std = record["scale_relative_std"]
        ctx.log.info("sfm: %s (%s): %d target(s), %d edges in %d photos; %s: x%.5g%s", record["source"], record["what"],
                     len(record["targets"]), record["edges"], record["photos_with_detections"],
                     "they set the scale" if record["set_scale"] else "a check of the scale, which they measure",
                     record["scale"], "" if std is None else f" +- {100 * std:.2g} %")
        for name, why in record["not_used"].items():
            ctx.log.warning("sfm: %s: %s not used: %s", record["option"], name, why)
