"""sfm: camera poses and sparse points from verified matches (COLMAP's incremental or global mapper).

Cameras come from the database (preprocess's intrinsics); when they are a calibration used as
``fixed`` (calibrate.use), bundle adjustment refines no intrinsics.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

from recon.options import opt
from recon.sparse import mapping
from recon.stage import Stage, StageContext, StageError, register
from recon.workspace import read_json, write_json


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


@register
class Sfm(Stage):
    name = "sfm"
    version = 2
    Config = SfmConfig
    requires = ("preprocess", "matching")
    outputs = ("sparse/<k>/{cameras,images,points3D}.bin", "models.json")
    publish = {"sparse": "sparse"}
    uses_seed = True
    summary = "incremental (or global) SfM with bundle adjustment; every model kept, largest as sparse/0"

    def run(self, ctx: StageContext, cfg: SfmConfig) -> dict:
        database = ctx.input("matching") / "database.db"
        images = ctx.input("preprocess") / "images_geometric"  # original colours for the points
        cameras = read_json(ctx.input("preprocess") / "images.json")["cameras"]
        if cameras and all(c["fixed"] for c in cameras):
            ctx.log.info("sfm: calibrated cameras kept fixed")
            cfg = replace(cfg, refine_focal_length=False, refine_principal_point=False, refine_extra_params=False)
        models = mapping.reconstruct(database, images, cfg, ctx.seed)
        report = mapping.registration_report(database, models, cfg.min_num_matches)
        if not models:
            raise StageError(f"sfm: no model could be built. {report['reason']}")
        for k, rec in enumerate(models):
            path = ctx.out / "sparse" / str(k)
            path.mkdir(parents=True, exist_ok=True)
            rec.write(str(path))
        write_json(ctx.out / "models.json", report)
        best = models[0]
        total = report["total_images"]
        if len(models) > 1:
            ctx.log.warning("sfm: %d separate models (sizes %s); the largest is sparse/0",
                            len(models), ", ".join(str(m.num_reg_images()) for m in models))
        for name, why in report["unregistered"].items():
            ctx.log.warning("not registered: %s: %s", name, why)
        return {"models": len(models), "registered": best.num_reg_images(), "images": total,
                "points": best.num_points3D(), "mean_reproj_error": round(best.compute_mean_reprojection_error(), 3)}
