"""mesh: a surface from the dense reconstruction (screened Poisson on fused points, a visibility-based
Delaunay graph cut of the fused points and the views' lines of sight, or TSDF + marching cubes on the
depth maps), cleaned and decimated; written as a vertex-coloured mesh.ply."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from recon.files import write_bytes
from recon.options import opt
from recon.products import DenseScene, DepthMaps, FusedCloud, SurfaceMesh
from recon.stage import Stage, StageContext, StageError, register
from recon.surface.options import MeshOptions


@dataclass(frozen=True)
class MeshConfig(MeshOptions):
    tsdf_max_views: int = opt(0, "tsdf: integrate at most this many depth maps, evenly spread (0 = all)", ge=0)
    drop_unseen: bool = opt(True, "drop faces no registered view sees (hidden from, outside of, or turned away from "
                                  "every view), but not those next to a seen face: Poisson's closures and the "
                                  "extensions no photo shows (recon.surface.unseen; zoo: docs/DECISIONS.md)")
    unmeasured_views: int = opt(3, "with drop_unseen: also drop faces that at least this many views see while none "
                                   "holds a depth there or finds them in a hole of its depth map (0: keep them). "
                                   "Zoo: mesh F@0.2 % facade_walk .920 -> .933, no scene's coverage or texture "
                                   "down (docs/DECISIONS.md)", ge=0)
    free_space: bool = opt(True, "drop faces that more views see through (their depth maps hold a surface behind "
                                 "the face) than agree with, where the mesh lies behind them: surface Poisson put "
                                 "where the views saw none (recon.surface.seen_through). Zoo: mesh F@0.2 % mean "
                                 "+.003, fence_poles .972 -> .980; held-out coverage mean -.001 (docs/DECISIONS.md)")
    max_faces_per_pixel: float = opt(
        0.25, "decimate further to at most this many faces per pixel of the surface in the views that show it "
              "largest (0: off): a vertex every 2 pixels or so, still finer than stereo's matching window resolves; "
              "binds on objects a few hundred pixels across, where mesh.target_faces left several vertices per "
              "pixel (recon.surface.resolution; zoo: docs/DECISIONS.md)", ge=0)
    drop_backdrop: bool = opt(True, "drop faces that more views show over the sky or a backdrop (within the matching "
                                    "window's radius of its edge) than measure, where no mesh lies behind them: a "
                                    "surface run on past its edge into the sky (recon.surface.backdrop; the background "
                                    "is found with the mvs options). Zoo: mesh F@0.2 % mean .9475 -> .9488, "
                                    "noisy_phone .969 -> .978; held-out coverage mean -.0005 (docs/DECISIONS.md)")
    denoise: bool = opt(True, "flatten the surface's noise, last, and leave its sharp edges as they were: the face "
                              "normals filtered bilaterally, the vertices moved to fit them, those within 2 edges "
                              "of a sharp vertex put back (recon.surface.denoise). Zoo, 17 scenes: the faces' "
                              "median angle to the true surface down on all (street_forward 17.1 -> 6.0 degrees, "
                              "turntable_black 6.0 -> 2.5, plain_boxes 1.8 -> 0.6), mesh F@0.2 % mean .9561 -> "
                              ".9565, held-out texture PSNR mean 31.02 -> 31.03 dB (docs/DECISIONS.md)")


def _drop_masked(ctx: StageContext, mesh):
    """With masks (preprocess.mask_dir): the mesh without faces over masked pixels, and how many went
    (:mod:`recon.surface.masking`); None without masks."""
    from recon.surface.masking import drop_masked_faces

    dense = ctx.input(DenseScene)
    if not dense.masks.is_dir():
        return None
    views = dense.views()
    return drop_masked_faces(mesh, views, {v.name: m for v in views if (m := dense.mask(v.name)) is not None})


def _no_finer_than_the_photos(ctx: StageContext, mesh, faces_per_pixel: float):
    """The mesh decimated to ``faces_per_pixel`` faces per pixel of its surface in the views that show it
    largest, where it has more (:mod:`recon.surface.resolution`), and how many faces went."""
    from recon.surface.cleanup import decimate
    from recon.surface.resolution import resolved_faces

    target = resolved_faces(mesh, ctx.input(DenseScene).views(), faces_per_pixel)
    if target >= len(mesh.faces):
        return mesh, 0
    ctx.log.info("mesh: %d faces for the photos' %d pixels of its surface: decimated to %d (mesh.max_faces_per_pixel "
                 "%g)", len(mesh.faces), round(target / faces_per_pixel), target, faces_per_pixel)
    decimated = decimate(mesh, target)
    return decimated, len(mesh.faces) - len(decimated.faces)


def _depth_maps(ctx: StageContext):
    """(view, its final depth map) for each registered view that has one, read one at a time."""
    return ctx.input(DepthMaps).of_views(ctx.input(DenseScene).views())


def _backdrops(ctx: StageContext):
    """(view, its final depth map, its photo's :func:`recon.surface.backdrop.backdrop_rim` at the depth map's
    size, with the run's mvs options) for each view with a depth map."""
    from dataclasses import fields

    from recon.mvs.options import MVSOptions
    from recon.mvs.stereo import load_grey
    from recon.surface.backdrop import backdrop_rim

    names = {f.name for f in fields(MVSOptions)}
    options = MVSOptions(**{k: v for k, v in ctx.settings.get("mvs", {}).items() if k in names})
    images = ctx.input(DenseScene).images
    for view, depth in _depth_maps(ctx):
        image, _ = load_grey(images / view.name, view, depth.shape[::-1])
        yield view, depth, backdrop_rim(image, depth, options)


def _fused_cloud(ctx: StageContext):
    """The fused cloud to mesh (open3d; fusion.mesh_reproj_error), its colours (N x 3 uint8; None without)
    and how error messages name it."""
    from recon._open3d import open3d

    fused = ctx.input(FusedCloud)
    path = fused.for_meshing()
    cloud = open3d().io.read_point_cloud(str(path))
    colors = (np.asarray(cloud.colors) * 255).round().astype(np.uint8) if cloud.has_colors() else None
    named = "dense/fused.ply" if path == fused.path else f"fusion's meshing.ply ({path})"
    return cloud, colors, named


@register
class Mesh(Stage):
    name = "mesh"
    version = 14
    Config = MeshConfig
    requires = (DenseScene, DepthMaps, FusedCloud)
    produces = SurfaceMesh
    summary = "Poisson (default), Delaunay graph-cut or TSDF surface, trimmed, cleaned, decimated: mesh.ply"

    def run(self, ctx: StageContext, cfg: MeshConfig) -> dict:
        from recon.surface.backdrop import backdrop_faces
        from recon.surface.cleanup import clean_mesh, keep_faces
        from recon.surface.seen_through import seen_through_faces
        from recon.surface.unseen import drop_unseen_faces

        points = None  # what the surface was built from, where it was built from the fused cloud
        if cfg.method == "poisson":
            mesh, points = self._poisson(ctx, cfg)
        elif cfg.method == "delaunay":
            mesh, points = self._delaunay(ctx, cfg)
        else:
            mesh = self._tsdf(ctx, cfg)
        mesh = clean_mesh(mesh, cfg, points)
        unseen = unmeasured = 0
        if cfg.drop_unseen:
            # without the unmeasured rule, only the cameras count: no depth map is read
            views = _depth_maps(ctx) if cfg.unmeasured_views else [(v, None) for v in ctx.input(DenseScene).views()]
            mesh, unseen, unmeasured = drop_unseen_faces(mesh, views, cfg.unmeasured_views)
            ctx.log.info("mesh: %d faces dropped: no view sees them or their neighbours; %d more: %d or more "
                         "views see them and none measures them", unseen, unmeasured, cfg.unmeasured_views)
        carved = 0
        if cfg.free_space:
            seen_through = seen_through_faces(mesh, _depth_maps(ctx))
            mesh, carved = keep_faces(mesh, ~seen_through), int(seen_through.sum())
            ctx.log.info("mesh: %d faces dropped: more views see through them than agree with them, and the "
                         "mesh lies behind them", carved)
        backdrop = 0
        if cfg.drop_backdrop:
            over = backdrop_faces(mesh, _backdrops(ctx))
            mesh, backdrop = keep_faces(mesh, ~over), int(over.sum())
            ctx.log.info("mesh: %d faces dropped: more views show the sky or a backdrop there than measure them",
                         backdrop)
        masked = _drop_masked(ctx, mesh)
        if masked is not None:
            mesh, dropped = masked
            ctx.log.info("mesh: %d faces over masked pixels dropped", dropped)
        finer = 0
        if len(mesh.faces) and cfg.max_faces_per_pixel:
            mesh, finer = _no_finer_than_the_photos(ctx, mesh, cfg.max_faces_per_pixel)
        if cfg.denoise and len(mesh.faces):  # last, on the faces as written: decimation leaves its own bumps
            from recon.surface.denoise import denoised_vertices

            started = time.perf_counter()
            mesh.vertices = denoised_vertices(mesh.vertices, mesh.faces)
            ctx.log.info("mesh: denoised %d faces in %.1f s", len(mesh.faces), time.perf_counter() - started)
        if len(mesh.faces) == 0:
            raise StageError(f"mesh: the {cfg.method} surface is empty after trimming; lower "
                             "mesh.density_quantile, set mesh.drop_unseen: false, or check the fusion stage's cloud")
        write_bytes(ctx.output.path, mesh.export(file_type="ply"))
        return {"method": cfg.method, "vertices": len(mesh.vertices), "faces": len(mesh.faces),
                "watertight": bool(mesh.is_watertight), "unseen_faces_dropped": unseen,
                "unmeasured_faces_dropped": unmeasured,
                "free_space_faces_dropped": carved,
                "backdrop_faces_dropped": backdrop,
                "masked_faces_dropped": masked[1] if masked else 0,
                "finer_than_the_photos_faces_dropped": finer}

    def _poisson(self, ctx: StageContext, cfg: MeshConfig):
        from recon.surface.poisson import poisson_mesh

        cloud, colors, named = _fused_cloud(ctx)
        if len(cloud.points) < 100 or not cloud.has_normals():
            raise StageError(f"mesh: {named} has too few oriented points for Poisson meshing; "
                             "check the fusion stage, or use mesh.method: tsdf")
        points = np.asarray(cloud.points)
        return poisson_mesh(points, np.asarray(cloud.normals), colors, cfg), points

    def _delaunay(self, ctx: StageContext, cfg: MeshConfig):
        from recon.surface.delaunay import delaunay_mesh

        cloud, colors, named = _fused_cloud(ctx)
        if len(cloud.points) < 100:
            raise StageError(f"mesh: {named} has too few points for Delaunay meshing; check the fusion stage")
        points = np.asarray(cloud.points)
        try:
            return delaunay_mesh(points, colors, _depth_maps(ctx), cfg), points
        except ValueError as e:
            raise StageError(f"mesh: no Delaunay surface from {named}: {e}; use mesh.method: poisson") from e

    def _tsdf(self, ctx: StageContext, cfg: MeshConfig):
        import cv2

        from recon.mvs.views import scaled_to
        from recon.surface.tsdf import tsdf_mesh

        dense = ctx.input(DenseScene)
        views = dense.views()
        if cfg.tsdf_max_views and len(views) > cfg.tsdf_max_views:
            views = [views[i] for i in np.linspace(0, len(views) - 1, cfg.tsdf_max_views).round().astype(int)]
        depths, images, cameras = [], [], []
        for view, depth in ctx.input(DepthMaps).of_views(views):
            image = cv2.cvtColor(cv2.imread(str(dense.images / view.name)), cv2.COLOR_BGR2RGB)
            image = cv2.resize(image, (depth.shape[1], depth.shape[0]), interpolation=cv2.INTER_AREA)
            depths.append(depth)
            images.append(image)
            cameras.append(scaled_to(view, depth.shape[1], depth.shape[0]))
        if not depths:
            raise StageError("mesh: no geometric depth maps found for TSDF meshing; run the mvs stage")
        return tsdf_mesh(depths, images, cameras, cfg)
