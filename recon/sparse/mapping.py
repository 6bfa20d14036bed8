"""Running COLMAP's mappers and explaining which photos did not register, and why."""

from __future__ import annotations

import logging
import tempfile
from pathlib import Path

import numpy as np

from recon.sparse.database import image_ids, private_copy, read_only

log = logging.getLogger(__name__)


def reconstruct(database: Path, images: Path, cfg, seed: int, start=None) -> list:
    """All models the mapper builds, largest first (``cfg`` is the sfm stage's config). ``start``: a
    model in the database's ids (:func:`recon.sparse.continuation.start_model`) that the incremental
    mapper continues, registering the other photos into it."""
    import pycolmap

    pycolmap.set_random_seed(seed)
    with tempfile.TemporaryDirectory(prefix="recon-sfm-") as scratch, private_copy(database) as database:
        start_path = ""
        if start is not None:
            start_path = str(Path(scratch) / "start")
            Path(start_path).mkdir()
            start.write(start_path)
            scratch = str(Path(scratch) / "models")
            Path(scratch).mkdir()
        if cfg.mapper == "global":
            opts = pycolmap.GlobalPipelineOptions()
            opts.min_num_matches = cfg.min_num_matches
            opts.min_model_size = cfg.min_model_size
            opts.multiple_models = cfg.multiple_models
            opts.random_seed = seed
            opts.num_threads = _threads(cfg)
            models = pycolmap.global_mapping(str(database), str(images), scratch, opts)
        else:
            models = pycolmap.incremental_mapping(str(database), str(images), scratch,
                                                  incremental_options(cfg, seed), input_path=start_path)
    ordered = sorted(models.values(), key=lambda r: (-r.num_reg_images(), -r.num_points3D()))
    if cfg.final_ba_iterations:
        ordered = [final_bundle_adjustment(rec, cfg) for rec in ordered]
    return ordered


def incremental_options(cfg, seed: int):
    import pycolmap

    opts = pycolmap.IncrementalPipelineOptions()
    opts.min_num_matches = cfg.min_num_matches
    opts.min_model_size = cfg.min_model_size
    opts.multiple_models = cfg.multiple_models
    opts.random_seed = seed
    opts.num_threads = _threads(cfg)
    opts.ba_refine_focal_length = cfg.refine_focal_length
    opts.ba_refine_principal_point = cfg.refine_principal_point
    opts.ba_refine_extra_params = cfg.refine_extra_params
    opts.ba_global_frames_ratio = cfg.ba_global_ratio
    opts.ba_global_points_ratio = cfg.ba_global_ratio
    opts.ba_global_max_num_iterations = cfg.ba_max_iterations
    mapper = opts.mapper
    mapper.init_min_tri_angle = cfg.init_min_tri_angle
    mapper.abs_pose_min_num_inliers = cfg.abs_pose_min_num_inliers
    mapper.ba_local_num_images = cfg.ba_local_images
    mapper.random_seed = seed
    mapper.num_threads = _threads(cfg)
    opts.triangulation.random_seed = seed
    return opts


def _threads(cfg) -> int:
    """COLMAP's thread count: all cores, or one where bit-identical re-runs are asked for (Ceres'
    multi-threaded sums, and so the incremental mapper's later decisions, depend on scheduling)."""
    return 1 if cfg.deterministic else -1


#: refined principal points are kept when they lower the mean reprojection error by a fraction of at
#: least max(MIN_GAIN, GAIN_OBSERVATIONS / observations). Two more parameters fitted to noise gain
#: about 1 / (2 observations); the bound asks for ~50x that, and 0.2 % at least. Measured: temple_ring
#: gains 0.58 % over 23,060 observations, fountain_p11 1.9 % over 28,238 (both kept: AUC@5 +10 and
#: +5); 16 synthetic views on an orbit 0.0 % over 9,659, 6 of them 0.29 % over 1,536 (refused: their
#: true principal points are the image centres, refined ones drift 4 and 20 px and the poses tilt)
PRINCIPAL_POINT_MIN_GAIN = 0.002
PRINCIPAL_POINT_GAIN_OBSERVATIONS = 25.0


def final_bundle_adjustment(rec, cfg):
    """One last global BA over the finished model, with a robust loss; then, when
    ``cfg.final_refine_principal_point``, one more that also refines the principal points, kept only
    where it explains the observations better (an orbit at one height leaves them unconstrained:
    they trade off against the cameras' tilt). Fisheye and 360 cameras keep theirs (the synthetic
    fisheye orbit: refining lowered the reprojection error by 0.67 %, and AUC@5 from 96.9 to 85.0).
    Returns the model kept."""
    import pycolmap

    _bundle_adjust(rec, cfg, cfg.refine_principal_point)
    pinhole = all(camera.is_perspective_pinhole() for camera in rec.cameras.values())
    if cfg.refine_principal_point or not cfg.final_refine_principal_point or not pinhole:
        return rec
    fixed = rec.compute_mean_reprojection_error()
    refined = pycolmap.Reconstruction(rec)
    _bundle_adjust(refined, cfg, True)
    error = refined.compute_mean_reprojection_error()
    gain = (fixed - error) / fixed if fixed > 0 else 0.0
    keep = gain >= max(PRINCIPAL_POINT_MIN_GAIN, PRINCIPAL_POINT_GAIN_OBSERVATIONS / max(rec.compute_num_observations(), 1))
    log.info("final BA: principal points %s (mean reprojection error %.4f -> %.4f px, %.2f %%)",
             "refined" if keep else "kept at the image centres: refining them gains too little", fixed, error,
             100 * gain)
    return refined if keep else rec


def _bundle_adjust(rec, cfg, principal_point: bool) -> None:
    import pycolmap

    opts = pycolmap.BundleAdjustmentOptions()
    opts.refine_focal_length = cfg.refine_focal_length
    opts.refine_principal_point = principal_point
    opts.refine_extra_params = cfg.refine_extra_params
    opts.print_summary = False
    opts.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    opts.ceres.solver_options.max_num_iterations = cfg.final_ba_iterations
    opts.ceres.solver_options.function_tolerance = 1e-6
    opts.ceres.solver_options.num_threads = _threads(cfg)
    pycolmap.bundle_adjustment(rec, opts)


def registration_report(database: Path, models: list, min_matches: int, init_min_tri_angle: float = 16.0) -> dict:
    """Per model: registered photos; per unregistered photo: the reason, from its verified matches;
    with no model, ``reason``: what the database shows about why (:func:`_no_model_reason`)."""
    import pycolmap

    with read_only(database) as db:
        names = {i: name for name, i in image_ids(db).items()}
        geometries = db.execute("SELECT pair_id, rows, config FROM two_view_geometries").fetchall()
        cameras = db.execute("SELECT width, height, params, prior_focal_length FROM cameras").fetchall()
    partners: dict[int, list[int]] = {i: [] for i in names}
    for pair_id, n, _ in geometries:
        if n >= min_matches:
            a, b = pycolmap.pair_id_to_image_pair(pair_id)
            partners[a].append(n)
            partners[b].append(n)
    in_model = {}
    for k, rec in enumerate(models):
        for image_id in rec.reg_image_ids():
            in_model.setdefault(rec.image(image_id).name, k)
    unregistered = {}
    for image_id, name in sorted(names.items(), key=lambda x: x[1]):
        if in_model.get(name) == 0:
            continue
        if name in in_model:
            unregistered[name] = f"registered in separate model {in_model[name]} (no overlap with the largest)"
        elif not partners[image_id]:
            unregistered[name] = f"too few matches: no other photo shares {min_matches}+ verified matches with it"
        else:
            best = max(partners[image_id])
            unregistered[name] = (f"registration failed: {len(partners[image_id])} matched photo(s), best "
                                  f"{best} inliers, but too few 2D-3D correspondences to the model")
    matched = sum(1 for v in partners.values() if v)
    return {
        "total_images": len(names),
        "models": [{"registered": rec.num_reg_images(), "points": rec.num_points3D(),
                    "mean_reproj_error": rec.compute_mean_reprojection_error()} for rec in models],
        "unregistered": unregistered,
        "reason": "" if models else _no_model_reason(len(names), matched, geometries, cameras, min_matches,
                                                     init_min_tri_angle),
    }


#: COLMAP's incremental mapper starts from a pair with at least this many verified inliers
#: (IncrementalMapperOptions.init_min_num_inliers)
INIT_MIN_INLIERS = 100


def _no_model_reason(photos: int, matched: int, geometries: list, cameras: list, min_matches: int,
                     init_min_tri_angle: float) -> str:
    """Why no model was built, from what the database shows: too few matches, no pair strong enough
    to start, or strong pairs that still gave no start, with the causes visible for that, most
    telling first: focal priors the pairs' geometry contradicts, pairs that fit a homography, the
    focal lengths the cameras start from, the baseline."""
    import pycolmap

    if matched < 2:
        return (f"Too few matches: no pair of the {photos} photos shares {min_matches}+ verified matches; "
                "are they photos of the same scene with enough overlap?")
    strong = [config for _, n, config in geometries if n >= INIT_MIN_INLIERS]
    if not strong:
        best = max(n for _, n, _ in geometries)
        return (f"No initial pair: {matched} photos have matches, but no pair has the {INIT_MIN_INLIERS}+ verified "
                f"inliers the mapper needs to start (the best has {best}); take photos with more overlap, or "
                "extract more features (features.max_image_size, features.max_num_features)")
    config = pycolmap.TwoViewGeometryConfiguration
    flat = sum(1 for c in strong if c in (config.PLANAR, config.PANORAMIC, config.PLANAR_OR_PANORAMIC))
    uncalibrated = sum(1 for c in strong if c == config.UNCALIBRATED)
    fov, priors = _starting_fov(cameras)
    causes = []
    if priors and 2 * uncalibrated >= len(strong):
        # with focal priors COLMAP calls a pair UNCALIBRATED when the essential matrix they imply
        # explains far fewer matches than a free fundamental matrix
        causes.append(f"wrong focal length priors: {uncalibrated} of those pairs contradict the focal lengths the "
                      f"cameras start from (EXIF or calibration: {fov} degree field of view across the diagonal); "
                      "a cropped, resized or digitally zoomed photo keeps a focal length that no longer fits it: "
                      "check the photos' EXIF")
    if flat:
        causes.append(f"{flat} of those pairs fit a homography (the camera turned on the spot, or the scene is "
                      "one plane): take photos from positions further apart")
    if priors and not causes:
        causes.append(f"wrong focal length priors ({priors} of {len(cameras)} camera(s) start from EXIF or a "
                      f"calibration: {fov} degree field of view across the diagonal): check the photos' EXIF")
    elif not priors:
        causes.append(f"no EXIF focal length: the cameras start from a guess ({fov} degree field of view across "
                      "the diagonal, ingest.default_focal_factor) that may be far off: a calibration helps")
    causes.append(f"too little baseline between the overlapping photos: lower sfm.init_min_tri_angle "
                  f"(now {init_min_tri_angle:g} degrees)")
    return (f"No initial pair: {len(strong)} pair(s) have the {INIT_MIN_INLIERS}+ verified inliers the mapper needs "
            f"to start, but none of them gave a first two-view model with a {init_min_tri_angle:g} degree "
            f"triangulation angle. Likely causes: " + "; ".join(causes) + ".")


def _starting_fov(cameras: list) -> tuple[str, int]:
    """The diagonal field of view (degrees, one value or a range) of the focal lengths the database's
    cameras start from, and how many of them are priors (EXIF or calibration), not guesses."""
    fovs, priors = [], 0
    for width, height, params, prior in cameras:
        focal = float(np.frombuffer(params, dtype=np.float64)[0])
        fovs.append(float(np.degrees(2 * np.arctan2(np.hypot(width, height) / 2, focal))))
        priors += bool(prior)
    span = f"{min(fovs):.0f}" if max(fovs) - min(fovs) < 1 else f"{min(fovs):.0f} to {max(fovs):.0f}"
    return span, priors
