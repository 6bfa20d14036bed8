"""fusion: depth maps -> one coloured, oriented point cloud (COLMAP's algorithm, its merge radius apart:
recon.mvs.fusion)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from recon.files import atomic
from recon.mvs.free_space import MARGIN, in_free_space
from recon.mvs.fused_ply import write_cloud, write_visibility
from recon.mvs.fusion import FusionViews, Tolerances, fuse, read_views
from recon.options import opt
from recon.products import DenseScene, DepthMaps, FusedCloud
from recon.stage import Progress, Stage, StageContext, StageError, register


@dataclass(frozen=True)
class FusionConfig:
    min_num_pixels: int = opt(2, "fewest depth-map pixels (views) that must agree on a point; 2 rather than 3 keeps "
                                 "surface only two photos see (a survey's edges, a walk's corners): zoo, "
                                 "docs/DECISIONS.md", ge=1)
    max_reproj_error: float = opt(1.0, "largest reprojection error (px) at which a view's pixel agrees with a point "
                                       "of dense/fused.ply (COLMAP: 2). The pixel a point's seed projects to lies "
                                       "within 0.71 px of the projection, so from 0.71 up only the depth and normal "
                                       "tests decide", gt=0)
    merge_reproj_error: float = opt(0.25, "an agreeing pixel within this reprojection error (px) is merged into the "
                                          "point and seeds no point of its own; smaller: a denser cloud. COLMAP "
                                          "merges every agreeing pixel. Zoo, against COLMAP's fusion at 0.5 px: fused "
                                          "F@0.2 % mean .9479 -> .9564, turntable_black .923 -> .962, street_forward "
                                          ".885 -> .908 (docs/DECISIONS.md)", gt=0)
    mesh_reproj_error: float = opt(1.0, "the mesh stage meshes a second cloud, whose points merge every pixel that "
                                        "agrees within this reprojection error (px), mesh_depth_error and "
                                        "mesh_normal_error; 0: it meshes dense/fused.ply. Zoo: the 1 px cloud's "
                                        "Poisson mesh is .002-.005 F@0.2 % above the 0.5 px cloud's on ten scenes, "
                                        "and no scene's held-out coverage falls (docs/DECISIONS.md)", ge=0)
    max_depth_error: float = opt(0.03, "largest relative depth difference between agreeing views for "
                                       "dense/fused.ply (COLMAP: 0.01). Zoo, with max_normal_error 60: fused F@0.2 % "
                                       "mean .9474 -> .9479 against 2 %, far_field .924 -> .928, street_forward .883 "
                                       "-> .885, no scene down by more than .0001 (docs/DECISIONS.md)", gt=0)
    mesh_depth_error: float = opt(0.01, "largest relative depth difference between agreeing views for the cloud the "
                                        "mesh stage meshes; at 0.02 its Poisson mesh lost (docs/DECISIONS.md)", gt=0)
    max_normal_error: float = opt(60.0, "largest normal angle between agreeing views (degrees) for dense/fused.ply; "
                                        "60 rather than COLMAP's 10 keeps surface seen at a grazing angle or from "
                                        "views far apart, where PatchMatch's normals of one point disagree more; "
                                        "the two sides of a thin object (opposite normals) still do not merge. Zoo: "
                                        "fused F@0.2 % mean .9457 -> .9474 against 20 (with 2 % of depth), walkaround "
                                        "(the worst) .835 -> .843, far_field .916 -> .924; noisy_phone -.0005 "
                                        "(docs/DECISIONS.md)", gt=0)
    mesh_normal_error: float = opt(10.0, "largest normal angle between agreeing views (degrees) for the cloud the "
                                         "mesh stage meshes (fusion.mesh_reproj_error); at 20 its Poisson mesh lost "
                                         "(docs/DECISIONS.md)", gt=0)
    keep_visibility: bool = opt(False, "write fused.ply.vis (the views that saw each point, in COLMAP's format, which "
                                       "its Delaunay mesher reads); no recon stage reads it, and it is as large as "
                                       "the cloud")
    free_space: bool = opt(True, "drop points that more views see through (their depth maps hold a surface behind "
                                 "the point) than agree with: an object in some photos only, as a parked car, "
                                 "is not kept (recon.mvs.free_space)")
    free_space_margin: float = opt(MARGIN, "a view sees through a point when its depths around the point's pixel "
                                         "all lie beyond the point by more than this (relative)", gt=0)


@register
class Fusion(Stage):
    name = "fusion"
    version = 4
    Config = FusionConfig
    requires = (DenseScene, DepthMaps)
    produces = FusedCloud
    summary = "fuse consistent depth-map pixels into a point cloud with normals and colours"

    def run(self, ctx: StageContext, cfg: FusionConfig) -> dict:
        dense = ctx.input(DenseScene)
        started = time.perf_counter()
        try:
            views = read_views(dense.images, dense.model, ctx.input(DepthMaps).folder)
        except ValueError as exc:  # an unreadable photo or map
            raise StageError(str(exc)) from exc
        if not views.cameras:
            raise StageError("fusion: no registered view has final depth and normal maps; run again with "
                             "--force mvs")
        ctx.log.info("fusion: read %d views' maps in %.1f s", len(views.cameras), time.perf_counter() - started)
        delivered = Tolerances(cfg.max_reproj_error, min(cfg.merge_reproj_error, cfg.max_reproj_error),
                               cfg.max_depth_error, cfg.max_normal_error)
        points, dropped = self._fuse(ctx, cfg, views, delivered, ctx.output.path,
                                     ctx.output.visibility if cfg.keep_visibility else None)
        result = {"points": points, "free_space_dropped": dropped}
        meshed = Tolerances(cfg.mesh_reproj_error, cfg.mesh_reproj_error, cfg.mesh_depth_error, cfg.mesh_normal_error)
        if cfg.mesh_reproj_error and meshed != delivered:
            result["mesh_points"], _ = self._fuse(ctx, cfg, views, meshed, ctx.output.meshing, None)
        return result

    def _fuse(self, ctx: StageContext, cfg: FusionConfig, views: FusionViews, within: Tolerances, path: Path,
              visibility_path: Path | None) -> tuple[int, int]:
        """Fuse ``views`` into ``path``, pixels agreeing ``within`` the tolerances, less the points in free
        space, with the views that saw each point into ``visibility_path`` when given; (points, dropped)."""
        started = time.perf_counter()
        progress = Progress(ctx.log, f"fusion: {path.name}", len(views.cameras))
        try:
            cloud = fuse(views, within, cfg.min_num_pixels, progress=progress.advance)
        finally:
            progress.close()
        dropped = 0
        if cfg.free_space and len(cloud.xyz):
            drop = in_free_space(cloud.xyz.astype(np.float64), views.depth_maps(), within.depth, cfg.free_space_margin)
            dropped = int(drop.sum())
            ctx.log.info("fusion: %d of %d points dropped: more views see through them than agree with them",
                         dropped, len(cloud.xyz))
            cloud = cloud.subset(~drop)
        if not len(cloud.xyz):
            raise StageError("fusion: no point was seen consistently by enough views (too few registered "
                             "photos, or depth maps mostly empty); lower fusion.min_num_pixels or check the "
                             "mvs depth maps")
        with atomic(path) as tmp:
            write_cloud(tmp, cloud.xyz, cloud.normals, cloud.colours)
        if visibility_path is not None:
            with atomic(visibility_path) as tmp:
                write_visibility(tmp, cloud.view_counts, views.model_indices[cloud.views])
        ctx.log.info("fusion: %d points within %.2f px (merged within %.2f), %g of the depth and %g degrees into %s "
                     "in %.1f s", len(cloud.xyz), within.reproj_px, within.merge_px, within.depth,
                     within.normal_degrees, path.name, time.perf_counter() - started)
        return len(cloud.xyz), dropped
