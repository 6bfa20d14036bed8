"""mvs: depth and normal maps per view: recon's CPU PatchMatch, or COLMAP's CUDA PatchMatch when present."""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np

from recon.mvs.colmap_cuda import cuda_available, run_patch_match
from recon.mvs.options import MVSOptions
from recon.options import opt
from recon.products import DenseScene, DepthMaps
from recon.stage import Stage, StageContext, StageError, register


@dataclass(frozen=True)
class MvsConfig(MVSOptions):
    backend: Literal["auto", "cpu", "colmap-cuda"] = opt(
        "auto", "cpu = recon's PatchMatch; colmap-cuda = COLMAP's (needs pycolmap-cuda12 and an NVIDIA GPU); "
                "auto = colmap-cuda when available, else cpu")


def backend_of(cfg: MvsConfig) -> str:
    """The backend that runs: ``auto`` resolved on this machine (part of the cache key)."""
    if cfg.backend == "auto":
        return "colmap-cuda" if cuda_available() else "cpu"
    return cfg.backend


def _view_pass(task) -> str:
    """One view's photometric or geometric pass, in a worker process."""
    from recon.logs import quiet_colmap
    from recon.mvs import stereo

    quiet_colmap()
    pass_name, dense, problem, options, out = task
    view = stereo.photometric_view if pass_name == "photometric" else stereo.geometric_view
    return str(view(dense, problem, options, out))


@register
class Mvs(Stage):
    name = "mvs"
    version = 1
    Config = MvsConfig
    requires = (DenseScene,)
    produces = DepthMaps
    uses_seed = True
    summary = "PatchMatch multi-view stereo: per-view depth and normal maps, consistency-filtered"

    def fingerprint(self, ctx: StageContext, cfg: MvsConfig):
        """The resolved backend: depth maps made by COLMAP's CUDA PatchMatch are not recon's."""
        return {"backend": backend_of(cfg)}

    def run(self, ctx: StageContext, cfg: MvsConfig) -> dict:
        dense = ctx.input(DenseScene)
        stereo = ctx.output.folder
        stereo.mkdir(exist_ok=True)
        for name in ("patch-match.cfg", "fusion.cfg"):
            if (dense.stereo_configs / name).exists():
                shutil.copyfile(dense.stereo_configs / name, stereo / name)
        if backend_of(cfg) == "colmap-cuda":
            return self._colmap_cuda(ctx, dense, stereo, cfg)
        return self._cpu(ctx, dense, stereo, cfg)

    def _cpu(self, ctx: StageContext, dense: DenseScene, stereo: Path, cfg: MvsConfig) -> dict:
        import pycolmap

        from recon.mvs.stereo import map_path
        from recon.mvs.views import select_problems

        workers = max(1, min(ctx.executor.workers, len(os.sched_getaffinity(0))))
        threads = cfg.num_threads or max(1, len(os.sched_getaffinity(0)) // workers)
        options = replace(cfg, seed=cfg.seed + ctx.seed, num_threads=threads)
        problems = select_problems(pycolmap.Reconstruction(str(dense.model)), options)
        if not problems:
            raise StageError("mvs: no view has source views with enough shared points and baseline")
        for pass_name in ("photometric", "geometric"):  # every view's photometric maps before any geometric
            ctx.map(_view_pass, [(pass_name, dense.folder, p, options, stereo) for p in problems],
                    desc=f"mvs {pass_name}", done=lambda t: map_path(stereo, "depth", t[2].ref, t[0]).exists())
            _apply_masks(ctx, dense, stereo, [p.ref for p in problems], pass_name)
        return _coverage(stereo, [p.ref for p in problems], backend="cpu")

    def _colmap_cuda(self, ctx: StageContext, dense: DenseScene, stereo: Path, cfg: MvsConfig) -> dict:
        """Thin adapter: COLMAP's own PatchMatch on the GPU, writing into this stage's folder."""
        if not cuda_available():
            raise StageError("mvs.backend: 'colmap-cuda' needs `pip install recon[cuda]` (pycolmap-cuda12) and "
                             "an NVIDIA GPU; use 'cpu' or 'auto'")
        scratch = ctx.out / "colmap"  # COLMAP's layout: the undistorted images and model, this stage's stereo/
        scratch.mkdir(exist_ok=True)
        for target in (dense.images, dense.model, stereo):
            link = scratch / target.name
            if not link.exists():
                link.symlink_to(target)
        run_patch_match(scratch, replace(cfg, seed=cfg.seed + ctx.seed))
        names = [p.stem.removesuffix(".geometric") for p in (stereo / "depth_maps").glob("*.geometric.bin")]
        _apply_masks(ctx, dense, stereo, names, "geometric")
        return _coverage(stereo, names, backend="colmap-cuda")


def _apply_masks(ctx: StageContext, dense: DenseScene, stereo: Path, names: list[str], pass_name: str) -> None:
    """Clear the depths of masked pixels (photos with masks): after the photometric pass, so that the
    geometric pass does not check consistency against them, and after the geometric pass."""
    from recon.mvs.stereo import map_path, mask_maps

    cleared = 0
    for name in names:
        mask = dense.mask(name)
        if mask is not None and map_path(stereo, "depth", name, pass_name).exists():
            cleared += mask_maps(stereo, name, mask, pass_name)
    if cleared:
        ctx.log.info("mvs: %s depths of %d masked pixels cleared", pass_name, cleared)


def _coverage(stereo: Path, names: list[str], backend: str) -> dict:
    from recon.mvs.colmap_io import read_depth_map
    from recon.mvs.stereo import map_path

    kept = [float(np.count_nonzero(d)) / d.size for d in
            (read_depth_map(map_path(stereo, "depth", n, "geometric")) for n in names)]
    return {"backend": backend, "views": len(names), "kept_pixels": round(float(np.mean(kept)) if kept else 0.0, 3)}
