"""Running COLMAP's mappers and explaining which photos did not register, and why."""

from __future__ import annotations

import logging
import tempfile
from pathlib import Path

from recon.sparse.database import opened

log = logging.getLogger(__name__)


def reconstruct(database: Path, images: Path, cfg, seed: int) -> list:
    """All models the mapper builds, largest first (``cfg`` is the sfm stage's config)."""
    import pycolmap

    pycolmap.set_random_seed(seed)
    with tempfile.TemporaryDirectory(prefix="recon-sfm-") as scratch:
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
    if cfg.final_ba_iterations and ordered:
        for rec in ordered:
            final_bundle_adjustment(rec, cfg)
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


def final_bundle_adjustment(rec, cfg) -> None:
    """One last global BA over the finished model, with a robust loss, then the outliers filtered."""
    import pycolmap

    opts = pycolmap.BundleAdjustmentOptions()
    opts.refine_focal_length = cfg.refine_focal_length
    opts.refine_principal_point = cfg.refine_principal_point
    opts.refine_extra_params = cfg.refine_extra_params
    opts.print_summary = False
    opts.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    opts.ceres.solver_options.max_num_iterations = cfg.final_ba_iterations
    opts.ceres.solver_options.function_tolerance = 1e-7
    opts.ceres.solver_options.num_threads = _threads(cfg)
    pycolmap.bundle_adjustment(rec, opts)


def registration_report(database: Path, models: list, min_matches: int) -> dict:
    """Per model: registered photos; per unregistered photo: the reason, from its verified matches."""
    import pycolmap

    with opened(database) as db:
        names = {img.image_id: img.name for img in db.read_all_images()}
        pair_ids, geometries = db.read_two_view_geometries()
    partners: dict[int, list[int]] = {i: [] for i in names}
    for pair_id, geom in zip(pair_ids, geometries):
        n = len(geom.inlier_matches)
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
        strong = sum(1 for g in geometries if len(g.inlier_matches) >= 100)
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
