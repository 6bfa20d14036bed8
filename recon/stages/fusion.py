"""fusion: depth maps -> one coloured, oriented point cloud (COLMAP's stereo fusion, on the CPU)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

from recon.files import atomic
from recon.mvs.free_space import MARGIN
from recon.mvs.fused_ply import keep_points, keep_visibility, read_points, vertex_count
from recon.options import opt
from recon.products import DenseScene, DepthMaps, FusedCloud
from recon.stage import Stage, StageContext, StageError, register


@dataclass(frozen=True)
class FusionConfig:
    min_num_pixels: int = opt(2, "fewest depth-map pixels (views) that must agree on a point; 2 rather than 3 keeps "
                                 "surface only two photos see (a survey's edges, a walk's corners): zoo, "
                                 "docs/DECISIONS.md", ge=1)
    max_reproj_error: float = opt(0.5, "largest reprojection error between agreeing views (px) for dense/fused.ply; "
                                       "smaller merges fewer pixels into each point: a denser cloud (COLMAP: 2). "
                                       "Zoo: 0.5 against 1, fused F@0.2 % mean .927 -> .937, turntable_black .818 "
                                       "-> .917 (docs/DECISIONS.md)", gt=0)
    mesh_reproj_error: float = opt(1.0, "the mesh stage meshes a second cloud, fused with this reprojection error "
                                        "(px), mesh_depth_error and mesh_normal_error; 0: it meshes dense/fused.ply. "
                                        "Zoo: the 1 px cloud's Poisson mesh is .002-.005 F@0.2 % above the 0.5 px "
                                        "cloud's on ten scenes, and no scene's held-out coverage falls "
                                        "(docs/DECISIONS.md)", ge=0)
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
    deterministic: bool = opt(True, "single-threaded fusion: the same points from the same depth maps. "
                                    "Multi-threaded, COLMAP merges pixels in the order its threads reach them "
                                    "and the cloud differs between runs (~0.1 % of the points)")
    keep_visibility: bool = opt(False, "keep COLMAP's fused.ply.vis (the views that saw each point, which COLMAP's "
                                       "Delaunay mesher reads); no recon stage reads it, and it is as large as "
                                       "the cloud")
    free_space: bool = opt(True, "drop points that more views see through (their depth maps hold a surface behind "
                                 "the point) than agree with: an object in some photos only, as a parked car, "
                                 "is not kept (recon.mvs.free_space)")
    free_space_margin: float = opt(MARGIN, "a view sees through a point when its depths around the point's pixel "
                                         "all lie beyond the point by more than this (relative)", gt=0)


class Tolerances(NamedTuple):
    """How closely the depth-map pixels that merge into one point must agree (COLMAP's fusion options)."""

    reproj_px: float
    depth: float  # relative
    normal_degrees: float


@register
class Fusion(Stage):
    name = "fusion"
    version = 3
    Config = FusionConfig
    requires = (DenseScene, DepthMaps)
    produces = FusedCloud
    summary = "fuse consistent depth-map pixels into a point cloud with normals and colours"

    def run(self, ctx: StageContext, cfg: FusionConfig) -> dict:
        dense = ctx.input(DenseScene)
        scratch = ctx.out / "workspace"  # COLMAP's layout, assembled from the two stages' outputs
        scratch.mkdir(exist_ok=True)
        for target in (dense.images, dense.model, ctx.input(DepthMaps).folder):
            name = target.name
            link = scratch / name
            if link.is_symlink():
                link.unlink()
            link.symlink_to(target)
        delivered = Tolerances(cfg.max_reproj_error, cfg.max_depth_error, cfg.max_normal_error)
        points, dropped = self._fuse(ctx, cfg, scratch, delivered, ctx.output.path,
                                     ctx.output.visibility if cfg.keep_visibility else None)
        result = {"points": points, "free_space_dropped": dropped}
        meshed = Tolerances(cfg.mesh_reproj_error, cfg.mesh_depth_error, cfg.mesh_normal_error)
        if cfg.mesh_reproj_error and meshed != delivered:
            result["mesh_points"], _ = self._fuse(ctx, cfg, scratch, meshed, ctx.output.meshing, None)
        return result

    def _fuse(self, ctx: StageContext, cfg: FusionConfig, scratch: Path, within: Tolerances, path: Path,
              visibility_path: Path | None) -> tuple[int, int]:
        """COLMAP's fusion of the depth maps in ``scratch`` into ``path``, pixels merging ``within`` the
        tolerances, with the views that saw each point into ``visibility_path`` when given, less the points
        in free space; (points, dropped)."""
        import pycolmap

        opts = pycolmap.StereoFusionOptions()
        opts.min_num_pixels = cfg.min_num_pixels
        opts.max_reproj_error = within.reproj_px
        opts.max_depth_error = within.depth
        opts.max_normal_error = within.normal_degrees
        opts.num_threads = 1 if cfg.deterministic else -1
        with atomic(path) as tmp:
            visibility = tmp.with_name(tmp.name + ".vis")  # COLMAP writes it beside the PLY
            try:
                pycolmap.stereo_fusion(str(tmp), str(scratch), options=opts, output_type="PLY")
                dropped = _drop_free_space(ctx, cfg, within.depth, tmp, visibility) if cfg.free_space else 0
                if visibility_path is not None and visibility.exists():
                    visibility.replace(visibility_path)
            finally:
                visibility.unlink(missing_ok=True)
            points = vertex_count(tmp)
            if points == 0:  # (trimesh reads an empty PLY as an empty scene, with no vertices)
                raise StageError("fusion: no point was seen consistently by enough views (too few registered "
                                 "photos, or depth maps mostly empty); lower fusion.min_num_pixels or check the "
                                 "mvs depth maps")
        ctx.log.info("fusion: %d points within %.2f px, %g of the depth and %g degrees into %s", points,
                     within.reproj_px, within.depth, within.normal_degrees, path.name)
        return points, dropped


def _drop_free_space(ctx: StageContext, cfg: FusionConfig, depth_error: float, ply: Path, visibility: Path) -> int:
    """Remove from the fused cloud (and its visibility record) the points more views see through than
    agree with (within ``depth_error``, relative); how many went."""
    from recon.mvs.free_space import in_free_space

    if vertex_count(ply) == 0:
        return 0
    points = read_points(ply)
    views = ctx.input(DepthMaps).of_views(ctx.input(DenseScene).views())
    drop = in_free_space(points, views, depth_error, cfg.free_space_margin)
    if drop.any():
        keep_points(ply, ~drop)
        if visibility.exists():
            keep_visibility(visibility, ~drop)
    ctx.log.info("fusion: %d of %d points dropped: more views see through them than agree with them",
                 int(drop.sum()), len(points))
    return int(drop.sum())

