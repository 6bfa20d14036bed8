"""Running COLMAP's mappers and explaining which photos did not register, and why."""

from __future__ import annotations

import logging
import tempfile
from pathlib import Path

from recon.sparse.database import image_ids, private_copy, read_only

log = logging.getLogger(__name__)


def reconstruct(database: Path, images: Path, cfg, seed: int) -> list:
    """All models the mapper builds, largest first (``cfg`` is the sfm stage's config)."""
    import pycolmap

    pycolmap.set_random_seed(seed)
    with tempfile.TemporaryDirectory(prefix="recon-sfm-") as scratch, private_copy(database) as database:
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
                                                  incremental_options(cfg, seed))
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
    they trade off against the cameras' tilt). Returns the model kept."""
    import pycolmap

    _bundle_adjust(rec, cfg, cfg.refine_principal_point)
    if cfg.refine_principal_point or not cfg.final_refine_principal_point:
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


def registration_report(database: Path, models: list, min_matches: int) -> dict:
    """Per model: registered photos; per unregistered photo: the reason, from its verified matches."""
    import pycolmap

    with read_only(database) as db:
        names = {i: name for name, i in image_ids(db).items()}
        inliers = db.execute("SELECT pair_id, rows FROM two_view_geometries").fetchall()
    partners: dict[int, list[int]] = {i: [] for i in names}
    for pair_id, n in inliers:
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
    reason = ""
    if not models:
        matched = sum(1 for v in partners.values() if v)
        strong = sum(1 for _, n in inliers if n >= 100)
        if matched < 2:
            reason = (f"Too few matches: no pair of the {len(names)} photos shares {min_matches}+ verified matches; "
                      "are they photos of the same scene with enough overlap?")
        else:
            reason = (f"No initial pair: {matched} photos have matches but {strong} pair(s) have the 100+ inliers "
                      "with enough baseline needed to start; take photos with more overlap, or lower "
                      "sfm.init_min_tri_angle")
    return {
        "total_images": len(names),
        "models": [{"registered": rec.num_reg_images(), "points": rec.num_points3D(),
                    "mean_reproj_error": rec.compute_mean_reprojection_error()} for rec in models],
        "unregistered": unregistered,
        "reason": reason,
    }
